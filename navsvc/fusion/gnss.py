"""GNSS fixes as both filters read them (pure): is a fix good, and how good is it.

Seed: Mayhew 1999, section 5.4 (validity from the receiver status: a fix is bad if the
receiver says so, there is no 2D/3D fix, fewer than 3 satellites are visible, or DOP > 20).
"""

from __future__ import annotations

from navsvc.types import GpsFix, GpsFixType

# A fix type alone says little: only the corrected solutions are trusted by type (a plain 3D
# fix in a street canyon is off by tens of metres as often as not).
_FIX_SIGMA_M = {GpsFixType.RTK: 0.05, GpsFixType.DGPS: 1.0}


def gps_problem(fix: GpsFix, min_sats: int, max_hdop: float) -> str | None:
    """Why a fix is bad (thesis validity rules), or None when it is good."""
    if not fix.status_ok:
        return "receiver status bad"
    if fix.fix == GpsFixType.NONE:
        return "no fix"
    if fix.sats is not None and fix.sats < min_sats:
        return f"{fix.sats} satellites (< {min_sats})"
    if fix.hdop is not None and fix.hdop > max_hdop:
        return f"HDOP {fix.hdop:g} (> {max_hdop:g})"
    return None


def gps_sigma_m(fix: GpsFix, uere_m: float, default_sigma_m: float) -> float:
    """1-σ horizontal error of a fix: its own accuracy, else HDOP × UERE, else by fix type
    (RTK, DGPS), else the conservative ``default_sigma_m``."""
    if fix.accuracy_m is not None and fix.accuracy_m > 0.0:
        return fix.accuracy_m
    if fix.hdop is not None and fix.hdop > 0.0:
        return fix.hdop * uere_m
    if fix.fix in _FIX_SIGMA_M:
        return _FIX_SIGMA_M[fix.fix]
    return default_sigma_m
