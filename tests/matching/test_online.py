"""The online matcher on a hand-made + junction (pure, no I/O)."""

import math

import networkx as nx
import numpy as np
import pytest

from navsvc.errors import ConfigError
from navsvc.matching.online import MatcherConfig, OnlineMatcher
from navsvc.types import FusedEstimate, MatchedPosition, MatchState
from roadgraph import EdgeKey, RoadGraph
from tests.roadgraph.test_graph import FRAME, cross_graph

X0, Y0 = FRAME.to_local(7.42, 43.73)


def estimate(t: float, x: float, y: float, heading_deg: float, speed: float = 8.0,
             sigma_m: float = 3.0) -> FusedEstimate:
    return FusedEstimate(t=t, x_m=X0 + x, y_m=Y0 + y, heading_rad=math.radians(heading_deg),
                         speed_mps=speed, yaw_rate_rps=0.0,
                         position_cov_m2=np.eye(2) * sigma_m ** 2,
                         heading_sigma_rad=math.radians(2.0))


def drive_turn(graph: RoadGraph, turn_to: str, heading_bias_deg: float = 0.0,
               lateral_m: float = 0.0) -> list[MatchedPosition]:
    """From 90 m south of the junction northward at 8 m/s, then east or on north, at 10 Hz."""
    matcher = OnlineMatcher(graph)
    out, t = [], 0.0
    for k in range(113):  # 90 m north
        y = -90.0 + 0.8 * k
        out.append(matcher.update(estimate(t, lateral_m, min(y, 0.0), heading_bias_deg)))
        t += 0.1
    for k in range(1, 100):  # 80 m more, east or north
        d = 0.8 * k
        x, y, h = (d, lateral_m, 90.0) if turn_to == "east" else (lateral_m, d, 0.0)
        out.append(matcher.update(estimate(t, x, y, h + heading_bias_deg)))
        t += 0.1
    return out


def edge_of(p: MatchedPosition) -> tuple[int, int] | None:
    return None if p.edge is None else (p.edge.u, p.edge.v)


@pytest.mark.parametrize(("turn_to", "last_edge"), [("east", (0, 2)), ("north", (0, 1))])
@pytest.mark.parametrize("bias_deg", [0.0, 12.0, -12.0])
def test_turn_and_straight_through(turn_to: str, last_edge: tuple[int, int],
                                   bias_deg: float) -> None:
    out = drive_turn(cross_graph(), turn_to, heading_bias_deg=bias_deg, lateral_m=2.0)
    assert edge_of(out[0]) == (3, 0)
    assert edge_of(out[-1]) == last_edge and out[-1].state == MatchState.ON_ROAD
    # the matched point lies on the road, offset grows along it, next node is its end
    assert out[-1].distance_to_road_m == pytest.approx(2.0, abs=0.01)
    assert out[-1].next_node == last_edge[1]
    assert out[-1].distance_to_next_node_m == pytest.approx(100.0 - 79.2, abs=0.5)


def test_no_u_turn_and_oneway_respected_in_candidates() -> None:
    out = drive_turn(cross_graph(), "east")
    seen = {(c.u, c.v) for p in out for c, _ in p.candidates}
    assert (0, 3) not in seen and (0, 4) not in seen
    for p in out:
        if p.candidates:
            assert sum(prob for _, prob in p.candidates) == pytest.approx(1.0)


def test_ambiguity_radius_rule() -> None:
    graph = cross_graph()  # longest adjacent-node distance 100 m → 4 m from the seed rule
    matcher = OnlineMatcher(graph, MatcherConfig(min_radius_m=10.0, max_radius_m=30.0))
    assert matcher.ambiguity_radius_m(1.0) == 10.0  # clamped up
    assert matcher.ambiguity_radius_m(5.0) == 15.0  # 3 sigma
    assert matcher.ambiguity_radius_m(50.0) == 30.0  # clamped down
    with pytest.raises(ConfigError):
        MatcherConfig(min_radius_m=40.0, max_radius_m=30.0)


def test_initializing_then_startup_picks_road_by_heading() -> None:
    matcher = OnlineMatcher(cross_graph())
    e = estimate(0.0, 1.0, -50.0, 0.0)
    first = matcher.update(FusedEstimate(**{**e.__dict__, "initialized": False}))
    # before start-up: the nearest road by distance alone, in either direction ...
    assert first.state == MatchState.INITIALIZING and edge_of(first) in {(0, 3), (3, 0)}
    assert first.distance_to_road_m == pytest.approx(1.0)  # the estimate, 1 m east of it
    assert edge_of(matcher.update(e)) == (3, 0)  # ... not taken: heading north, northbound
    other = OnlineMatcher(cross_graph())
    assert edge_of(other.update(estimate(0.0, 1.0, -50.0, 180.0))) == (0, 3)


