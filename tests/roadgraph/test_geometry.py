import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from roadgraph.geometry import (
    LocalFrame,
    bearing_rad,
    end_bearings_rad,
    normalize_bearing_rad,
    point_at_offset,
    polyline_length_m,
    project_onto_polyline,
    turn_angle_rad,
    utm_crs_for,
    wrap_angle_rad,
)

coord = st.floats(-1000.0, 1000.0, allow_nan=False)
polylines = st.lists(st.tuples(coord, coord), min_size=2, max_size=8).map(
    lambda pts: np.array(pts, dtype=np.float64))


def test_bearing_compass_convention() -> None:
    assert bearing_rad(0, 0, 0, 10) == pytest.approx(0.0)
    assert bearing_rad(0, 0, 10, 0) == pytest.approx(math.pi / 2)
    assert bearing_rad(0, 0, 0, -10) == pytest.approx(math.pi)
    assert bearing_rad(0, 0, -10, 0) == pytest.approx(3 * math.pi / 2)


def test_turn_angle_right_positive_left_negative() -> None:
    north, east, west = 0.0, math.pi / 2, 3 * math.pi / 2
    assert turn_angle_rad(north, east) == pytest.approx(math.pi / 2)
    assert turn_angle_rad(north, west) == pytest.approx(-math.pi / 2)
    assert turn_angle_rad(west, north) == pytest.approx(math.pi / 2)
    assert turn_angle_rad(0.1, 2 * math.pi - 0.1) == pytest.approx(-0.2)


def test_projection_on_an_l_shape() -> None:
    coords = np.array([[0.0, 0.0], [100.0, 0.0], [100.0, 50.0]])
    p = project_onto_polyline(coords, 40.0, 3.0)
    assert (p.offset_m, p.distance_m, p.x_m, p.y_m) == pytest.approx((40.0, 3.0, 40.0, 0.0))
    assert p.bearing_rad == pytest.approx(math.pi / 2)
    p = project_onto_polyline(coords, 104.0, 20.0)
    assert (p.offset_m, p.distance_m) == pytest.approx((120.0, 4.0))
    assert p.bearing_rad == pytest.approx(0.0)
    p = project_onto_polyline(coords, -10.0, 0.0)
    assert (p.offset_m, p.distance_m) == pytest.approx((0.0, 10.0))


def test_projection_skips_zero_length_segments_for_bearing() -> None:
    coords = np.array([[0.0, 0.0], [0.0, 0.0], [0.0, 10.0]])
    assert project_onto_polyline(coords, 0.0, -5.0).bearing_rad == pytest.approx(0.0)


def test_end_bearings_use_the_first_and_last_stretch() -> None:
    # a 1 m kink at the start does not decide the leaving direction
    coords = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 100.0], [101.0, 100.0]])
    start, end = end_bearings_rad(coords, reach_m=20.0)
    assert math.degrees(start) == pytest.approx(math.degrees(math.atan2(1, 19)), abs=0.01)
    assert end == pytest.approx(math.pi / 2)


@given(polylines, coord, coord)
def test_projection_properties(coords: np.ndarray, x: float, y: float) -> None:
    p = project_onto_polyline(coords, x, y)
    length = polyline_length_m(coords)
    assert -1e-9 <= p.offset_m <= length + 1e-6
    vertex_dist = np.hypot(coords[:, 0] - x, coords[:, 1] - y).min()
    assert p.distance_m <= vertex_dist + 1e-6
    assert math.hypot(p.x_m - x, p.y_m - y) == pytest.approx(p.distance_m, abs=1e-6)
    assert 0.0 <= p.bearing_rad < 2 * math.pi
    # the projected point lies on the polyline at the reported offset
    px, py, _ = point_at_offset(coords, p.offset_m)
    assert math.hypot(px - p.x_m, py - p.y_m) < 1e-5


@given(st.floats(-100.0, 100.0))
def test_angle_wrapping(a: float) -> None:
    w = wrap_angle_rad(a)
    assert -math.pi < w <= math.pi
    assert math.isclose(math.sin(w), math.sin(a), abs_tol=1e-9)
    assert math.isclose(math.cos(w), math.cos(a), abs_tol=1e-9)
    b = normalize_bearing_rad(a)
    assert 0.0 <= b < 2 * math.pi


def test_utm_zone() -> None:
    assert utm_crs_for(7.42, 43.73).to_epsg() == 32632
    assert utm_crs_for(-104.99, 39.75).to_epsg() == 32613
    assert utm_crs_for(151.2, -33.9).to_epsg() == 32756


_FRAME = LocalFrame.for_point(7.42, 43.73)


@given(st.floats(7.0, 8.0), st.floats(43.0, 44.5))
def test_frame_round_trip_within_a_millimetre(lon: float, lat: float) -> None:
    x, y = _FRAME.to_local(lon, lat)
    lon2, lat2 = _FRAME.to_wgs84(x, y)
    x2, y2 = _FRAME.to_local(lon2, lat2)
    assert math.hypot(x2 - x, y2 - y) < 1e-3


def test_frame_arrays_match_scalars() -> None:
    lonlat = np.array([[7.41, 43.73], [7.43, 43.74]])
    local = _FRAME.coords_to_local(lonlat)
    assert local[1] == pytest.approx(_FRAME.to_local(7.43, 43.74))
    assert _FRAME.coords_to_wgs84(local) == pytest.approx(lonlat)
