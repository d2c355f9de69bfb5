"""Road-graph benchmarks: import time and peak memory, open time, nearest-edge queries.

Nearest-edge queries run on 100,000 random points, side by side with
``osmnx.distance.nearest_edges`` on the same graph and points in the same run.

    python bench/roadgraph_bench.py [--map-source maps/monaco.osm.gz] [--points 100000]
"""

from __future__ import annotations

import argparse
import gc
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import networkx as nx
import numpy as np
import osmnx as ox
import shapely
from report import median_us, print_table, write_json
from tqdm import tqdm

from roadgraph import EdgeKey, RoadGraph

ROOT = Path(__file__).resolve().parent.parent

_IMPORT_CHILD = """
import resource, sys, time
from pathlib import Path
from roadgraph import import_map
t = time.perf_counter()
import_map(Path(sys.argv[2]), source=Path(sys.argv[1]))
print(time.perf_counter() - t, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
"""


def bench_import(source: Path, db: Path, runs: int) -> dict[str, float]:
    """Import in a fresh process each run (peak RSS of that process; time without start-up)."""
    times, peaks = [], []
    for _ in tqdm(range(runs), desc="import runs", leave=False):
        out = subprocess.run([sys.executable, "-c", _IMPORT_CHILD, str(source), str(db)],
                             capture_output=True, text=True, check=True).stdout.split()
        times.append(float(out[0]))
        peaks.append(int(out[1]) / 1024.0)
    return {"import_s_median": statistics.median(times),
            "import_peak_rss_mib_median": statistics.median(peaks)}