def test_before_start_up_no_road_is_reported_beyond_the_start_up_radius() -> None:
    far = estimate(0.0, 200.0, -200.0, 0.0)
    first = OnlineMatcher(cross_graph()).update(FusedEstimate(**{**far.__dict__,
                                                                "initialized": False}))
    assert first.state == MatchState.INITIALIZING and first.edge is None
    assert (first.x_m, first.y_m) == (far.x_m, far.y_m)


def test_off_road_after_a_while_then_back() -> None:
    matcher = OnlineMatcher(cross_graph())
    matcher.update(estimate(0.0, 0.0, -50.0, 0.0))
    states = [matcher.update(estimate(8.0 + 0.1 * k, 60.0, -60.0, 0.0)).state
              for k in range(1, 60)]  # 60 m off, 8 s later: where its speed could take it
    assert states[0] == MatchState.ON_ROAD  # not at once
    assert states[-1] == MatchState.OFF_ROAD
    back = matcher.update(estimate(15.0, 0.5, -40.0, 0.0))
    assert back.state == MatchState.ON_ROAD and edge_of(back) == (3, 0)


def test_an_estimate_that_jumps_far_from_its_road_leaves_it_at_once() -> None:
    """Beyond the start-up search radius the road is no longer the one driven: no "on road"
    150 m from it, where a nearer drift waits ``off_road_after_s``."""
    matcher = OnlineMatcher(cross_graph())
    matcher.update(estimate(0.0, 0.0, -50.0, 0.0))
    jumped = matcher.update(estimate(0.1, 160.0, -50.0, 0.0))
    assert jumped.state == MatchState.OFF_ROAD and jumped.edge is None
    back = matcher.update(estimate(0.2, 95.0, 1.0, 90.0))  # onto the east arm, at once
    assert back.state == MatchState.ON_ROAD and edge_of(back) == (0, 2)


def test_lost_when_moving_against_the_road() -> None:
    matcher = OnlineMatcher(cross_graph())
    matcher.update(estimate(0.0, 0.0, -80.0, 0.0))
    states = [matcher.update(estimate(0.1 * k, 0.0, -80.0 + 0.8 * k, 90.0)).state
              for k in range(1, 50)]
    assert MatchState.LOST in states


def test_the_wrong_branch_of_a_narrow_fork_is_left_for_the_right_one() -> None:
    """Two roads leave a node 12° apart: matched to the wrong one, the vehicle is never far
    enough off it (30 m) nor heading against it to be off road or lost, but after a couple of
    seconds holding far less of the likelihood than the road it runs along (9 m off), the
    matcher starts up again on the right one (before ``rival_share``, 15 m off: clearly off
    it for its sigma)."""
    g = nx.MultiDiGraph()
    fork = math.radians(12.0)
    pos = {0: (0.0, 0.0), 1: (0.0, 300.0), 2: (300.0 * math.sin(fork), 300.0 * math.cos(fork))}
    for n, (dx, dy) in pos.items():
        g.add_node(n, x=X0 + dx, y=Y0 + dy)
    g.add_edge(0, 1, name="north")
    g.add_edge(0, 2, name="north-north-east")
    matcher = OnlineMatcher(RoadGraph.from_networkx(g, FRAME))
    assert edge_of(matcher.update(estimate(0.0, 0.0, 10.0, 0.0))) == (0, 1)  # the wrong one
    matched = {}
    for k in range(1, 300):  # along the 12° road at 8 m/s, 10 Hz
        d = 10.0 + 0.8 * k
        p = matcher.update(estimate(0.1 * k, d * math.sin(fork), d * math.cos(fork), 12.0))
        matched[round(d)] = edge_of(p)
    assert matched[30] == (0, 1)  # 6 m off: between the two, no reason to doubt yet
    assert all(matched[d] == (0, 2) for d in range(50, 240, 10))


def test_standing_in_the_region_keeps_what_the_turn_showed() -> None:
    """Turned east into the junction, the car stops 2 m in; its positions scatter nearer the
    north arm. Standing tells nothing new, so the east road stays the one reported."""
    matcher = OnlineMatcher(cross_graph())
    t = 0.0
    for k in range(113):  # north up to the junction at 8 m/s, 10 Hz
        matcher.update(estimate(t, 0.0, min(-90.0 + 0.8 * k, 0.0), 0.0))
        t += 0.1
    for k in range(1, 4):  # the turn: a few metres east
        matcher.update(estimate(t, 0.8 * k, 0.0, 90.0))
        t += 0.1
    standing = []
    for k in range(60):
        standing.append(matcher.update(estimate(t, 2.0, 2.5 if k % 2 else 1.5, 90.0,
                                                speed=0.0)))
        t += 0.1
    assert all(edge_of(p) == (0, 2) for p in standing)


