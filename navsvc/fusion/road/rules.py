"""Rule-based GPS fusion (pure). Seed: Mayhew 1999, section 5.4.

The estimate is pulled toward GPS by a weighted sum instead of a Kalman gain. Parameters keep
the thesis's names and values (``GPSPosWeight`` 0.04 and ``GPSHeadingWeight`` 0.6 per second,
``m_GPSVelocityThreshold`` 2.8 m/s, ``m_GPSNoUpdateThresh`` 30 and ``..Thresh2`` 3000 fixes); the
distance threshold, stated in squared milliarcseconds for SA-era GPS, is in metres here.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass


class GpsAction(enum.Enum):
    INITIALIZE = "initialize"  # take position (and heading) from GPS
    BLEND = "blend"  # weighted sum of estimate and GPS
    REJECT = "reject"  # dead reckoning only
    REINITIALIZE = "reinitialize"  # estimate is lost: restart from GPS


@dataclass(frozen=True)
class GpsDecision:
    action: GpsAction
    position_weight: float  # per fix, in [0, 1]
    heading_weight: float
    reason: str
    heading_lost: bool = False  # a restart of an estimate that was lost: its heading too


@dataclass(frozen=True)
class RuleParams:
    position_weight_per_s: float = 0.04  # GPSPosWeight
    heading_weight_per_s: float = 0.6  # GPSHeadingWeight
    min_speed_for_heading_mps: float = 2.8  # m_GPSVelocityThreshold
    stopped_speed_mps: float = 0.5  # below: GPS heading ignored (receiver heading wanders)
    max_distance_m: float = 50.0  # GPSPosThreshold: farther fixes are not fused
    widen_after_fixes: int = 30  # m_GPSNoUpdateThresh: good but too far this long → widen
    widen_factor: float = 1.5  # threshold growth per further rejected fix
    reinit_after_fixes: int = 3000  # m_GPSNoUpdateThresh2: good, far too far this long → restart


def per_fix_weight(weight_per_s: float, dt_s: float) -> float:
    """A per-second weight applied over ``dt_s``: ``1 - (1 - w)^dt``."""
    return float(1.0 - (1.0 - min(max(weight_per_s, 0.0), 1.0)) ** max(dt_s, 0.0))


def decide_rules(
    p: RuleParams, *, gps_ok: bool, initialized: bool, distance_m: float,
    gps_speed_mps: float | None, rejected_fixes: int, dt_s: float,
) -> GpsDecision:
    """The thesis's rules, in its order of precedence."""
    if not gps_ok:
        return GpsDecision(GpsAction.REJECT, 0.0, 0.0, "receiver reports a bad fix")
    if not initialized:
        return GpsDecision(GpsAction.INITIALIZE, 1.0, 1.0, "first good fix")
    speed = gps_speed_mps if gps_speed_mps is not None else 0.0
    heading_w = per_fix_weight(p.heading_weight_per_s, dt_s) \
        if speed >= p.min_speed_for_heading_mps else 0.0
    threshold = p.max_distance_m
    if rejected_fixes >= p.widen_after_fixes:
        threshold *= p.widen_factor ** min(rejected_fixes - p.widen_after_fixes + 1, 20)
    if distance_m <= threshold:
        pos_w = per_fix_weight(p.position_weight_per_s, dt_s)
        if speed < p.stopped_speed_mps:
            return GpsDecision(GpsAction.BLEND, pos_w, 0.0, "stopped: GPS heading ignored")
        return GpsDecision(GpsAction.BLEND, pos_w, heading_w, "close to the estimate")
    if rejected_fixes >= p.reinit_after_fixes:
        return GpsDecision(GpsAction.REINITIALIZE, 1.0, 1.0, "far from the estimate too long")
    return GpsDecision(GpsAction.REJECT, 0.0, 0.0,
                       f"gated: {distance_m:.0f} m from the estimate (> {threshold:.0f} m)")
