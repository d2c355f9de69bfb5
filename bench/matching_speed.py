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

- Valhalla Meili (``pyvalhalla``, in process in ``.venv-peers``, run by
  ``bench/peer_match.py`` as ``bench/matching_eval.py`` runs it; ``bash bench/peers/setup.sh``
  builds the venv and the tiles of the same OSM file): ``trace_attributes`` with
  ``gps_accuracy`` the simulator's true GPS sigma, each trace ``--repeats`` times. Its time is
  the peer's own in-process matching time (parsing its answer included), so its points per
  second are over all traces together; ours are given both ways. OSRM comes in the same run
  and is shown too.

    pip install -e '.[bench]'
    python bench/matching_speed.py [--map maps/monaco.db] [--drives 10] [--duration 600]
        [--repeats 3] [--skip leuvenmapmatching] [--peers-python .venv-peers/bin/python]
        [--peers-cache bench/.cache/peers/monaco]
"""

from __future__ import annotations

import json
import logging
import math
import statistics
import subprocess
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import networkx as nx
import numpy as np
from report import drives_parser, print_table, write_json
from shapely.geometry import LineString
from tqdm import tqdm

from navsvc.sim.evaluate import NODE_TOLERANCE_M
from navsvc.sim.simulate import DriveSpec, simulate_drive
from navsvc.wire.route import match_trace
from navsvc.wire.traces import TraceFix
from roadgraph import EdgeKey, RoadGraph

SIGMA_M = 10.0
ROOT = Path(__file__).resolve().parent.parent
TRUE_GPS_SIGMA_M = 4.123105625617661  # the simulator's default fixes (bench/matching_eval.py)
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
    from leuvenmapmatching.map.inmem import InMemMap
    from leuvenmapmatching.matcher.distance import DistanceMatcher

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
    import pandas as pd
    from mappymatch.constructs.trace import Trace
    from mappymatch.maps.nx.nx_map import NxMap
    from mappymatch.maps.nx.readers.osm_readers import NetworkType, parse_osmnx_graph
    from mappymatch.matchers.lcss.lcss import LCSSMatcher

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


def drive_trace(graph: RoadGraph, seed: int, duration_s: float, gps_rate_hz: float = 1.0
                ) -> tuple[list[TraceFix], TraceTruth]:
    """The GPS fixes of one simulated drive, and the truth at each."""
    drive = simulate_drive(graph, DriveSpec(duration_s=duration_s, seed=seed,
                                            tunnels_block_gps=False, gps_rate_hz=gps_rate_hz))
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


def _parser() -> Any:
    parser = drives_parser(__doc__)
    parser.add_argument("--skip", action="append", default=[],
                        choices=["leuvenmapmatching", "mappymatch", "valhalla"],
                        help="leave a peer out (valhalla: Valhalla and OSRM)")
    parser.add_argument("--repeats", type=int, default=3, help="timings per trace (median)")
    parser.add_argument("--gps-rate", type=float, default=1.0, help="fixes per second")
    parser.add_argument("--peers-python", type=Path, default=ROOT / ".venv-peers" / "bin" /
                        "python", help="Python of .venv-peers (bench/peers/setup.sh)")
    parser.add_argument("--peers-cache", type=Path, default=None,
                        help="the peers' map data (default bench/.cache/peers/<map stem>)")
    return parser


def _matchers(graph: RoadGraph, skip: list[str]) -> dict[str, tuple[Matcher, float]]:
    builders: dict[str, Callable[[RoadGraph], Matcher]] = {
        "navsvc": navsvc_matcher, "leuvenmapmatching": leuven_matcher,
        "mappymatch": mappymatch_matcher}
    matchers: dict[str, tuple[Matcher, float]] = {}
    for name, build in builders.items():
        if name not in skip:
            start = time.perf_counter()
            try:
                matchers[name] = (build(graph), time.perf_counter() - start)
            except ImportError as exc:
                print(f"{name} skipped: {exc} (pip install -e '.[bench]')")
    return matchers


Traces = list[tuple[list[TraceFix], TraceTruth]]
Peers = dict[str, tuple[dict[int, list[tuple[int, ...]]], float]]


def _time(args: Any, graph: RoadGraph, traces: Traces, matchers: dict[str, tuple[Matcher, float]]
          ) -> tuple[dict[tuple[str, int], list[float]],
                     dict[tuple[str, int], list[tuple[int, ...]]], list[dict[str, float]], Peers]:
    """Interleaved: each trace by each matcher in turn, so that the machine's slow spells fall
    on all of them alike and the ratios between them hold. Valhalla and OSRM run between our
    rounds (one pass over all traces each), so that a slow spell of this shared machine falls
    on both sides of each round's ratio."""
    times: dict[tuple[str, int], list[float]] = {}
    results: dict[tuple[str, int], list[tuple[int, ...]]] = {}
    rounds: list[dict[str, float]] = []
    peers: Peers = {}
    for fixes, _ in traces:  # warm up (first calls fill caches) before any timing
        for matcher, _ in matchers.values():
            matcher(fixes)
    for _ in tqdm(range(args.repeats), desc="rounds"):
        for seed, (fixes, _) in enumerate(traces, start=1):
            for name, (matcher, _) in matchers.items():
                start = time.perf_counter()
                results[(name, seed)] = matcher(fixes)
                times.setdefault((name, seed), []).append(time.perf_counter() - start)
        found = {} if "valhalla" in args.skip else _peers(args, graph, traces)
        if found:
            peers = found
            rounds.append({"navsvc": sum(t[-1] for (n, _), t in times.items()
                                         if n == "navsvc"),
                           **{name: seconds for name, (_, seconds) in found.items()}})
    return times, results, rounds, peers


