"""The start-up heading from fixes along the line an odometer drove
(navsvc.fusion.gnss.fit_track): exact on a clean line at any heading, surer the longer the
baseline, and refusing fixes that leap off the line or run faster than the odometer."""

from __future__ import annotations

import math

from hypothesis import given
from hypothesis import strategies as st

from navsvc.fusion.gnss import baseline_heading, fit_track

Fix = tuple[float, float, float, float]


def _line(heading_rad: float, distances_m: list[float], offsets_east_m: list[float] | None = None,
          rate_hz: float = 1.0) -> tuple[Fix, ...]:
    """Fixes at ``distances_m`` along a line from (100, -50) at ``heading_rad``, with an
    east error each."""
    offsets = offsets_east_m or [0.0] * len(distances_m)
    return tuple((k / rate_hz, 100.0 + d * math.sin(heading_rad) + off,
                  -50.0 + d * math.cos(heading_rad), d)
                 for k, (d, off) in enumerate(zip(distances_m, offsets, strict=True)))


@given(st.floats(0.0, 2.0 * math.pi, exclude_max=True),
       st.lists(st.floats(0.5, 20.0), min_size=1, max_size=12))
def test_a_clean_line_gives_its_heading_at_any_bearing(heading_rad: float,
                                                       steps_m: list[float]) -> None:
    distances = [0.0]
    for step in steps_m:
        distances.append(distances[-1] + step)
    fit = fit_track(_line(heading_rad, distances), 3.0)
    assert fit.agrees
    assert abs(math.remainder(fit.heading_rad - heading_rad, 2.0 * math.pi)) < 1e-6
    assert 0.0 < fit.variance_rad2


def test_the_longer_the_baseline_the_surer_the_heading() -> None:
    short = fit_track(_line(1.0, [0.0, 10.0, 20.0]), 3.0)
    long = fit_track(_line(1.0, [0.0, 20.0, 40.0]), 3.0)
    assert math.isclose(short.variance_rad2, 4.0 * long.variance_rad2)
    assert math.isclose(long.variance_rad2, 9.0 / 800.0)  # sigma^2 / sum of (d - mean d)^2


def test_fixes_faster_than_one_a_second_count_as_one_a_second() -> None:
    one_hz = fit_track(_line(0.0, [0.0, 10.0, 20.0]), 3.0)
    ten_hz = fit_track(_line(0.0, [0.0, 10.0, 20.0], rate_hz=10.0), 3.0)
    assert math.isclose(ten_hz.variance_rad2, 10.0 * one_hz.variance_rad2)


def test_a_fix_leaping_off_the_line_is_no_heading() -> None:
    fit = fit_track(_line(0.0, [0.0, 5.0, 10.0, 15.0, 20.0], [0.0, 0.0, 28.0, 0.0, 0.0]), 3.0)
    assert not fit.agrees


def test_fixes_running_faster_than_the_odometer_drove_are_no_heading() -> None:
    """The fixes' error sweeping east at 10 m/s while the car pulls away north at 2-3 m/s
    (a replayed urban-canyon start-up): a straight line, but 3 times as long as driven."""
    fit = fit_track(_line(0.0, [0.0, 1.0, 2.5, 4.5, 7.0, 10.0],
                          [-28.0, -22.0, -15.0, -8.0, 0.0, 6.0]), 3.0)
    assert not fit.agrees


def test_fixes_that_span_no_distance_say_nothing_of_the_heading() -> None:
    """Nor give a start-up heading, however far the odometer says it drove (a jump of its
    ticks, sent by the WebSocket fuzzer, started a heading with an infinite variance)."""
    for fit in (fit_track(_line(0.0, [0.0]), 3.0), fit_track(_line(0.0, [5.0, 5.0, 5.0]), 3.0)):
        assert fit.variance_rad2 == math.inf and fit.agrees
        assert baseline_heading(fit, (0.0, 5.0, 0.0, 5.0), 200.0, 5.0, 15.0, 4.0) is None


@given(st.floats(0.0, 2.0 * math.pi, exclude_max=True), st.floats(0.1, 3.0))
def test_the_fitted_distance_ratio_is_how_far_the_fixes_moved_per_odometer_metre(
        heading_rad: float, ratio: float) -> None:
    distances = [0.0, 5.0, 10.0, 15.0, 20.0]
    fixes = tuple((t, e, n, d / ratio) for t, e, n, d in _line(heading_rad, distances))
    assert math.isclose(fit_track(fixes, 3.0).distance_ratio, ratio, rel_tol=1e-9)


def test_fixes_that_moved_a_third_of_the_drive_give_no_start_up_heading() -> None:
    """Fixes sweeping across the drive (a non-line-of-sight ramp, gh-issue-70 168 of the
    tune split): 8 m along the line in the 21 m the odometer drove. The fit's own test lets
    it through at this short baseline; the distance misfit does not."""
    distances = [0.0, 5.0, 10.0, 15.0, 21.0]
    fixes = tuple((t, e, n, d / (8.0 / 21.0)) for t, e, n, d in
                  _line(0.3, [d * 8.0 / 21.0 for d in distances]))
    fit = fit_track(fixes, 3.5)
    assert fit.agrees and math.isclose(fit.distance_ratio, 8.0 / 21.0)
    ends = (fixes[0][1], fixes[0][2], fixes[-1][1], fixes[-1][2])
    assert baseline_heading(fit, ends, 21.0, 5.0, 15.0, 4.0) is not None
    assert baseline_heading(fit, ends, 21.0, 5.0, 15.0, 4.0, max_distance_misfit=0.5) is None
    clean = fit_track(_line(0.3, distances), 3.5)
    assert baseline_heading(clean, ends, 21.0, 5.0, 15.0, 4.0, max_distance_misfit=0.5) \
        is not None
