import math
from pathlib import Path

import networkx as nx
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from roadgraph import EdgeKey, LocalFrame, RoadGraph, RoadGraphError
from roadgraph.geometry import project_onto_polyline
from roadgraph.store import read_network

FRAME = LocalFrame.for_point(7.42, 43.73)


def cross_graph() -> RoadGraph:
    """A + junction at the origin: two-way arms of 100 m to N, E, S; a one-way arm W → centre."""
    g = nx.MultiDiGraph()
    x0, y0 = FRAME.to_local(7.42, 43.73)
    pos = {0: (0, 0), 1: (0, 100), 2: (100, 0), 3: (0, -100), 4: (-100, 0)}
    for n, (dx, dy) in pos.items():
        g.add_node(n, x=x0 + dx, y=y0 + dy)
    for arm in (1, 2, 3):
        g.add_edge(0, arm, name=f"arm{arm}")
        g.add_edge(arm, 0, name=f"arm{arm}")
    g.add_edge(4, 0, name="west", oneway=True)
    return RoadGraph.from_networkx(g, FRAME)


def test_out_edges_respect_oneway() -> None:
    g = cross_graph()
    assert sorted(e.v for e in g.out_edges(0)) == [1, 2, 3]
    assert sorted(e.u for e in g.in_edges(0)) == [1, 2, 3, 4]
    bearings = {e.v: math.degrees(e.bearing_start_rad) for e in g.out_edges(0)}
    assert bearings == pytest.approx({1: 0.0, 2: 90.0, 3: 180.0})


def test_turn_angles() -> None:
    g = cross_graph()
    from_west = EdgeKey(4, 0, 0)  # heading east
    assert math.degrees(g.turn_angle_rad(from_west, EdgeKey(0, 1, 0))) == pytest.approx(-90)
    assert math.degrees(g.turn_angle_rad(from_west, EdgeKey(0, 3, 0))) == pytest.approx(90)
    assert g.turn_angle_rad(from_west, EdgeKey(0, 2, 0)) == pytest.approx(0.0)
    with pytest.raises(RoadGraphError, match="do not meet"):
        g.turn_angle_rad(EdgeKey(0, 1, 0), EdgeKey(0, 2, 0))


def test_projection_on_hand_built_edge() -> None:
    g = cross_graph()
    x0, y0 = FRAME.to_local(7.42, 43.73)
    p = g.project(EdgeKey(0, 2, 0), x0 + 30, y0 + 4)
    assert (p.offset_m, p.distance_m, p.remaining_m) == pytest.approx((30, 4, 70), abs=1e-6)
    assert p.bearing_rad == pytest.approx(math.pi / 2)


def test_edges_near_on_hand_built_graph() -> None:
    g = cross_graph()
    x0, y0 = FRAME.to_local(7.42, 43.73)
    near = g.edges_near(x0 + 50, y0 + 3, 10.0)
    assert {n.edge for n in near} == {EdgeKey(0, 2, 0), EdgeKey(2, 0, 0)}
    assert all(n.distance_m == pytest.approx(3.0) for n in near)
    assert g.edges_near(x0 + 50, y0 + 50, 10.0) == []
    assert g.nearest_edge(x0 + 50, y0 + 30).distance_m == pytest.approx(30.0)


def test_distance_to_road_along_a_heading() -> None:
    """The nearest road running along the heading (either way); the radius when none is."""
    g = cross_graph()
    x0, y0 = FRAME.to_local(7.42, 43.73)
    east, north, fit = math.pi / 2, 0.0, math.radians(30.0)
    assert g.distance_to_road_m(x0 + 50, y0 + 3, east, 30.0, fit) == pytest.approx(3.0)
    assert g.distance_to_road_m(x0 + 50, y0 + 3, -east, 30.0, fit) == pytest.approx(3.0)
    # the east arm is 3 m away but runs across a northbound heading; the north arm is 50 m
    assert g.distance_to_road_m(x0 + 50, y0 + 3, north, 30.0, fit) == 30.0
    assert g.distance_to_road_m(x0 + 20, y0 + 60, north, 30.0, fit) == pytest.approx(20.0)


