"""How far the fixes' path is turned from the dead-reckoned one
(navsvc.fusion.gnss.turn_between_paths): a heading error turns the path, a
non-line-of-sight offset only shifts it."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from navsvc.fusion.gnss import turn_between_paths


def _path(heading_rad: float, turn_rate_rps: float, steps: int) -> np.ndarray:
    """A car driving 10 m a second from (0, 0), turning at ``turn_rate_rps``."""
    headings = heading_rad + turn_rate_rps * np.arange(steps)
    steps_m = 10.0 * np.column_stack([np.sin(headings), np.cos(headings)])
    return np.cumsum(steps_m, axis=0)


def _turned(path: np.ndarray, angle_rad: float) -> np.ndarray:
    """``path`` turned clockwise (as a heading turns) about the origin."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.column_stack([c * path[:, 0] + s * path[:, 1], -s * path[:, 0] + c * path[:, 1]])


@given(st.floats(0.0, 2.0 * math.pi), st.floats(-0.1, 0.1),
       st.floats(-3.1, 3.1), st.floats(-100.0, 100.0), st.floats(-100.0, 100.0))
def test_a_turned_and_shifted_path_gives_its_turn(heading_rad: float, turn_rate_rps: float,
                                                  angle_rad: float, east_m: float,
                                                  north_m: float) -> None:
    dead_reckoned = _path(heading_rad, turn_rate_rps, 12)
    fixes = _turned(dead_reckoned, angle_rad) + [east_m, north_m]
    turn = turn_between_paths(dead_reckoned, fixes, 3.0)
    assert abs(math.remainder(turn.angle_rad - angle_rad, 2.0 * math.pi)) < 1e-6
    assert turn.misfit_m < 1e-6


def test_a_shifted_path_is_not_turned() -> None:
    dead_reckoned = _path(0.5, 0.05, 12)
    turn = turn_between_paths(dead_reckoned, dead_reckoned + [30.0, -40.0], 3.0)
    assert abs(turn.angle_rad) < 1e-9
    assert turn.misfit_m < 1e-9
    assert turn.shift_misfit_m < 1e-9  # the shift is taken out: the misfit of a shift alone


def test_a_turned_path_lies_far_from_the_one_only_shifted() -> None:
    dead_reckoned = _path(0.0, 0.0, 11)  # 100 m north
    turn = turn_between_paths(dead_reckoned, _turned(dead_reckoned, math.pi / 2.0), 3.0)
    assert math.isclose(turn.angle_rad, math.pi / 2.0)
    assert turn.shift_misfit_m > 40.0


def test_the_longer_the_path_the_surer_the_turn() -> None:
    short, long = _path(0.0, 0.0, 5), _path(0.0, 0.0, 9)
    var_short = turn_between_paths(short, short, 3.0).variance_rad2
    var_long = turn_between_paths(long, long, 3.0).variance_rad2
    assert math.isclose(var_short, 9.0 / 1000.0)  # sigma^2 / sum of squares about the mean
    assert var_long < var_short / 5.0


def test_a_path_standing_still_says_nothing() -> None:
    standing = np.zeros((6, 2))
    turn = turn_between_paths(standing, standing + [5.0, 5.0], 3.0)
    assert math.isinf(turn.variance_rad2)
