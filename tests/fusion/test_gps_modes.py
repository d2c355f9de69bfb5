import pytest

from navsvc.fusion.road.fuzzy import THESIS_SETS, fuzzy_weights, rule_strengths, trapezoid
from navsvc.fusion.road.rules import GpsAction, RuleParams, decide_rules, per_fix_weight


def test_trapezoid() -> None:
    t = (2.0, 2.5, 3.0, 3.5)
    assert [trapezoid(v, t) for v in (1.0, 2.25, 2.75, 3.25, 4.0)] == [0, 0.5, 1, 0.5, 0]
    assert trapezoid(1e9, (2.5, 3.0, float("inf"), float("inf"))) == 1.0


def test_fuzzy_close_and_fast_gives_large_weight() -> None:
    strengths = rule_strengths(THESIS_SETS, 2.0, 10.0, 0)
    assert strengths == {"LARGE": 1.0, "MED": 0.0, "SMALL": 0.0, "ZERO": 0.0, "ONE": 0.0}
    pos, head = fuzzy_weights(THESIS_SETS, 2.0, 10.0, 0)
    assert 0.03 < pos < 0.06 and 0.5 < head < 0.8


def test_fuzzy_far_and_long_rejected_recovers() -> None:
    pos, _ = fuzzy_weights(THESIS_SETS, 500.0, 10.0, 5000)
    assert pos > 0.99
    pos, _ = fuzzy_weights(THESIS_SETS, 500.0, 10.0, 0)
    assert pos < 0.002


def test_rules_in_thesis_order() -> None:
    p = RuleParams()
    common = dict(initialized=True, rejected_fixes=0, dt_s=1.0)
    assert decide_rules(p, gps_ok=False, distance_m=1, gps_speed_mps=10, **common).action \
        == GpsAction.REJECT
    assert decide_rules(p, gps_ok=True, initialized=False, distance_m=0, gps_speed_mps=0,
                        rejected_fixes=0, dt_s=1.0).action == GpsAction.INITIALIZE
    d = decide_rules(p, gps_ok=True, distance_m=5, gps_speed_mps=10, **common)
    assert d.action == GpsAction.BLEND
    assert (d.position_weight, d.heading_weight) == pytest.approx((0.04, 0.6))
    d = decide_rules(p, gps_ok=True, distance_m=5, gps_speed_mps=0.1, **common)
    assert d.heading_weight == 0.0 and "stopped" in d.reason
    assert decide_rules(p, gps_ok=True, distance_m=80, gps_speed_mps=10, **common).action \
        == GpsAction.REJECT
    widened = decide_rules(p, gps_ok=True, initialized=True, distance_m=80, gps_speed_mps=10,
                           rejected_fixes=31, dt_s=1.0)
    assert widened.action == GpsAction.BLEND
    assert decide_rules(p, gps_ok=True, initialized=True, distance_m=1e6, gps_speed_mps=10,
                        rejected_fixes=3000, dt_s=1.0).action == GpsAction.REINITIALIZE


def test_per_fix_weight() -> None:
    assert per_fix_weight(0.04, 1.0) == pytest.approx(0.04)
    assert per_fix_weight(0.04, 2.0) == pytest.approx(1 - 0.96 ** 2)
