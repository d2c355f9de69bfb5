"""Online map matching on simulated urban drives: the matcher with and without map feedback,
nearest-road snapping of the raw GPS fixes as the baseline, and the peers OSRM and Valhalla
Meili matching the same drives' GPS fixes alone, offline.

Each drive (seeded) lasts ``--duration`` seconds with a 60 s GPS outage at 300 s (at half the
drive when it is shorter); gyro + odometer, ``ekf`` fusion, driven online through
``navsvc.session.VehicleSession``. Seeds: TUNE_SEEDS are what the matchers may be tuned on,
REPORT_SEEDS are held out and what the figures are reported on (``--seeds``); the first
``--drives`` of the set. The peers run with their defaults and the GPS error model's sigma,
tuned on nothing.

Two tables per run:

* all matchers x maps by the two metrics of ``road_metrics`` (read its docstring for the
  exact definitions): epochs on the right road within 10 m along the path, and the truth's
  road changes made correctly; median and worst drive, scored at the drive's GPS fixes;
* per map, ``navsvc.sim.evaluate``'s metrics (intersections traversed correctly, share of
  epochs on the right road within 5 m of an intersection, position RMS, outage drift); the
  peers have no estimate in an outage, so no drift.

The peers need ``bash bench/peers/setup.sh`` once (``.venv-peers`` and the map files under
``bench/.cache/peers/<map>/``, ``<map>`` the database's file stem); without them the bench says
so and runs without the peers. ``bench/peer_match.py`` runs them in that venv, and each
peer's matched point is put on our edge of the same OSM way nearest it (direction from the
peer's travel direction). Maps: ``maps/monaco.db``, and Andorra imported with
``roadgraph import tests/data/graphhopper/andorra.osm.pbf -o bench/.cache/andorra.db``.

With ``--harsh`` the drives are the generalisation bench's harsh-urban ones instead
(``generalisation_eval.harsh_drive``: randomised error levels, UrbanNav's real error replayed
on every third, a start at a standstill, its 60 s outage mid-drive), with that bench's seed
sets, so that the held-out drives are held out from its tuning too.

    python bench/matching_eval.py [--maps maps/monaco.db bench/.cache/andorra.db]
        [--drives 10] [--duration 600] [--seeds report|tune] [--no-peers] [--harsh]
"""

from __future__ import annotations

import json
import math
import statistics
import subprocess
import tempfile
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import generalisation_eval
from report import drives_parser, print_table, write_json
from road_metrics import RoadScore, epochs_of, roads_at, score, truth_path
from tqdm import tqdm

from navsvc.session import SessionConfig, VehicleSession
from navsvc.sim.evaluate import Evaluation, evaluate
from navsvc.sim.simulate import SENSOR_KINDS, DriveSpec, SensorErrors, simulate_drive
from navsvc.wire.positions import position_json
from roadgraph import EdgeKey, EdgeProjection, RoadGraph

BENCH = Path(__file__).resolve().parent
PEERS_PYTHON = BENCH.parent / ".venv-peers" / "bin" / "python"
PEERS_CACHE = BENCH / ".cache" / "peers"
PEERS = ("OSRM", "Valhalla Meili")
TUNE_SEEDS = tuple(range(1, 101))  # the seeds this bench used until the peers came in
REPORT_SEEDS = tuple(range(1001, 1101))  # held out
OUTAGE_AT_S, OUTAGE_S = 300.0, 60.0
# 1-sigma horizontal error of a simulated fix at HDOP 1: the per-axis Gauss-Markov and white
# parts together, times sqrt 2 (4.1 m); a fix's sigma is this times its HDOP (the peers' radius).
_E = SensorErrors()
GPS_SIGMA_M = math.hypot(_E.gps_markov_sigma_m, _E.gps_white_sigma_m) * math.sqrt(2.0)
SAME_DISTANCE_M = 0.5  # edges this close to the nearest one are told apart by direction


def outage(duration_s: float) -> tuple[float, float]:
    return (min(OUTAGE_AT_S, duration_s / 2.0), OUTAGE_S)