def _row(name: str, seed: int, fixes: list[TraceFix], truth: TraceTruth,
         matched: list[tuple[int, ...]], seconds: float, setup_s: float) -> dict[str, Any]:
    right = [way in ways for way, ways in zip(truth.way, matched)]
    right_at_node = [r or bool(node.intersection(ways))
                     for r, node, ways in zip(right, truth.ways_at_node, matched)]
    return {"matcher": name, "seed": seed, "points": len(fixes), "seconds": seconds,
            "points_per_s": math.nan if math.isnan(setup_s) else len(fixes) / seconds,
            "right_road_share": sum(right) / len(fixes),
            "right_road_share_node_tolerance": sum(right_at_node) / len(fixes),
            "unmatched": sum(not m for m in matched), "setup_s": setup_s}


def main() -> None:
    args = _parser().parse_args()
    for noisy in ("mappymatch", "be.kuleuven.cs.dtai.mapmatching"):
        logging.getLogger(noisy).setLevel(logging.WARNING)
    graph = RoadGraph.open(args.map)
    traces = [drive_trace(graph, seed, args.duration, args.gps_rate)
              for seed in range(1, args.drives + 1)]
    matchers = _matchers(graph, args.skip)
    times, results, rounds, peers = _time(args, graph, traces, matchers)
    rows = [_row(name, seed, fixes, truth, results[(name, seed)],
                 statistics.median(times[(name, seed)]), setup_s)
            for name, (_, setup_s) in matchers.items()
            for seed, (fixes, truth) in enumerate(traces, start=1)]
    total = sum(len(f) for f, _ in traces)
    for name, (outcome, _) in peers.items():
        seconds = statistics.median(r[name] for r in rounds)
        rows += [_row(name, seed, fixes, truth, outcome[seed], seconds * len(fixes) / total,
                      math.nan) for seed, (fixes, truth) in enumerate(traces, start=1)]
    _report(args, rows, rounds, list(peers))