def test_shortest_path() -> None:
    g = cross_graph()
    assert g.shortest_path(4, 2) == [EdgeKey(4, 0, 0), EdgeKey(0, 2, 0)]
    assert g.shortest_path(1, 1) == []
    with pytest.raises(nx.NetworkXNoPath):
        g.shortest_path(0, 4)  # one-way arm


def _brute_force_near(g: RoadGraph, x: float, y: float, r: float) -> dict[EdgeKey, float]:
    out = {}
    for e in g.edges:
        d = project_onto_polyline(e.coords, x, y).distance_m
        if d <= r:
            out[EdgeKey(e.u, e.v, e.key)] = d
    return out


@settings(max_examples=100, deadline=None)
@given(st.floats(0.0, 1.0), st.floats(0.0, 1.0), st.floats(1.0, 150.0))
def test_edges_near_matches_brute_force(sample_graph: RoadGraph, fx: float, fy: float,
                                        r: float) -> None:
    w, s, e, n = sample_graph.info.bbox_wgs84
    x0, y0 = sample_graph.frame.to_local(w, s)
    x1, y1 = sample_graph.frame.to_local(e, n)
    x, y = x0 + fx * (x1 - x0), y0 + fy * (y1 - y0)
    near = sample_graph.edges_near(x, y, r)
    expected = _brute_force_near(sample_graph, x, y, r)
    # exact ties at the radius may fall either side of floating-point rounding
    assert {k for k, d in expected.items() if d < r - 1e-6} <= {ne.edge for ne in near}
    assert {ne.edge for ne in near} <= set(expected)
    for ne in near:
        assert ne.distance_m == pytest.approx(expected[ne.edge], abs=1e-6)
        # the closest point found by the grid is the one a projection onto the edge finds
        p = sample_graph.project(ne.edge, x, y)
        assert (ne.x_m, ne.y_m) == pytest.approx((p.x_m, p.y_m), abs=1e-6)
        assert ne.offset_m == pytest.approx(p.offset_m, abs=1e-6)
        assert ne.length_m == p.length_m
        at_vertex = np.hypot(*(sample_graph.edge(ne.edge).coords - (p.x_m, p.y_m)).T).min()
        # the bearing is the holding segment's: at a vertex, rounding may pick either one
        assert ne.bearing_rad == pytest.approx(p.bearing_rad) or at_vertex < 1e-6
    dists = [ne.distance_m for ne in near]
    assert dists == sorted(dists)
    assert sample_graph.edges_near(x, y, r, limit=3) == near[:3]


def test_nearest_edge_matches_brute_force(sample_graph: RoadGraph) -> None:
    rng = np.random.default_rng(7)
    xs = np.array([n.x_m for n in sample_graph.nodes])
    ys = np.array([n.y_m for n in sample_graph.nodes])
    for _ in range(50):
        x = rng.uniform(xs.min(), xs.max())
        y = rng.uniform(ys.min(), ys.max())
        best = min(project_onto_polyline(e.coords, x, y).distance_m for e in sample_graph.edges)
        assert sample_graph.nearest_edge(x, y).distance_m == pytest.approx(best, abs=1e-6)


def test_sample_graph_is_an_intersection_graph(sample_graph: RoadGraph) -> None:
    g = sample_graph.graph
    assert g.number_of_nodes() == sample_graph.info.node_count
    assert g.number_of_edges() == sample_graph.info.edge_count
    # simplified: no node is a mere bend joining exactly two roads of one way through it
    through = [n for n in g.nodes if g.in_degree(n) == 1 and g.out_degree(n) == 1
               and next(iter(g.predecessors(n))) != next(iter(g.successors(n)))]
    assert len(through) < 0.05 * g.number_of_nodes()
    for e in sample_graph.edges:
        u, v = sample_graph.node(e.u), sample_graph.node(e.v)
        assert e.coords[0] == pytest.approx((u.x_m, u.y_m))
        assert e.coords[-1] == pytest.approx((v.x_m, v.y_m))
        assert e.length_m > 0
    names = {e.name for e in sample_graph.edges if e.name}
    assert "Boulevard Albert 1er" in names or any("Albert" in n for n in names)