def _graph(nodes: dict[int, tuple[float, float]],
           edges: list[tuple[int, int, list[tuple[float, float]]]]) -> RoadGraph:
    """Nodes at (dx, dy) from the frame's origin; one-way edges through interior points."""
    from shapely.geometry import LineString
    g = nx.MultiDiGraph()
    for n, (dx, dy) in nodes.items():
        g.add_node(n, x=X0 + dx, y=Y0 + dy)
    for u, v, via in edges:
        points = [nodes[u], *via, nodes[v]]
        g.add_edge(u, v, oneway=True,
                   geometry=LineString([(X0 + dx, Y0 + dy) for dx, dy in points]))
    return RoadGraph.from_networkx(g, FRAME)


def _along(points: list[tuple[float, float]], step_m: float) -> list[tuple[float, float, float]]:
    """Points every ``step_m`` along a polyline, with the heading there (degrees)."""
    out = []
    for (xa, ya), (xb, yb) in zip(points, points[1:], strict=False):
        length = math.hypot(xb - xa, yb - ya)
        heading = math.degrees(math.atan2(xb - xa, yb - ya)) % 360.0
        out += [(xa + (xb - xa) * s / length, ya + (yb - ya) * s / length, heading)
                for s in np.arange(0.0, length, step_m)]
    return out


def test_a_loop_back_to_the_junction_is_followed() -> None:
    """A one-way turning loop (Andorra has one): up its east side to the far node, back down
    its west side to the junction, and away the way the car came. The way back is not a
    U-turn (it turns 45° from the east side), so it must be among the region's hypotheses;
    when it was not, the match stood at the far node while the car drove on."""
    east = [(15.0, 10.0), (20.0, 20.0), (15.0, 30.0)]
    west = [(-15.0, 30.0), (-20.0, 20.0), (-15.0, 10.0)]
    graph = _graph({0: (0.0, -100.0), 1: (0.0, 0.0), 3: (0.0, 40.0), 4: (0.0, 140.0)},
                   [(0, 1, []), (1, 0, []), (1, 3, east), (3, 1, west), (3, 4, []), (4, 3, [])])
    path = [(0.0, -100.0), (0.0, 0.0), *east, (0.0, 40.0), *west, (0.0, 0.0), (0.0, -100.0)]
    matcher = OnlineMatcher(graph, MatcherConfig(min_radius_m=25.0))  # 2 r + 20 m spans the loop
    worst = 0.0
    for k, (x, y, heading) in enumerate(_along(path, 0.8)):
        p = matcher.update(estimate(0.1 * k, x, y, heading))
        worst = max(worst, math.hypot(p.x_m - (X0 + x), p.y_m - (Y0 + y)))
    assert edge_of(p) == (1, 0) and p.state == MatchState.ON_ROAD
    assert worst < 5.0


def test_a_road_no_hypothesis_leads_to_is_found_again_soon() -> None:
    """Matched to the wrong one of two parallel roads 8 m apart, the car drives on where the
    wrong one turns off. None of the region's roads leads on, so after ``poor_fit_after_s``
    clearly off them all the matcher starts up again, rather than waiting to be 30 m off for
    3 s (the match stood still at the junction for some 50 m)."""
    graph = _graph({0: (0.0, -100.0), 1: (0.0, 0.0), 2: (0.0, 100.0), 5: (8.0, -100.0),
                    6: (8.0, 0.0), 7: (100.0, 0.0)},
                   [(0, 1, []), (1, 2, []), (5, 6, []), (6, 7, [])])
    matcher = OnlineMatcher(graph)
    assert edge_of(matcher.update(estimate(0.0, 5.0, -90.0, 0.0))) == (5, 6)  # the wrong one
    matched = {}
    for k in range(1, 220):  # north at 8 m/s, 10 Hz, 2 m beside the right road
        y = -90.0 + 0.8 * k
        p = matcher.update(estimate(0.1 * k, 2.0, y, 0.0))
        matched[round(y)] = (edge_of(p), math.hypot(p.x_m - (X0 + 2.0), p.y_m - (Y0 + y)))
    assert matched[-50][0] == (5, 6)  # 6 m off: within its sigma, no reason to doubt yet
    assert matched[40][0] == (1, 2)
    assert max(error for _, error in matched.values()) < 40.0