def nearest_road_baseline(graph: RoadGraph, drive: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Each raw GPS fix snapped to its nearest edge (what a matcher without fusion does)."""
    out = []
    for r in drive:
        if r["kind"] != "gps":
            continue
        x, y = graph.frame.to_local(r["lon"], r["lat"])
        p = graph.nearest_edge(x, y)
        lon, lat = graph.frame.to_wgs84(p.x_m, p.y_m)
        out.append({"t": r["t"], "lat": lat, "lon": lon, "fused_lat": r["lat"],
                    "fused_lon": r["lon"], "heading_deg": r.get("heading_deg", 0.0),
                    "edge": {"u": p.edge.u, "v": p.edge.v}})
    return out


# --- the peers' results on our edges ----------------------------------------------------
def way_index(graph: RoadGraph) -> dict[int, list[EdgeKey]]:
    """Our edges by the OSM ways they follow."""
    ways: dict[int, list[EdgeKey]] = {}
    for e in graph.edges:
        for way in e.osm_way_ids:
            ways.setdefault(way, []).append(EdgeKey(e.u, e.v, e.key))
    return ways


def peer_edge(graph: RoadGraph, ways: dict[int, list[EdgeKey]],
              fix: dict[str, Any]) -> EdgeProjection | None:
    """The peer's matched point on our nearest edge of the OSM way it matched; of two edges
    as near (a two-way road), the one along the peer's travel direction. None when the peer
    matched nothing or a way our graph lacks (not a road for cars to osmnx)."""
    keys = ways.get(fix["way_id"]) if fix["way_id"] is not None else None
    if not keys:
        return None
    x, y = graph.frame.to_local(fix["lon"], fix["lat"])
    found = sorted((graph.project(k, x, y) for k in keys), key=lambda p: p.distance_m)
    near = [p for p in found if p.distance_m <= found[0].distance_m + SAME_DISTANCE_M]
    if fix["bearing_deg"] is None or len(near) == 1:
        return near[0]
    heading = math.radians(fix["bearing_deg"])
    return min(near, key=lambda p: abs(math.remainder(p.bearing_rad - heading, math.tau)))


def peer_estimates(graph: RoadGraph, ways: dict[int, list[EdgeKey]],
                   gps: list[dict[str, Any]], fixes: list[dict[str, Any]]
                   ) -> tuple[list[dict[str, Any]], Counter[str]]:
    """A peer's per-fix results as the wire records ``evaluate`` reads (no fusion: the
    "fused" position is the fix), and how each fix came out."""
    out, how = [], Counter[str]()
    for g, f in zip(gps, fixes, strict=True):
        p = peer_edge(graph, ways, f)
        how[f["how"] if p is not None or f["way_id"] is None else "way not in our graph"] += 1
        lon, lat = graph.frame.to_wgs84(p.x_m, p.y_m) if p else (g["lon"], g["lat"])
        heading = math.degrees(p.bearing_rad) if p else g.get("heading_deg", 0.0)
        out.append({"t": g["t"], "lat": lat, "lon": lon, "fused_lat": g["lat"],
                    "fused_lon": g["lon"], "heading_deg": heading % 360.0,
                    "edge": {"u": p.edge.u, "v": p.edge.v} if p else None})
    return out, how


def run_peers(map_path: Path, graph: RoadGraph,
              drives: dict[int, list[dict[str, Any]]]
              ) -> tuple[dict[str, dict[int, Any]], dict[str, Any]] | None:
    """Both peers on every drive's GPS fixes, in .venv-peers, and the run's figures; None
    (saying why) when they are not set up."""
    cache = PEERS_CACHE / map_path.stem
    if not PEERS_PYTHON.exists():
        print(f"\npeers skipped: {PEERS_PYTHON} is missing (run: bash bench/peers/setup.sh)")
        return None
    if not (cache / "source.sha256").exists():
        print(f"\npeers skipped on {map_path.stem}: no {cache} (run: bash bench/peers/setup.sh "
              f"{map_path.stem}=<the OSM file {graph.info.source_name}>)")
        return None
    if (cache / "source.sha256").read_text().strip() != graph.info.source_sha256:
        print(f"\npeers skipped on {map_path.stem}: {cache} was built from another OSM file "
              f"than {map_path} ({graph.info.source_name}); rerun bench/peers/setup.sh")
        return None
    traces = {str(seed): [{"t": r["t"], "lat": r["lat"], "lon": r["lon"],
                           "sigma_m": GPS_SIGMA_M * r.get("hdop", 1.0)}
                          for r in d if r["kind"] == "gps"] for seed, d in drives.items()}
    with tempfile.TemporaryDirectory() as tmp:
        src, dst = Path(tmp) / "traces.json", Path(tmp) / "matched.json"
        src.write_text(json.dumps({"traces": traces}))
        subprocess.run([str(PEERS_PYTHON), str(BENCH / "peer_match.py"), str(cache), str(src),
                        str(dst)], check=True)
        found = json.loads(dst.read_text())
    meta = found.pop("meta")
    print(f"\npeers on {map_path.stem}: loaded in {meta['load_s']:.2f} s, matched "
          f"{meta['fixes']} fixes in OSRM {meta['match_s']['osrm']:.2f} s, Valhalla "
          f"{meta['match_s']['valhalla']:.2f} s ({meta['osrm_version']}, "
          f"{meta['valhalla_version']}); OSRM matchings per trace (gaps: split): "
          f"{sorted(Counter(meta['osrm_matchings'].values()).items())}")
    return {name: {int(s): fixes for s, fixes in found[key].items()}
            for name, key in zip(PEERS, ("osrm", "valhalla"))}, meta


# --- one drive --------------------------------------------------------------------------
def _row(seed: int, method: str, e: Evaluation, roads: RoadScore,
         outage_s: tuple[float, float]) -> dict[str, Any]:
    found = next((o for o in e.outages if o.start_s <= outage_s[0] + 1.0 <= o.end_s), None)
    return {"seed": seed, "method": method,
            "intersections_correct": e.intersections_correct,
            "intersections_total": e.intersections_total,
            "right_road_share": e.on_right_road_share, "position_rms_m": e.position.rms_m,
            "fused_rms_m": e.fused.rms_m, "raw_gps_rms_m": e.raw_gps.rms_m,
            "outage_end_error_m": found.end_error_m if found else None,
            "outage_drift_pct": found.drift_pct if found else None,
            "epochs": roads.epochs, "right_road_10m": roads.right,
            "right_road_10m_share": roads.right_share, "road_changes": roads.changes,
            "road_changes_right": roads.changes_right,
            "road_changes_share": roads.changes_share,
            "road_changes_unobservable": roads.changes_unobservable}


def _scored(seed: int, method: str, drive: list[dict[str, Any]],
            estimates: list[dict[str, Any]], outage_s: tuple[float, float]) -> dict[str, Any]:
    truth = truth_path(drive)
    epochs = epochs_of(drive, truth)
    return _row(seed, method, evaluate(drive, estimates),
                score(truth, epochs, roads_at(estimates, epochs)), outage_s)


Drive = tuple[list[dict[str, Any]], tuple[float, float]]  # truth and GPS records, outage


def _one_drive(job: tuple[str, int, float, bool]) -> tuple[list[dict[str, Any]], Drive]:
    """Our three matchers on one drive: their rows, and the drive's truth and GPS records
    with its outage (start, length)."""
    map_path, seed, duration, harsh = job
    graph = RoadGraph.open(map_path)
    if harsh:
        drive, _, outage_start = generalisation_eval.harsh_drive(graph, seed, duration)
        outage_s = (outage_start, generalisation_eval.OUTAGE_LENGTH_S)
    else:
        outage_s = outage(duration)
        drive = simulate_drive(graph, DriveSpec(duration_s=duration, seed=seed,
                                                outages=(outage_s,), tunnels_block_gps=False))
    packets = [r for r in drive if r["kind"] in set(SENSOR_KINDS["gyro_odometer"])]
    rows = [_scored(seed, "nearest road (raw GPS)", drive, nearest_road_baseline(graph, drive),
                    outage_s)]
    for feedback in (False, True):
        session = VehicleSession(SessionConfig(map_feedback=feedback), graph)
        out = [position_json(p, graph.frame) for p in session.add_records(packets).positions]
        rows.append(_scored(seed, "matcher + feedback" if feedback else "matcher", drive, out,
                            outage_s))
    return rows, ([r for r in drive if r["kind"] in ("truth", "gps")], outage_s)


def _evaluate_map(map_path: Path, seeds: list[int], duration: float, workers: int,
                  with_peers: bool, harsh: bool) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    drives: dict[int, Drive] = {}
    jobs = [(str(map_path), seed, duration, harsh) for seed in seeds]
    with ProcessPoolExecutor(workers) as pool:
        for seed, (found, drive) in zip(seeds, tqdm(pool.map(_one_drive, jobs), total=len(jobs),
                                                    desc=f"drives on {map_path.stem}")):
            rows += found
            drives[seed] = drive
    quirks: dict[str, Any] = {}
    if with_peers:
        found, quirks = _peer_rows(map_path, drives)
        rows += found
    for r in rows:
        r["map"] = map_path.stem
    return rows, quirks


def _peer_rows(map_path: Path, drives: dict[int, Drive]
               ) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """The peers' rows on the drives of one map, and how their fixes came out."""
    graph = RoadGraph.open(map_path)
    ran = run_peers(map_path, graph, {seed: drive for seed, (drive, _) in drives.items()})
    if ran is None:
        return [], {}
    peers, meta = ran
    ways = way_index(graph)
    rows, quirks = [], {"meta": meta}
    for name in PEERS:
        how: Counter[str] = Counter()
        for seed, (drive, outage_s) in drives.items():
            gps = [r for r in drive if r["kind"] == "gps"]
            estimates, counts = peer_estimates(graph, ways, gps, peers[name][seed])
            how += counts
            rows.append(_scored(seed, name, drive, estimates, outage_s))
        quirks[name] = dict(how)
        print(f"  {name}: fixes by outcome {dict(how)}")
    return rows, quirks


