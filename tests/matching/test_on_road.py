"""The position given that the car is on a road (pure), and the session's use of it before
start-up."""

import math

import networkx as nx
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from navsvc.matching.on_road import on_road_posterior
from navsvc.matching.online import OnlineMatcher
from navsvc.session import VehicleSession
from navsvc.types import FusedEstimate
from roadgraph import RoadGraph
from tests.roadgraph.test_graph import FRAME, cross_graph

X0, Y0 = FRAME.to_local(7.42, 43.73)
ROAD_SIGMA_M = 4.0


def _north_road(length_m: float = 2000.0) -> RoadGraph:
    """One two-way road running north along x = 0, centred on the frame's origin."""
    g = nx.MultiDiGraph()
    g.add_node(0, x=X0, y=Y0 - length_m / 2.0)
    g.add_node(1, x=X0, y=Y0 + length_m / 2.0)
    g.add_edge(0, 1, name="north")
    g.add_edge(1, 0, name="north")
    return RoadGraph.from_networkx(g, FRAME)


def _posterior(graph: RoadGraph, dx: float, dy: float, sigma_m: float
               ) -> tuple[float, float, np.ndarray]:
    roads = graph.edges_near(X0 + dx, Y0 + dy, 300.0)
    found = on_road_posterior(X0 + dx, Y0 + dy, sigma_m ** 2, roads, ROAD_SIGMA_M)
    assert found is not None
    x, y, cov = found
    return x - X0, y - Y0, cov


@settings(max_examples=60, deadline=None)
@given(across_m=st.floats(-40.0, 40.0), along_m=st.floats(-100.0, 100.0),
       sigma_m=st.floats(1.0, 30.0))
def test_on_a_lone_road_the_error_across_it_shrinks_and_along_it_stays(
        across_m: float, along_m: float, sigma_m: float) -> None:
    """Far from the road's ends: across it the estimate and the road's spread combine (the
    offset shrinks by road^2 / (sigma^2 + road^2)), along it nothing is learnt."""
    x, y, cov = _posterior(_north_road(), across_m, along_m, sigma_m)
    shrink = ROAD_SIGMA_M ** 2 / (sigma_m ** 2 + ROAD_SIGMA_M ** 2)
    assert x == pytest.approx(shrink * across_m, abs=1e-6)
    assert y == pytest.approx(along_m, abs=1e-6)
    assert cov[0, 0] == pytest.approx(sigma_m ** 2 * shrink, rel=1e-6)
    assert cov[1, 1] == pytest.approx(sigma_m ** 2, rel=1e-6)
    assert cov[0, 1] == pytest.approx(0.0, abs=1e-6)


def test_a_road_stored_each_way_counts_once() -> None:
    graph = _north_road()
    both = graph.edges_near(X0 + 10.0, Y0, 50.0)
    assert len(both) == 2
    x2, y2, cov2 = on_road_posterior(X0 + 10.0, Y0, 100.0, both, ROAD_SIGMA_M) or (0, 0, None)
    x1, y1, cov1 = on_road_posterior(X0 + 10.0, Y0, 100.0, both[:1], ROAD_SIGMA_M) or (0, 0, None)
    assert (x2, y2) == pytest.approx((x1, y1))
    np.testing.assert_allclose(cov2, cov1)


def test_the_car_is_not_past_the_end_of_its_road() -> None:
    """Fixes 20 m beyond a dead end, in line with the road: the mean lies on the road, short
    of its end, and the sigma along it is less than the estimate's."""
    x, y, cov = _posterior(_north_road(200.0), 0.0, 120.0, 10.0)
    assert x == pytest.approx(0.0, abs=1e-6)
    assert 90.0 < y < 100.0
    assert cov[1, 1] < 100.0


def test_at_a_junction_the_mean_lies_among_its_roads() -> None:
    """Fixes on the node of a symmetric + junction: the mean stays there and the covariance,
    spanning the four arms, is round."""
    x, y, cov = _posterior(cross_graph(), 0.0, 0.0, 10.0)
    assert (x, y) == pytest.approx((0.0, 0.0), abs=1e-6)
    assert cov[0, 0] == pytest.approx(cov[1, 1], rel=1e-6)
    assert 0.0 < cov[0, 0] < 100.0


def test_without_a_road_there_is_no_posterior() -> None:
    assert on_road_posterior(X0, Y0, 100.0, [], ROAD_SIGMA_M) is None


@settings(max_examples=40, deadline=None)
@given(dx=st.floats(-60.0, 60.0), dy=st.floats(-60.0, 60.0), sigma_m=st.floats(1.0, 40.0))
def test_the_covariance_is_a_covariance(dx: float, dy: float, sigma_m: float) -> None:
    _, _, cov = _posterior(cross_graph(), dx, dy, sigma_m)
    assert cov[0, 1] == pytest.approx(cov[1, 0])
    assert np.all(np.linalg.eigvalsh(cov) > 0.0)


@pytest.mark.parametrize(("sigma_m", "moved"), [(10.0, True), (60.0, False)])
def test_the_matcher_places_an_unstarted_estimate_on_its_roads_within_reach(
        sigma_m: float, moved: bool) -> None:
    """An unstarted estimate 8 m east of the cross's north arm is drawn toward it; one so
    unsure that 3 sigma reach past the start-up radius is left as it is."""
    e = FusedEstimate(t=0.0, x_m=X0 + 8.0, y_m=Y0 + 50.0, heading_rad=math.nan,
                      speed_mps=0.0, yaw_rate_rps=math.nan,
                      position_cov_m2=np.eye(2) * sigma_m ** 2, heading_sigma_rad=math.inf,
                      initialized=False, gps_bias_var_m2=sigma_m ** 2)
    placed = OnlineMatcher(cross_graph()).on_road(e)
    assert (abs(placed.x_m - X0) < 8.0 * 0.5) == moved
    assert placed.tracking_sigma_m == pytest.approx(0.0, abs=1e-6)
    if not moved:
        assert placed is e


def _standstill_records(east_m: float, seconds: int) -> list[dict[str, float | str]]:
    """A car standing on the cross's north arm, 50 m up it; its fixes, 1 m sure, all
    ``east_m`` east of it (an error they share, that no fix sees)."""
    lon, lat = FRAME.to_wgs84(X0 + east_m, Y0 + 50.0)
    records: list[dict[str, float | str]] = []
    for t in range(seconds):
        records.append({"t": float(t), "kind": "odometer", "speed_mps": 0.0})
        records.append({"t": t + 0.5, "kind": "gps", "lat": lat, "lon": lon,
                        "accuracy_m": 1.0})
    return records


def test_before_start_up_the_session_reports_the_car_on_its_road() -> None:
    """Before start-up the estimate is the fixes' (12 m east of the road) and at least that
    unsure (the nearest road is 12 m off); given that the car is on a road it lies within
    2 m of it, and the 2.45-sigma circle holds that error. Without a map it stays 12 m off."""
    with_map = VehicleSession(graph=cross_graph())
    without = VehicleSession()
    records = _standstill_records(12.0, 10)
    seen = [p.estimate for p in with_map.add_records(records).positions]
    blind = [p.estimate for p in without.add_records(records).positions]
    assert len(seen) == len(blind) == 10 and not any(e.initialized for e in seen)
    for e in seen:
        error_m = math.hypot(e.x_m - X0, e.y_m - Y0 - 50.0)
        assert error_m < 2.0 and error_m <= 2.45 * e.position_sigma_m
    assert all(math.hypot(e.x_m - X0, e.y_m - Y0 - 50.0) > 11.0 for e in blind)
