"""The fixes' error as the map sees it (navsvc.fusion.gnss.MapSeenError): a running mean
square of their distance from the roads, winsorised, and what of it a sigma leaves out."""

from __future__ import annotations

import math

from hypothesis import given
from hypothesis import strategies as st

from navsvc.fusion.gnss import MIN_SIGMA_M, MapSeenError, gps_sigma_m
from navsvc.types import GpsFix

MEMORY_S = 60.0


@given(st.lists(st.tuples(st.floats(0.0, 30.0), st.floats(0.0, 2.0)), max_size=200))
def test_the_mean_square_stays_within_what_was_seen(fixes: list[tuple[float, float]]) -> None:
    seen = MapSeenError()
    for distance, dt in fixes:
        seen = seen.updated(distance, dt, MEMORY_S)
        assert 0.0 <= seen.learnt_s <= MEMORY_S
    largest = max((d for d, dt in fixes), default=0.0)
    assert 0.0 <= seen.mean_sq_m2 <= largest ** 2 + 1e-9


def test_a_steady_error_is_learnt_and_what_the_sigma_misses_is_reported() -> None:
    seen = MapSeenError()
    for _ in range(29):
        seen = seen.updated(8.0, 1.0, MEMORY_S)
    assert seen.unseen_var_m2(1.0, MEMORY_S, 10.0) == 0.0  # not half the memory yet
    seen = seen.updated(8.0, 1.0, MEMORY_S)
    assert math.isclose(seen.mean_sq_m2, 64.0)
    assert math.isclose(seen.unseen_var_m2(1.0, MEMORY_S, 10.0), 63.0)
    assert seen.unseen_var_m2(9.0, MEMORY_S, 10.0) == 0.0  # the sigma holds it already
    assert math.isclose(seen.unseen_var_m2(1.0, MEMORY_S, 5.0), 24.0)  # at most 5 m


def test_a_far_fix_counts_at_three_rms_and_a_repeated_time_not_at_all() -> None:
    seen = MapSeenError()
    for _ in range(60):
        seen = seen.updated(2.0, 1.0, MEMORY_S)
    assert seen.updated(2.0, 0.0, MEMORY_S) == seen
    far = seen.updated(30.0, 1.0, MEMORY_S)  # a non-line-of-sight fix: counted as 6 m
    assert math.isclose(far.mean_sq_m2, 4.0 + (36.0 - 4.0) / 60.0)


def test_the_variance_ratio_scales_both_ways_within_its_bounds() -> None:
    """Fixes the map sees closer to the roads than their sigma says scale the reported
    covariance down (to the floor at most); farther, up (to the cap); from 1 (nothing
    learnt) as the evidence comes, all of it from half the memory."""
    seen = MapSeenError()
    assert seen.variance_ratio(4.0, MEMORY_S, 10.0, 0.25) == 1.0  # nothing learnt
    for _ in range(15):
        seen = seen.updated(2.0, 1.0, MEMORY_S)
    assert math.isclose(seen.variance_ratio(4.0, MEMORY_S, 10.0, 0.1), (1.0 + 0.25) / 2.0)
    for _ in range(15):
        seen = seen.updated(2.0, 1.0, MEMORY_S)
    assert math.isclose(seen.variance_ratio(4.0, MEMORY_S, 10.0, 0.1), 0.25)
    assert seen.variance_ratio(8.0, MEMORY_S, 10.0, 0.25) == 0.25  # the floor
    assert math.isclose(seen.variance_ratio(1.0, MEMORY_S, 10.0, 0.25), 4.0)
    assert math.isclose(seen.variance_ratio(1.0, MEMORY_S, 1.5, 0.25), 2.25)  # the cap


@given(st.lists(st.tuples(st.floats(0.0, 30.0), st.floats(0.0, 2.0)), max_size=100),
       st.floats(0.5, 20.0), st.floats(0.05, 1.0))
def test_the_variance_ratio_agrees_with_the_unseen_variance(
        fixes: list[tuple[float, float]], sigma_m: float, floor: float) -> None:
    """Above 1 the ratio is one plus the unseen variance over the sigma's; never below the
    floor."""
    seen = MapSeenError()
    for distance, dt in fixes:
        seen = seen.updated(distance, dt, MEMORY_S)
    ratio = seen.variance_ratio(sigma_m, MEMORY_S, 10.0, floor)
    unseen = seen.unseen_var_m2(sigma_m, MEMORY_S, 10.0)
    assert ratio >= min(floor, 1.0)
    if unseen > 0.0:
        assert math.isclose(ratio, 1.0 + unseen / sigma_m ** 2, rel_tol=1e-9)


def test_a_fix_claiming_an_accuracy_no_receiver_has_counts_as_a_centimetre() -> None:
    """A client may send any accuracy above zero; squared, 5e-324 m is zero, and the
    filters divided by it (the WebSocket fuzzer's positions with non-finite numbers, and a
    ZeroDivisionError in the rules and fuzzy modes' map-seen error)."""
    fix = GpsFix(0.0, lat_deg=43.73, lon_deg=7.42, accuracy_m=5e-324)
    sigma_m = gps_sigma_m(fix, 5.0, 10.0)
    assert sigma_m == MIN_SIGMA_M
    seen = MapSeenError()
    for _ in range(59):
        seen = seen.updated(3.0, 1.0, MEMORY_S)
    assert math.isfinite(seen.variance_ratio(sigma_m, MEMORY_S, 10.0, 0.25))