# --- tables -----------------------------------------------------------------------------
def _pct(values: list[float]) -> tuple[float, float]:
    finite = [v for v in values if v == v]
    return (100.0 * statistics.median(finite), 100.0 * min(finite)) if finite else (math.nan,) * 2


def road_table(rows: list[dict[str, Any]]) -> list[list[Any]]:
    table = []
    for m in dict.fromkeys(r["map"] for r in rows):
        for method in dict.fromkeys(r["method"] for r in rows if r["map"] == m):
            g = [r for r in rows if r["map"] == m and r["method"] == method]
            right, changes = _pct([r["right_road_10m_share"] for r in g]), \
                _pct([r["road_changes_share"] for r in g])
            made, total = sum(r["road_changes_right"] for r in g), sum(r["road_changes"] for r in g)
            pooled = 100.0 * sum(r["right_road_10m"] for r in g) / sum(r["epochs"] for r in g)
            table.append([m, method, *right, pooled, *changes, f"{made}/{total}",
                          statistics.mean(r["road_changes_unobservable"] for r in g)])
    return table


def evaluate_table(rows: list[dict[str, Any]]) -> list[list[Any]]:
    table = []
    for method in dict.fromkeys(r["method"] for r in rows):
        g = [r for r in rows if r["method"] == method]
        correct = sum(r["intersections_correct"] for r in g)
        total = sum(r["intersections_total"] for r in g)
        drift = [r["outage_drift_pct"] for r in g if r["outage_drift_pct"] is not None]
        shares = [r["right_road_share"] or 0.0 for r in g]
        table.append([method, f"{correct}/{total}", 100.0 * correct / max(total, 1),
                      100.0 * statistics.mean(shares), 100.0 * min(shares),
                      statistics.median(r["position_rms_m"] for r in g),
                      statistics.median(drift) if drift else float("nan"),
                      max(drift) if drift else float("nan")])
    return table


