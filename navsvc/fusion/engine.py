"""FusionEngine: one vehicle's fusion, one shell over both filters (pure: no I/O, no clock).

The sensor configuration's profile (:mod:`navsvc.fusion.profiles`) picks the filter: the
8-state road-vehicle EKF (:class:`navsvc.fusion.road.filter.RoadFilter`, Mayhew 1999) or the
strapdown INS (:class:`navsvc.fusion.ins.strapdown.StrapdownFilter`, Giroux et al. 2005).
Both take packets in time order and give the same :class:`FusedEstimate` stream; the engine
puts its reorder window (:mod:`navsvc.fusion.reorder`) in front, so late packets are handled
alike, and builds the road constraint of map feedback from the matcher's road.

Two ways in: :meth:`FusionEngine.add`, a packet at a time (the reference path, and the only
one for GPS, the strapdown INS, an uninitialised filter and late packets), and
:meth:`FusionEngine.add_run`, a run of dead-reckoning samples in one compiled call
(:mod:`navsvc.fusion.road.batch`) when the road filter is initialised and the run is in time
order; otherwise it takes the run's first sample through ``add``.
"""

from __future__ import annotations

from typing import Any, Protocol

from navsvc.fusion._jit import Array
from navsvc.fusion.config import FusionConfig
from navsvc.fusion.gnss import RoadDistance
from navsvc.fusion.ins.strapdown import StrapdownFilter, StrapdownOptions
from navsvc.fusion.kalman import Measurement
from navsvc.fusion.profiles import FilterKind
from navsvc.fusion.reorder import ReorderWindow, Replayable, S
from navsvc.fusion.road.batch import SampleRun, T
from navsvc.fusion.road.filter import RoadFilter
from navsvc.fusion.road.measurements import RoadConstraint
from navsvc.types import FusedEstimate, Packet
from roadgraph.geometry import LocalFrame


class Filter(Replayable[S], Protocol[S]):
    """What the engine needs of a filter, beside what the reorder window needs."""

    frame: LocalFrame | None  # the metric frame (set at the first fix when not given)

    def estimate(self) -> FusedEstimate | None:
        """The current estimate, or None before initialisation."""
        ...

    def correct(self, m: Measurement[Array]) -> bool:
        """Apply an external measurement; False when it is refused."""
        ...


DEFAULT_CONFIG = FusionConfig()
DEFAULT_INS = StrapdownOptions()


class FusionEngine:
    """One vehicle's filter. ``add`` a packet, get the estimates it produced."""

    def __init__(self, config: FusionConfig = DEFAULT_CONFIG,
                 frame: LocalFrame | None = None,
                 ins: StrapdownOptions = DEFAULT_INS,
                 road_distance: RoadDistance | None = None) -> None:
        """``road_distance``: the map's fit of a position (in ``frame``): the road filter
        tells by it which of two GPS tracks lies on the roads, and both filters the fixes'
        error the map sees (:class:`navsvc.fusion.gnss.MapSeenError`)."""
        self.config = config
        self.profile = config.profile
        road = self.profile.filter == FilterKind.ROAD
        self.filter: Filter[Any] = RoadFilter(config, frame, road_distance) if road \
            else StrapdownFilter(config, frame, ins, road_distance)
        self.window: ReorderWindow[Any] = ReorderWindow(config.reorder_window_s)

    @property
    def t(self) -> float | None:
        """Time of the filter's state (the latest packet applied)."""
        return self.filter.t

    @property
    def frame(self) -> LocalFrame | None:
        """The metric frame of the estimates."""
        return self.filter.frame

    def add(self, packet: Packet) -> list[FusedEstimate]:
        """Apply one packet in time order; return the estimates it emitted (GPS epochs, ticks).

        Raises :class:`PacketError`: ``time_backwards`` for a packet older than the window, or
        the filter's own refusal (the packet then changes nothing).
        """
        return self.window.add(self.filter, packet)

    def add_run(self, run: SampleRun, start: int = 0, last_match_t: float | None = None,
                match_interval_s: float | None = None) -> tuple[int, list[FusedEstimate]]:
        """Apply samples ``start..`` of a run as :meth:`add` would one by one, up to the
        first that emits an estimate or at which a matcher that last stepped at
        ``last_match_t`` is due again (every ``match_interval_s``; None: no matcher).
        Returns the index after the last sample taken and the estimates it emitted.

        The batched path when the road filter is initialised and the sample is not older
        than its state; else the first sample alone through :meth:`add` (which may raise
        :class:`PacketError` for it)."""
        f = self.filter
        if isinstance(f, RoadFilter) and f.state.initialized and f.state.t is not None and \
                run.rows[start, T] >= f.state.t:
            return self.window.add_run(f, run, start, True, last_match_t, match_interval_s)
        return start + 1, self.add(run.packet(start))

    def estimate(self) -> FusedEstimate | None:
        """The current estimate, or None before initialisation."""
        return self.filter.estimate()

    def correct_to_road(self, east_m: float, north_m: float, road_bearing_rad: float,
                        sigma_across_m: float, sigma_heading_rad: float,
                        probability: float = 1.0) -> bool:
        """Map feedback: the position is on the road through ``(east_m, north_m)`` with
        bearing ``road_bearing_rad`` and the heading follows it (:class:`RoadConstraint`),
        with ``probability`` that it is the road driven; False when the gate refuses it. It
        cannot be replayed: the reorder window starts again after it."""
        applied = self.filter.correct(RoadConstraint(east_m, north_m, road_bearing_rad,
                                                     sigma_across_m, sigma_heading_rad,
                                                     probability))
        if applied:
            self.window.clear()
        return applied
