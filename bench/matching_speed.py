"""Offline trace matching: speed and accuracy against leuvenmapmatching and mappymatch.

All three match the same traces on the same road network in one run: the GPS fixes (1 Hz) of
simulated drives on the sample map, whose truth says which road the car was on at each fix.
Accuracy is the share of fixes matched to an edge of the right OSM way (strictly; and as
``navsvc evaluate`` scores it, where within 5 m of an intersection the roads on both sides of it
are right, as the car is on both within the GPS error there); speed is points per
second of matching (the map is loaded and indexed once per matcher, outside the timing; each
trace is matched ``--repeats`` times by each matcher in turn and the median time kept, as this
machine is noisy).

- navsvc: ``match_trace`` (HMM + Viterbi, sigma 10 m).
- leuvenmapmatching: ``DistanceMatcher`` on an ``InMemMap`` of every edge's polyline vertices
  (projected metres, R-tree index), with the noise of its documentation's example scaled to
  the same 10 m sigma and a lattice width of 5.
- mappymatch: ``LCSSMatcher`` on an ``NxMap`` made by its own ``parse_osmnx_graph`` from our
  edges (same geometry, no component filtering).

    pip install -e '.[bench]'
    python bench/matching_speed.py [--map maps/monaco.db] [--drives 10] [--duration 600]
        [--repeats 3] [--skip leuvenmapmatching]
"""

from __future__ import annotations

import logging
import statistics
import time
from collections.abc import Callable
from typing import Any, NamedTuple

import networkx as nx
import numpy as np
import pandas as pd
from leuvenmapmatching.map.inmem import InMemMap
from leuvenmapmatching.matcher.distance import DistanceMatcher
from mappymatch.constructs.trace import Trace
from mappymatch.maps.nx.nx_map import NxMap
from mappymatch.maps.nx.readers.osm_readers import NetworkType, parse_osmnx_graph
from mappymatch.matchers.lcss.lcss import LCSSMatcher
from report import drives_parser, print_table, write_json
from shapely.geometry import LineString
from tqdm import tqdm

from navsvc.sim.evaluate import NODE_TOLERANCE_M
from navsvc.sim.simulate import DriveSpec, simulate_drive
from navsvc.wire.route import match_trace
from navsvc.wire.traces import TraceFix
from roadgraph import EdgeKey, RoadGraph

SIGMA_M = 10.0
# A matcher: fixes -> the OSM way ids of the edge each fix was matched to (empty: unmatched).
Matcher = Callable[[list[TraceFix]], list[tuple[int, ...]]]


def navsvc_matcher(graph: RoadGraph) -> Matcher:
    def run(fixes: list[TraceFix]) -> list[tuple[int, ...]]:
        route = match_trace(graph, fixes)
        return [tuple(graph.edge(EdgeKey(**p["matched"]["edge"])).osm_way_ids)
                if p["matched"] else () for p in route["points"]]
    return run


def leuven_matcher(graph: RoadGraph) -> Matcher:
    """Each edge's polyline as a chain of leuven nodes; leuven edges labelled with our edge."""
    leuven = InMemMap("roads", use_latlon=False, use_rtree=True, index_edges=True)
    label: dict[tuple[int, int], EdgeKey] = {}
    next_id = max(n.id for n in graph.nodes) + 1
    for node in graph.nodes:
        leuven.add_node(node.id, (node.y_m, node.x_m))
    for edge in graph.edges:
        ids = [edge.u]
        for x, y in edge.coords[1:-1]:
            leuven.add_node(next_id, (float(y), float(x)))
            ids.append(next_id)
            next_id += 1
        ids.append(edge.v)
        for a, b in zip(ids[:-1], ids[1:]):
            if a != b:
                leuven.add_edge(a, b)
                label[(a, b)] = EdgeKey(edge.u, edge.v, edge.key)

    def run(fixes: list[TraceFix]) -> list[tuple[int, ...]]:
        matcher = DistanceMatcher(
            leuven, max_dist=5 * SIGMA_M, max_dist_init=5 * SIGMA_M, obs_noise=SIGMA_M,
            obs_noise_ne=1.5 * SIGMA_M, dist_noise=SIGMA_M, min_prob_norm=0.001,
            non_emitting_states=True, max_lattice_width=5)
        path = [(y, x) for x, y in (graph.frame.to_local(f.lon_deg, f.lat_deg) for f in fixes)]
        matcher.match(path)
        out: list[tuple[int, ...]] = [()] * len(fixes)
        for m in matcher.lattice_best:
            if m.obs_ne == 0 and m.edge_m.l2 is not None:
                key = label.get((m.edge_m.l1, m.edge_m.l2))
                if key is not None:
                    out[m.obs] = tuple(graph.edge(key).osm_way_ids)
        return out
    return run


def mappymatch_matcher(graph: RoadGraph) -> Matcher:
    g = nx.MultiDiGraph(crs="epsg:4326")
    for node in graph.nodes:
        g.add_node(node.id, x=node.lon_deg, y=node.lat_deg)
    for e in graph.edges:
        g.add_edge(e.u, e.v, e.key, geometry=LineString(e.lonlat), length=e.length_m,
                   osmid=list(e.osm_way_ids), name=e.name, highway=e.highway,
                   maxspeed=e.maxspeed)
    road_map = NxMap(parse_osmnx_graph(g, NetworkType.DRIVE, filter_to_largest_component=False))
    matcher = LCSSMatcher(road_map)

    def run(fixes: list[TraceFix]) -> list[tuple[int, ...]]:
        frame = pd.DataFrame({"latitude": [f.lat_deg for f in fixes],
                              "longitude": [f.lon_deg for f in fixes]})
        result = matcher.match_trace(Trace.from_dataframe(frame))
        out: list[tuple[int, ...]] = []
        for m in result.matches:
            osmid = (m.road.metadata or {}).get("osmid") if m.road else None
            out.append(tuple(osmid) if isinstance(osmid, list) else
                       (osmid,) if osmid is not None else ())
        return out
    return run