def test_nearest_edge_far_outside_the_map(sample_graph: RoadGraph) -> None:
    n = sample_graph.nodes[0]
    far = sample_graph.nearest_edge(n.x_m + 20_000.0, n.y_m + 20_000.0)
    best = min(project_onto_polyline(e.coords, n.x_m + 20_000.0, n.y_m + 20_000.0).distance_m
               for e in sample_graph.edges)
    assert far.distance_m == pytest.approx(best)
    assert sample_graph.edges_near(n.x_m + 20_000.0, n.y_m, 100.0) == []


def test_points_the_projection_cannot_hold_are_near_nothing(sample_graph: RoadGraph) -> None:
    x, y = sample_graph.frame.to_local(0.0, -90.0)  # the south pole in Monaco's UTM zone
    assert sample_graph.edges_near(x, y, 30.0) == []
    assert sample_graph.edges_near(math.inf, 0.0, 30.0) == []
    with pytest.raises(RoadGraphError, match="outside what the map's projection can hold"):
        sample_graph.nearest_edge(math.nan, 0.0)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 10_000), st.floats(0.0, 3000.0))
def test_distances_from_agrees_with_networkx(sample_graph: RoadGraph, pick: int,
                                             cutoff_m: float) -> None:
    source = sample_graph.nodes[pick % len(sample_graph.nodes)].id
    expected = nx.single_source_dijkstra_path_length(sample_graph.graph, source,
                                                     cutoff=cutoff_m, weight="length")
    found = sample_graph.distances_from(source, cutoff_m)
    assert found.keys() == expected.keys()
    for node, distance in expected.items():
        assert found[node] == pytest.approx(distance, abs=1e-9)


def test_opened_graph_answers_as_the_graph_of_its_records(sample_db: Path) -> None:
    """The service's graph (compact arrays, records read from the database on demand) against
    one built from every record in memory: the same answers."""
    opened = RoadGraph.open(sample_db)
    held = RoadGraph(read_network(sample_db))
    assert len(opened.edges) == len(held.edges) and len(opened.nodes) == len(held.nodes)
    assert list(opened.nodes) == list(held.nodes)
    assert all(a.same_as(b, tol_m=0.0) for a, b in zip(opened.edges, held.edges))
    rng = np.random.default_rng(3)
    xs = np.array([n.x_m for n in held.nodes])
    ys = np.array([n.y_m for n in held.nodes])
    for x, y in zip(rng.uniform(xs.min(), xs.max(), 200), rng.uniform(ys.min(), ys.max(), 200)):
        assert opened.edges_near(x, y, 80.0) == held.edges_near(x, y, 80.0)
    ids = [n.id for n in held.nodes]
    for node in ids[::7]:
        for mine, theirs in ((opened.out_edges(node), held.out_edges(node)),
                             (opened.in_edges(node), held.in_edges(node))):
            assert len(mine) == len(theirs)
            assert all(a.same_as(b, tol_m=0.0) for a, b in zip(mine, theirs))
    for source, target in zip(ids[::11], ids[5::11]):
        try:
            expected = held.shortest_path(source, target)
        except nx.NetworkXNoPath:
            with pytest.raises(nx.NetworkXNoPath):
                opened.shortest_path(source, target)
            continue
        assert opened.shortest_path(source, target) == expected


def test_to_networkx_is_the_whole_graph(sample_graph: RoadGraph) -> None:
    g = sample_graph.to_networkx()
    assert g.number_of_nodes() == sample_graph.info.node_count
    assert g.number_of_edges() == sample_graph.info.edge_count
    e = sample_graph.edges[10]
    assert g.edges[e.u, e.v, e.key]["length"] == e.length_m
    n = sample_graph.nodes[3]
    assert (g.nodes[n.id]["x"], g.nodes[n.id]["lat"]) == (n.x_m, n.lat_deg)


def test_shortest_path_agrees_with_networkx(sample_graph: RoadGraph) -> None:
    g = sample_graph.graph
    ids = [n.id for n in sample_graph.nodes]
    rng = np.random.default_rng(5)
    checked = 0
    for source, target in rng.choice(ids, (60, 2)).tolist():
        try:
            expected = nx.shortest_path_length(g, source, target, weight="length")
        except nx.NetworkXNoPath:
            continue
        path = sample_graph.shortest_path(source, target)
        assert sum(sample_graph.edge(e).length_m for e in path) == pytest.approx(expected)
        assert all(a.v == b.u for a, b in zip(path[:-1], path[1:]))
        checked += 1
    assert checked > 30
