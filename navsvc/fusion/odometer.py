"""The odometer as both filters read it (pure): distance travelled, and speed.

Seed: Mayhew 1999, chapter 4 (ABS wheel pulses, about 27.3 per metre). Ticks are coarse (one
tick in 20 ms is 1.8 m/s), so a speed from cumulative distance is taken over a window of at
least ``window_s``.
"""

from __future__ import annotations

from navsvc.types import OdometerSample

Window = tuple[float, float]  # (t s, cumulative distance m) at the window's start


def distance_m(packet: OdometerSample, ticks_per_m: float) -> float | None:
    """The cumulative distance of a reading: its own, else from its ticks."""
    if packet.distance_m is not None:
        return packet.distance_m
    return None if packet.ticks is None else packet.ticks / ticks_per_m


def speed_mps(packet: OdometerSample, window: Window | None, ticks_per_m: float,
              window_s: float) -> tuple[Window | None, float | None]:
    """The new window and the speed a reading gives (None while the window is short).

    A speed reading is taken as it is. A distance starts the window again when it is the first,
    or goes back in time or distance (a counter reset)."""
    if packet.speed_mps is not None:
        return window, packet.speed_mps
    distance = distance_m(packet, ticks_per_m)
    if distance is None:
        return window, None
    if window is None or packet.t < window[0] or distance < window[1]:
        return (packet.t, distance), None
    if packet.t - window[0] < window_s:
        return window, None
    return (packet.t, distance), (distance - window[1]) / (packet.t - window[0])