def _two_parallel_roads() -> RoadGraph:
    """Two two-way roads running north, 300 m long, 20 m apart (x = 0 and x = 20)."""
    g = nx.MultiDiGraph()
    pos = {0: (0.0, -150.0), 1: (0.0, 150.0), 2: (20.0, -150.0), 3: (20.0, 150.0)}
    for n, (dx, dy) in pos.items():
        g.add_node(n, x=X0 + dx, y=Y0 + dy)
    for u, v in ((0, 1), (2, 3)):
        g.add_edge(u, v, name=f"road{u}")
        g.add_edge(v, u, name=f"road{u}")
    return RoadGraph.from_networkx(g, FRAME)


@pytest.mark.parametrize(("sigma_before_m", "restarts"), [(3.0, True), (8.0, False)])
def test_an_estimate_that_jumps_to_a_road_nearby_is_matched_there_at_once(
        sigma_before_m: float, restarts: bool) -> None:
    """A re-acquired fix moves the estimate 20 m across, onto the parallel road, farther than
    its speed and 3 sigma explain: the road it was on says nothing of where it is now, and the
    matcher starts up again at once (not after ``poor_fit_after_s``). A correction of that
    size by an estimate that was that unsure (3 x 8 m) is no jump: the road is kept."""
    matcher = OnlineMatcher(_two_parallel_roads())
    for k in range(20):  # north along x = 0 at 8 m/s, 10 Hz
        p = matcher.update(estimate(0.1 * k, 0.0, -100.0 + 0.8 * k, 0.0, sigma_m=sigma_before_m))
    assert edge_of(p) == (0, 1)
    jumped = matcher.update(estimate(2.0, 20.5, -84.0, 0.0, sigma_m=3.0))
    assert edge_of(jumped) == ((2, 3) if restarts else (0, 1))


def _two_streets(gap_m: float) -> RoadGraph:
    """Two parallel streets running north, ``gap_m`` apart, each of two 100 m edges."""
    g = nx.MultiDiGraph()
    for n, (dx, dy) in {0: (0, -100), 1: (0, 0), 2: (0, 100),
                        3: (gap_m, -100), 4: (gap_m, 0), 5: (gap_m, 100)}.items():
        g.add_node(n, x=X0 + dx, y=Y0 + dy)
    for u, v in ((0, 1), (1, 2), (3, 4), (4, 5)):
        g.add_edge(u, v, name="street")
    return RoadGraph.from_networkx(g, FRAME)


def test_road_share_is_whole_when_no_other_road_could_be_the_one_driven() -> None:
    """Alone beside its street (the next edge of the same street, ahead, does not count)."""
    graph = _two_streets(80.0)
    matcher = OnlineMatcher(graph)
    on_first_edge = estimate(0.0, 1.0, -2.0, 0.0)  # 2 m before the street's middle node
    assert matcher.road_share(on_first_edge, EdgeKey(0, 1, 0)) == pytest.approx(1.0)


def test_road_share_halves_between_two_streets_and_follows_the_nearer() -> None:
    graph = _two_streets(10.0)
    matcher = OnlineMatcher(graph)
    between = estimate(0.0, 5.0, -50.0, 0.0)
    assert matcher.road_share(between, EdgeKey(0, 1, 0)) == pytest.approx(0.5, abs=1e-6)
    nearer_west = estimate(0.0, 2.0, -50.0, 0.0)
    west, east = EdgeKey(0, 1, 0), EdgeKey(3, 4, 0)
    assert matcher.road_share(nearer_west, west) > 0.5 > matcher.road_share(nearer_west, east)
    assert matcher.road_share(nearer_west, west) + \
        matcher.road_share(nearer_west, east) == pytest.approx(1.0)


@pytest.mark.parametrize(("east_m", "switches"), [(6.0, False), (8.5, True)])
def test_a_road_beside_that_fits_far_better_takes_the_match_over(east_m: float,
                                                                 switches: bool) -> None:
    """Matched to the west one of two streets 10 m apart, the estimate runs ``east_m`` east
    of it: well within the poor-fit distance of both, but at 8.5 m the street it runs beside
    holds over 70 % of their likelihood, and after ``poor_fit_after_s`` the matcher starts
    up again there (a fork taken wrongly in an outage: Monaco 546 of the tune split, 1.37
    -> 0.45x raw GPS); nearer the middle it keeps its road."""
    matcher = OnlineMatcher(_two_streets(10.0))
    for k in range(10):
        p = matcher.update(estimate(0.1 * k, 0.0, -90.0 + 0.8 * k, 0.0))
    assert edge_of(p) == (0, 1)
    matched = [edge_of(matcher.update(estimate(1.0 + 0.1 * k, east_m, -82.0 + 0.8 * k, 0.0)))
               for k in range(40)]
    assert all(edge == (0, 1) for edge in matched[:19])  # not before poor_fit_after_s
    assert matched[-1] == ((3, 4) if switches else (0, 1))
