"""Road-graph benchmarks: import time and peak memory, open time, nearest-edge queries.

Nearest-edge queries run on 100,000 random points, side by side with
``osmnx.distance.nearest_edges`` on the same graph and points in the same run.

    python bench/roadgraph_bench.py [--map-source maps/monaco.osm.gz] [--points 100000]

``--scaling`` measures instead, on maps made by tiling the bundled one (bench/big_maps.py, up
to 3,600 tiles: 2 million directed edges), against map size: import time and peak memory
(a fresh process per import), the service's open time and resident memory (a fresh process
per map, after the open), nearest-edge query times, and matching speed (the same simulated
drive on the first tile, which lies at the same place in every map; offline HMM matching and
the online session) as a ratio to the small map's, all in the same run:

    nice -n 10 python bench/roadgraph_bench.py --scaling [--tiles 1 16 128 1024 3600]
"""

from __future__ import annotations

import argparse
import gc
import json
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
from report import RESULTS, median_us, print_table, write_json
from tqdm import tqdm

from roadgraph import EdgeKey, RoadGraph

ROOT = Path(__file__).resolve().parent.parent

_IMPORT_CHILD = """
import resource, sys, time
from pathlib import Path
from roadgraph import import_map
t = time.perf_counter()
import_map(Path(sys.argv[2]), source=Path(sys.argv[1]), builder=sys.argv[3])
print(time.perf_counter() - t, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
"""