class TraceTruth(NamedTuple):
    way: list[int]  # the true OSM way at each fix
    ways_at_node: list[frozenset[int]]  # within NODE_TOLERANCE_M of an intersection: its ways


def drive_trace(graph: RoadGraph, seed: int, duration_s: float) -> tuple[list[TraceFix],
                                                                          TraceTruth]:
    """The GPS fixes of one simulated drive, and the truth at each."""
    drive = simulate_drive(graph, DriveSpec(duration_s=duration_s, seed=seed,
                                            tunnels_block_gps=False))
    truth = {round(r["t"], 1): r for r in drive if r["kind"] == "truth"}
    fixes = [TraceFix(r["t"], r["lat"], r["lon"]) for r in drive if r["kind"] == "gps"]
    at_fix = [truth[round(f.t, 1)] for f in fixes]
    nodes = graph.nodes
    node_xy = np.array([(n.x_m, n.y_m) for n in nodes])
    true_xy = graph.frame.coords_to_local(np.array([(r["lon"], r["lat"]) for r in at_fix]))
    ways_at_node = []
    for x, y in true_xy:
        gaps = np.hypot(node_xy[:, 0] - x, node_xy[:, 1] - y)
        k = int(np.argmin(gaps))
        ways_at_node.append(frozenset(
            w for e in graph.out_edges(nodes[k].id) + graph.in_edges(nodes[k].id)
            for w in e.osm_way_ids) if gaps[k] <= NODE_TOLERANCE_M else frozenset())
    return fixes, TraceTruth([r["osm_way_id"] for r in at_fix], ways_at_node)


def main() -> None:
    parser = drives_parser(__doc__)
    parser.add_argument("--skip", action="append", default=[],
                        choices=["leuvenmapmatching", "mappymatch"], help="leave a peer out")
    parser.add_argument("--repeats", type=int, default=3, help="timings per trace (median)")
    args = parser.parse_args()
    for noisy in ("mappymatch", "be.kuleuven.cs.dtai.mapmatching"):
        logging.getLogger(noisy).setLevel(logging.WARNING)
    graph = RoadGraph.open(args.map)
    traces = [drive_trace(graph, seed, args.duration) for seed in range(1, args.drives + 1)]
    builders: dict[str, Callable[[RoadGraph], Matcher]] = {
        "navsvc": navsvc_matcher, "leuvenmapmatching": leuven_matcher,
        "mappymatch": mappymatch_matcher}
    matchers: dict[str, tuple[Matcher, float]] = {}
    for name, build in builders.items():
        if name not in args.skip:
            start = time.perf_counter()
            matchers[name] = (build(graph), time.perf_counter() - start)
    # Interleaved: each trace by each matcher in turn, so that the machine's slow spells fall
    # on all of them alike and the ratios between them hold.
    times: dict[tuple[str, int], list[float]] = {}
    results: dict[tuple[str, int], list[tuple[int, ...]]] = {}
    for seed, (fixes, _) in enumerate(tqdm(traces, desc="traces"), start=1):
        for _ in range(args.repeats):
            for name, (matcher, _) in matchers.items():
                start = time.perf_counter()
                results[(name, seed)] = matcher(fixes)
                times.setdefault((name, seed), []).append(time.perf_counter() - start)
    rows: list[dict[str, Any]] = []
    for name, (_, setup_s) in matchers.items():
        for seed, (fixes, truth) in enumerate(traces, start=1):
            matched = results[(name, seed)]
            elapsed = statistics.median(times[(name, seed)])
            right = [way in ways for way, ways in zip(truth.way, matched)]
            right_at_node = [r or bool(node.intersection(ways))
                             for r, node, ways in zip(right, truth.ways_at_node, matched)]
            rows.append({"matcher": name, "seed": seed, "points": len(fixes),
                         "seconds": elapsed, "points_per_s": len(fixes) / elapsed,
                         "right_road_share": sum(right) / len(fixes),
                         "right_road_share_node_tolerance": sum(right_at_node) / len(fixes),
                         "unmatched": sum(not m for m in matched), "setup_s": setup_s})
    ours = statistics.median(r["points_per_s"] for r in rows if r["matcher"] == "navsvc")
    table = []
    for name in dict.fromkeys(r["matcher"] for r in rows):
        g = [r for r in rows if r["matcher"] == name]
        pps = statistics.median(r["points_per_s"] for r in g)
        table.append([name, sum(r["points"] for r in g), pps, ours / pps,
                      100.0 * statistics.median(r["right_road_share"] for r in g),
                      100.0 * statistics.median(r["right_road_share_node_tolerance"] for r in g),
                      100.0 * min(r["right_road_share_node_tolerance"] for r in g),
                      g[0]["setup_s"]])
    print_table(f"Offline matching, {args.drives} simulated drives x {args.duration:.0f} s "
                f"(1 Hz GPS), {args.map.name}",
                ["matcher", "points", "points/s (median)", "navsvc speed-up",
                 "right road % (median)", "same, 5 m at junctions (median)", "(worst)",
                 "map setup s"], table)
    write_json("matching_speed", {"drives": args.drives, "duration_s": args.duration,
                                  "rows": rows})


if __name__ == "__main__":
    main()