def _report(args: Any, rows: list[dict[str, Any]], rounds: list[dict[str, float]],
            peers: list[str]) -> None:
    ours = statistics.median(r["points_per_s"] for r in rows if r["matcher"] == "navsvc")
    ours_all = _all_points_per_s([r for r in rows if r["matcher"] == "navsvc"])
    table = []
    for name in dict.fromkeys(r["matcher"] for r in rows):
        g = [r for r in rows if r["matcher"] == name]
        pps = statistics.median(r["points_per_s"] for r in g)
        everything = _all_points_per_s(g)
        table.append([name, sum(r["points"] for r in g), pps, everything, ours_all / everything,
                      100.0 * statistics.median(r["right_road_share"] for r in g),
                      100.0 * statistics.median(r["right_road_share_node_tolerance"] for r in g),
                      100.0 * min(r["right_road_share_node_tolerance"] for r in g),
                      g[0]["setup_s"]])
    print_table(f"Offline matching, {args.drives} simulated drives x {args.duration:.0f} s "
                f"({args.gps_rate:g} Hz GPS), {args.map.name}",
                ["matcher", "points", "points/s (median)", "points/s (all)",
                 "navsvc speed-up (all)",
                 "right road % (median)", "same, 5 m at junctions (median)", "(worst)",
                 "map setup s"], table)
    for name in peers:
        ratios = [r[name] / r["navsvc"] for r in rounds]
        print(f"navsvc against {name}, round by round (its seconds / ours): "
              f"{', '.join(f'{x:.2f}' for x in ratios)}; median {statistics.median(ratios):.2f}")
    write_json("matching_speed", {"drives": args.drives, "duration_s": args.duration,
                                  "gps_rate_hz": args.gps_rate, "peer_rounds": rounds,
                                  "map": args.map.name, "repeats": args.repeats,
                                  "navsvc_points_per_s_all": ours_all,
                                  "navsvc_points_per_s_median": ours, "rows": rows})


def _all_points_per_s(rows: list[dict[str, Any]]) -> float:
    """Points over seconds, summed over every trace."""
    return sum(r["points"] for r in rows) / sum(r["seconds"] for r in rows)


def _peers(args: Any, graph: RoadGraph, traces: list[tuple[list[TraceFix], TraceTruth]]
           ) -> dict[str, tuple[dict[int, list[tuple[int, ...]]], float]]:
    """Valhalla Meili and OSRM on the same traces, one pass, through bench/peer_match.py in
    .venv-peers: each one's matched ways per seed, and its matching seconds."""
    cache = args.peers_cache or ROOT / "bench" / ".cache" / "peers" / args.map.stem
    if not args.peers_python.exists() or not (cache / "source.sha256").exists():
        print(f"peers skipped: no {args.peers_python} or {cache} (bash bench/peers/setup.sh)")
        return {}
    if (cache / "source.sha256").read_text().strip() != graph.info.source_sha256:
        print(f"peers skipped: {cache} was built from another OSM file than {args.map}")
        return {}
    fixes = {str(seed): [{"t": f.t, "lat": f.lat_deg, "lon": f.lon_deg,
                          "sigma_m": TRUE_GPS_SIGMA_M} for f in trace]
             for seed, (trace, _) in enumerate(traces, start=1)}
    with tempfile.TemporaryDirectory() as tmp:
        src, dst = Path(tmp) / "traces.json", Path(tmp) / "matched.json"
        src.write_text(json.dumps({"traces": fixes}))
        subprocess.run([str(args.peers_python), str(ROOT / "bench" / "peer_match.py"),
                        str(cache), str(src), str(dst)], check=True)
        found = json.loads(dst.read_text())
    meta = found.pop("meta")
    out = {}
    for name, key in (("valhalla meili", "valhalla"), ("osrm", "osrm")):
        ways = {int(i): [(m["way_id"],) if m["way_id"] is not None else () for m in matched]
                for i, matched in found[key].items()}
        out[name] = (ways, meta["match_s"][key])
    return out


if __name__ == "__main__":
    main()
