"""The scorecard on hand-made runs: the 2.45-sigma circle, the error while GPS is present, and
the targets' verdicts."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import pytest

from navsvc.sim.scorecard import (
    PHASES,
    Scorecard,
    check,
    circle_by_phase,
    consistency,
    fixes_to_recover,
    max_error_with_gps_m,
    output_share,
    pooled_circle_share,
    score,
)
from roadgraph import LocalFrame

LON, LAT = 7.42, 43.73
FRAME = LocalFrame.for_point(LON, LAT)
X0, Y0 = FRAME.to_local(LON, LAT)


def _at(t: float, dx: float = 0.0, **extra: Any) -> dict[str, Any]:
    lon, lat = FRAME.to_wgs84(X0 + dx, Y0)
    return {"t": t, "lat": lat, "lon": lon, **extra}


DRIVE = [_at(float(t), kind="truth", heading_deg=90.0, u=1, v=2) for t in range(11)] + \
    [_at(float(t), kind="gps") for t in (0, 1, 2, 3, 8, 9, 10)]  # no GPS from 3 to 8


def _estimate(t: float, error_m: float, sigma_m: float) -> dict[str, Any]:
    fused = _at(t, error_m)
    return {**_at(t, error_m), "fused_lat": fused["lat"], "fused_lon": fused["lon"],
            "position_sigma_m": sigma_m}


def test_circle_share_and_normalised_error() -> None:
    estimates = [_estimate(float(t), e, 1.0) for t, e in enumerate([0.0, 1.0, 2.4, 2.5])]
    share, nees, epochs = consistency(DRIVE, estimates)
    assert share == 0.5 + 0.25  # 2.5 m is outside 2.45 sigma
    assert epochs == 4
    assert nees == pytest.approx((0 + 1 + 2.4 ** 2 + 2.5 ** 2) / 4 / 2, rel=1e-4)


def test_the_circle_by_phase_counts_each_epoch_in_the_first_phase_that_fits() -> None:
    """80 s with a planned outage from 35 to 45 s and another gap from 60 to 65 s; one
    epoch in each phase lies outside 2.45 sigma."""
    drive = [_at(float(t), kind="truth", heading_deg=90.0, u=1, v=2) for t in range(81)] + \
        [_at(float(t), kind="gps") for t in range(81) if not (35 <= t < 45 or 60 <= t < 65)]
    outside = {5, 15, 40, 47, 62, 70}
    estimates = [_estimate(float(t), 3.0 if t in outside else 0.0, 1.0) for t in range(81)]
    counts = circle_by_phase(drive, estimates, 35.0, 10.0)
    assert list(counts) == list(PHASES)
    assert list(counts.values()) == [(9, 10), (19, 20), (9, 10), (9, 10), (4, 5), (25, 26)]


def test_max_error_counts_only_epochs_with_a_fix_in_the_second_before() -> None:
    estimates = [_estimate(2.0, 10.0, 1.0), _estimate(3.5, 20.0, 1.0),
                 _estimate(5.0, 99.0, 1.0), _estimate(9.0, 30.0, 1.0)]
    assert max_error_with_gps_m(DRIVE, estimates) == pytest.approx(30.0, abs=1e-3)


def _card(ratio: float, drift: float, circle: float, err: float) -> Scorecard:
    return Scorecard(ratio, drift, circle, 1.0, err, 1.0, 1.0, 1.0, 1.0)


def test_targets_met_and_missed() -> None:
    good = [_card(0.5, 1.5, 0.95, 20.0), _card(0.6, 2.0, 0.92, 30.0), _card(0.4, 3.9, 0.97, 5.0)]
    assert all(met for *_, met in check(good))
    bad = [*good, _card(0.95, 5.0, 0.5, 51.0)]
    verdicts = {name: (worst, met) for name, _, worst, _, met in check(bad)}
    assert verdicts == {"fused_to_raw_ratio": (0.95, False), "outage_drift_pct": (5.0, False),
                        "circle_share": (0.5, False),
                        "max_matched_error_with_gps_m": (51.0, False)}


def test_the_pooled_circle_share_weighs_each_drive_by_its_epochs() -> None:
    long_drive = replace(_card(0.5, 1.0, 0.95, 5.0), circle_epochs=300)
    short_drive = replace(_card(0.5, 1.0, 0.5, 5.0), circle_epochs=100)
    unscored = _card(0.5, 1.0, math.nan, 5.0)
    unscored = replace(unscored, circle_share=None, circle_epochs=0)
    assert pooled_circle_share([long_drive, short_drive, unscored]) == \
        pytest.approx((0.95 * 300 + 0.5 * 100) / 400)
    assert pooled_circle_share([unscored]) is None


def test_no_scores_is_not_a_pass() -> None:
    card = Scorecard(math.nan, None, None, None, None, None, math.nan, math.nan, 1.0)
    assert not any(met for *_, met in check([card]))


def test_output_share_counts_the_seconds_with_an_estimate() -> None:
    estimates = [_estimate(t, 1.0, 1.0) for t in (2.0, 2.5, 3.2, 7.9)]
    assert output_share(DRIVE, estimates) == pytest.approx(3 / 10)
    assert output_share(DRIVE, []) == 0.0


def test_a_drive_without_output_fails_the_ratio_instead_of_dropping_out() -> None:
    silent = score(DRIVE, [], outage_start_s=3.0)
    assert silent.output_share == 0.0 and silent.fused_to_raw_ratio == math.inf
    verdicts = {name: (worst, met) for name, _, worst, _, met in
                check([_card(0.5, 1.5, 0.95, 20.0), silent])}
    assert verdicts["fused_to_raw_ratio"] == (math.inf, False)


def test_fixes_to_recover_count_the_fixes_after_the_outage_until_the_estimate_is_back() -> None:
    estimates = [_estimate(8.0, 30.0, 1.0), _estimate(9.0, 5.0, 1.0),
                 _estimate(10.0, 1.0, 1.0)]
    assert fixes_to_recover(DRIVE, estimates, 3.0, 10.0) == 2.0  # 8 s: 30 m; 9 s: 5 m
    assert fixes_to_recover(DRIVE, estimates, 3.0, 0.5) == math.inf  # never that close
    assert fixes_to_recover(DRIVE, estimates, 10.0, 10.0) is None  # no fix after 10 s


def test_fixes_faster_than_one_a_second_count_once_a_second() -> None:
    drive = [*DRIVE, *(_at(8.0 + k / 10.0, kind="gps") for k in range(1, 10))]  # 10 Hz
    estimates = [_estimate(8.0 + k / 10.0, 30.0 if k < 10 else 5.0, 1.0) for k in range(11)]
    assert fixes_to_recover(drive, estimates, 3.0, 10.0) == 2.0