def bench_import(source: Path, db: Path, runs: int, builder: str = "auto") -> dict[str, float]:
    """Import in a fresh process each run (peak RSS of that process; time without start-up)."""
    times, peaks = [], []
    for _ in tqdm(range(runs), desc="import runs", leave=False):
        out = subprocess.run([sys.executable, "-c", _IMPORT_CHILD, str(source), str(db),
                              builder],
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


_SERVICE_CHILD = """
import gc, json, sys, time
from pathlib import Path
import numpy as np
from navsvc.session import VehicleSession, SessionConfig
from navsvc.wire.route import match_trace
from navsvc.wire.traces import TraceFix
from roadgraph import RoadGraph

def rss_mib():
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0

def near_road_points(graph, n, rng):
    coords = graph.arrays.coords
    return coords[rng.integers(0, len(coords), n)] + rng.normal(0.0, 15.0, (n, 2))

def time_per_call(fn, points, desc):
    out = []
    gc.collect()
    gc.disable()
    for x, y in points.tolist():
        t = time.perf_counter()
        fn(x, y)
        out.append(time.perf_counter() - t)
    gc.enable()
    return out

drive = json.loads(open(sys.argv[2]).read())
before = rss_mib()
t = time.perf_counter()
graph = RoadGraph.open(sys.argv[1])
open_s = time.perf_counter() - t
after = rss_mib()
pts = near_road_points(graph, 20_000, np.random.default_rng(42))
near = time_per_call(lambda x, y: graph.edges_near(x, y, 50.0), pts, "edges_near")
nearest = time_per_call(graph.nearest_edge, pts, "nearest_edge")
fixes = [TraceFix(*f) for f in drive["fixes"]]
offline, online = [], []
for _ in range(3):
    t = time.perf_counter()
    match_trace(graph, fixes)
    offline.append(time.perf_counter() - t)
    t = time.perf_counter()
    VehicleSession(SessionConfig(), graph).add_records(drive["packets"])
    online.append(time.perf_counter() - t)
print(json.dumps({"open_s": open_s, "rss_before_open_mib": before, "rss_after_open_mib": after,
                  "rss_after_queries_mib": rss_mib(),
                  "edges_near_median_us": float(np.median(near)) * 1e6,
                  "nearest_edge_median_us": float(np.median(nearest)) * 1e6,
                  "offline_points_per_s": len(fixes) / float(np.median(offline)),
                  "online_packets_per_s": len(drive["packets"]) / float(np.median(online)),
                  "edges": graph.info.edge_count, "nodes": graph.info.node_count}))
"""


def _drive_file(small_db: Path, out: Path) -> Path:
    """A 10-minute simulated drive on the small map: its GPS fixes and its sensor packets."""
    from navsvc.sim.simulate import DriveSpec, simulate_drive

    graph = RoadGraph.open(small_db)
    drive = simulate_drive(graph, DriveSpec(duration_s=600.0, seed=3, tunnels_block_gps=False))
    fixes = [(r["t"], r["lat"], r["lon"]) for r in drive if r["kind"] == "gps"]
    packets = [r for r in drive if r["kind"] != "truth"]
    out.write_text(json.dumps({"fixes": fixes, "packets": packets}))
    return out


def _service(db: Path, drive: Path) -> dict[str, float]:
    out = subprocess.run([sys.executable, "-c", _SERVICE_CHILD, str(db), str(drive)],
                         capture_output=True, text=True, check=True).stdout
    result: dict[str, float] = json.loads(out.splitlines()[-1])
    return result


def scaling(tiles: list[int], out_dir: Path, rounds: int, reuse: bool) -> None:
    """The scaling table (see the module docstring). The service is measured ``rounds``
    times per map, the maps taken in turn in each round (this machine's load changes by the
    minute: a map measured only while it was busy would look slower), and the median kept."""
    from big_maps import build

    sources = build(tiles, [ROOT / "maps" / "monaco.osm.gz"], out_dir)
    dbs = [source.with_suffix("").with_suffix(".db") for source in sources]
    previous = {}
    if reuse and (RESULTS / "roadgraph_scaling.json").exists():
        previous = {m["tiles"]: m for m in json.loads(
            (RESULTS / "roadgraph_scaling.json").read_text())["maps"]}
    imports = []
    for n, source, db in zip(tiles, sources, dbs):
        if reuse and db.exists() and n in previous:
            imports.append({k: previous[n][k] for k in
                            ("import_s_median", "import_peak_rss_mib_median")})
        else:
            imports.append(bench_import(source, db, 1, builder="arrays"))
        print(f"{source.name}: imported", flush=True)
    drive = _drive_file(dbs[0], out_dir / "drive.json")
    runs: list[list[dict[str, float]]] = [[] for _ in tiles]
    for r in range(rounds):
        for k, db in enumerate(dbs):
            runs[k].append(_service(db, drive))
        print(f"service round {r + 1}/{rounds} done", flush=True)
    results = []
    for n, source, db, imp, measured in zip(tiles, sources, dbs, imports, runs):
        med = {key: statistics.median(m[key] for m in measured) for key in measured[0]}
        results.append({"tiles": n, "source": source.name,
                        "source_mib": source.stat().st_size / 2**20,
                        "db_mib": db.stat().st_size / 2**20, **imp, **med,
                        "service_rounds": rounds})
    small = results[0]
    rows = []
    for r in results:
        r["offline_speed_ratio_to_small"] = r["offline_points_per_s"] / small[
            "offline_points_per_s"]
        r["online_speed_ratio_to_small"] = r["online_packets_per_s"] / small[
            "online_packets_per_s"]
        rows.append([f"{int(r['edges']):,}", f"{int(r['nodes']):,}", f"{r['source_mib']:.1f}",
                     r["import_s_median"], f"{r['import_peak_rss_mib_median']:.0f}",
                     r["open_s"], f"{r['rss_after_open_mib']:.0f}",
                     f"{r['rss_after_open_mib'] - r['rss_before_open_mib']:.0f}",
                     r["edges_near_median_us"], r["nearest_edge_median_us"],
                     r["offline_speed_ratio_to_small"], r["online_speed_ratio_to_small"]])
    print_table("Road graph against map size (Monaco tiled; one process per import and per "
                f"service open; service figures: median of {rounds} rounds)",
                ["edges", "nodes", "pbf MiB", "import s", "import peak MiB", "open s",
                 "service RSS MiB", "of which map", "near r=50 µs", "nearest µs",
                 "offline speed ×", "online speed ×"], rows)
    write_json("roadgraph_scaling", {
        "maps": results,
        "targets": {"edges": 2_000_000, "import_s": 600.0, "import_peak_rss_mib": 6144.0,
                    "open_s": 2.0, "service_rss_mib": 1536.0, "nearest_edge_median_us": 50.0,
                    "matching_speed_ratio_min": 1.0 / 1.5},
    })


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scaling", action="store_true",
                        help="the table against map size on tiled maps (see above)")
    parser.add_argument("--tiles", type=int, nargs="+", default=[1, 16, 128, 1024, 3600])
    parser.add_argument("--cache", type=Path, default=ROOT / "bench" / ".cache" / "big_maps")
    parser.add_argument("--rounds", type=int, default=3, help="service measurements per map")
    parser.add_argument("--reuse-imports", action="store_true",
                        help="keep the databases and import figures of the last --scaling run")
    parser.add_argument("--map-source", type=Path, default=ROOT / "maps" / "monaco.osm.gz",
                        help="OSM extract to import (default: the bundled sample map)")
    parser.add_argument("--points", type=int, default=100_000, help="query points per set")
    parser.add_argument("--radius-m", type=float, default=50.0, help="edges_near radius")
    parser.add_argument("--osmnx-single-points", type=int, default=300,
                        help="points for osmnx one-point-per-call timing (slow)")
    parser.add_argument("--import-runs", type=int, default=3)
    args = parser.parse_args()
    if args.scaling:
        scaling(args.tiles, args.cache, args.rounds, args.reuse_imports)
        return

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