def main() -> None:
    parser = drives_parser(__doc__)
    parser.add_argument("--maps", type=Path, nargs="+",
                        help="several road-graph databases (instead of --map)")
    parser.add_argument("--seeds", choices=("report", "tune"), default="report",
                        help="REPORT_SEEDS (held out, default) or TUNE_SEEDS")
    parser.add_argument("--no-peers", action="store_true", help="leave out OSRM and Valhalla")
    parser.add_argument("--harsh", action="store_true",
                        help="the generalisation bench's harsh-urban drives and seed sets")
    args = parser.parse_args()
    if args.harsh:
        pool = generalisation_eval.REPORT_SEEDS if args.seeds == "report" \
            else generalisation_eval.TUNE_SEEDS
    else:
        pool = REPORT_SEEDS if args.seeds == "report" else TUNE_SEEDS
    seeds = list(pool[:args.drives])
    rows: list[dict[str, Any]] = []
    quirks: dict[str, Any] = {}
    for map_path in args.maps or [args.map]:
        found, quirks[map_path.stem] = _evaluate_map(map_path, seeds, args.duration,
                                                      args.workers, not args.no_peers,
                                                      args.harsh)
        rows += found
        at, length = outage(args.duration)
        drives = f"harsh-urban drives, {generalisation_eval.OUTAGE_LENGTH_S:.0f} s outage " \
            "mid-drive" if args.harsh else \
            f"drives, {length:.0f} s outage at {at:.0f} s"
        print_table(f"{map_path.stem}: online matching, {len(seeds)} {args.seeds} {drives} x "
                    f"{args.duration:.0f} s, gyro + odometer (navsvc.sim.evaluate)",
                    ["method", "intersections", "correct %", "right road % (mean)",
                     "right road % (worst drive)", "position RMS m (median)",
                     "outage drift % (median)", "drift max %"],
                    evaluate_table(found))
    print_table(f"Right road within 10 m along the path and road changes made correctly, at the "
                f"GPS fixes; {len(seeds)} {args.seeds} drives (seeds {seeds[0]}..{seeds[-1]}) x "
                f"{args.duration:.0f} s per map",
                ["map", "matcher", "right road % (median)", "right road % (worst)",
                 "right road % (all epochs)", "road changes % (median)",
                 "road changes % (worst)", "changes made", "unobservable per drive"],
                road_table(rows))
    write_json("matching_eval", {"drives": len(seeds), "seeds": args.seeds, "seed_list": seeds,
                                 "harsh": args.harsh,
                                 "duration_s": args.duration, "gps_sigma_m": GPS_SIGMA_M,
                                 "peer_outcomes": quirks, "rows": rows})


if __name__ == "__main__":
    main()