def bench_open(db: Path, runs: int) -> float:
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        RoadGraph.open(db)
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def sample_points(graph: RoadGraph, n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Two point sets: near roads (a random edge point plus 15 m noise) and uniform in the bbox."""
    edges = graph.edges
    lines = [shapely.LineString(e.coords) for e in edges]
    pick = rng.integers(0, len(edges), n)
    frac = rng.random(n)
    on_road = np.array([shapely.get_coordinates(lines[i].interpolate(f, normalized=True))[0]
                        for i, f in zip(pick, frac)])
    near_road = on_road + rng.normal(0.0, 15.0, (n, 2))
    xs = np.concatenate([e.coords[:, 0] for e in edges])
    ys = np.concatenate([e.coords[:, 1] for e in edges])
    uniform = np.column_stack([rng.uniform(xs.min(), xs.max(), n),
                               rng.uniform(ys.min(), ys.max(), n)])
    return {"near_road": near_road, "uniform_bbox": uniform}


def osmnx_graph(graph: RoadGraph) -> nx.MultiDiGraph:
    """The same edges as an osmnx projected graph (geometry on every edge)."""
    g = nx.MultiDiGraph(crs=graph.info.crs_wkt)
    for n in graph.nodes:
        g.add_node(n.id, x=n.x_m, y=n.y_m)
    for e in graph.edges:
        g.add_edge(e.u, e.v, key=e.key, length=e.length_m, geometry=shapely.LineString(e.coords))
    return g


def _same_distance(graph: RoadGraph, x: float, y: float, osmnx_key: tuple[int, int, int]) -> bool:
    """Our nearest edge is osmnx's, or an exact tie with it."""
    ours = graph.nearest_edge(x, y)
    theirs = graph.project(EdgeKey(*osmnx_key), x, y).distance_m
    return tuple(ours.edge) == tuple(osmnx_key) or abs(ours.distance_m - theirs) < 1e-6


def time_per_call(fn, points: np.ndarray, desc: str) -> list[float]:  # type: ignore[no-untyped-def]
    """Seconds per call, with the garbage collector paused as timeit does."""
    out = []
    gc.collect()
    gc.disable()
    try:
        for x, y in tqdm(points.tolist(), desc=desc, leave=False, mininterval=1):
            t = time.perf_counter()
            fn(x, y)
            out.append(time.perf_counter() - t)
    finally:
        gc.enable()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--map-source", type=Path, default=ROOT / "maps" / "monaco.osm.gz",
                        help="OSM extract to import (default: the bundled sample map)")
    parser.add_argument("--points", type=int, default=100_000, help="query points per set")
    parser.add_argument("--radius-m", type=float, default=50.0, help="edges_near radius")
    parser.add_argument("--osmnx-single-points", type=int, default=300,
                        help="points for osmnx one-point-per-call timing (slow)")
    parser.add_argument("--import-runs", type=int, default=3)
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        db = Path(tmp) / "map.db"
        imp = bench_import(args.map_source, db, args.import_runs)
        open_s = bench_open(db, 10)
        graph = RoadGraph.open(db)
    rng = np.random.default_rng(42)
    sets = sample_points(graph, args.points, rng)
    ox_graph = osmnx_graph(graph)

    rows, results = [], {}
    for name, pts in sets.items():
        ours_near = time_per_call(lambda x, y: graph.edges_near(x, y, args.radius_m), pts,
                                  "edges_near")
        ours_nearest = time_per_call(graph.nearest_edge, pts, "nearest_edge")
        t = time.perf_counter()
        ox_bulk = ox.distance.nearest_edges(ox_graph, pts[:, 0], pts[:, 1])
        ox_bulk_us = (time.perf_counter() - t) / len(pts) * 1e6
        few = pts[: args.osmnx_single_points]
        ox_single = time_per_call(lambda x, y: ox.distance.nearest_edges(ox_graph, x, y), few,
                                  "osmnx nearest_edges")
        agree = np.mean([_same_distance(graph, x, y, k)
                         for (x, y), k in zip(pts[:2000], ox_bulk[:2000])])
        r = {
            "edges_near_median_us": median_us(ours_near),
            "nearest_edge_median_us": median_us(ours_nearest),
            "osmnx_nearest_edges_one_point_per_call_median_us": median_us(ox_single),
            "osmnx_nearest_edges_bulk_us_per_point": ox_bulk_us,
            "agreement_with_osmnx_nearest": float(agree),
        }
        results[name] = r
        rows.append([name, f"edges_near r={args.radius_m:g} m", r["edges_near_median_us"], "-"])
        rows.append([name, "nearest_edge", r["nearest_edge_median_us"],
                     r["osmnx_nearest_edges_one_point_per_call_median_us"]
                     / r["nearest_edge_median_us"]])
        rows.append([name, "osmnx nearest_edges, 1 point/call",
                     r["osmnx_nearest_edges_one_point_per_call_median_us"], 1.0])
        rows.append([name, f"osmnx nearest_edges, bulk {len(pts)} (amortised)",
                     ox_bulk_us, "-"])

    print_table(f"Import and open: {args.map_source.name} "
                f"({graph.info.node_count} nodes, {graph.info.edge_count} edges)",
                ["measure", "median"],
                [["import time (s)", imp["import_s_median"]],
                 ["import peak RSS (MiB)", imp["import_peak_rss_mib_median"]],
                 ["open time (ms)", open_s * 1e3]])
    print_table(f"Nearest-edge queries, {args.points} points per set "
                f"(osmnx one-per-call on the first {args.osmnx_single_points})",
                ["points", "query", "median µs", "osmnx/ours"], rows)
    for name, r in results.items():
        print(f"{name}: nearest edge agrees with osmnx on "
              f"{100 * r['agreement_with_osmnx_nearest']:.1f} % of 2000 points")
    write_json("roadgraph", {
        "map": args.map_source.name, "nodes": graph.info.node_count,
        "edges": graph.info.edge_count, **imp, "open_s_median": open_s,
        "points_per_set": args.points, "radius_m": args.radius_m, "queries": results,
        "targets": {"open_s": 1.0, "edges_near_median_us": 50.0},
    })


if __name__ == "__main__":
    main()
