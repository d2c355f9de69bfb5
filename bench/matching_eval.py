"""Online map matching on simulated urban drives: the matcher with and without map feedback,
and nearest-road snapping of the raw GPS fixes as the baseline.

Each drive (fixed seeds) lasts 10 minutes on the sample map with a 60 s GPS outage at 300 s;
gyro + odometer, ``ekf`` fusion. Scored by ``navsvc.sim.evaluate`` (intersections traversed
correctly, share of epochs on the right road, errors, outage drift).

    python bench/matching_eval.py [--map maps/monaco.db] [--drives 10] [--duration 600]
"""

from __future__ import annotations

import statistics
from concurrent.futures import ProcessPoolExecutor
from typing import Any

from report import drives_parser, print_table, write_json
from tqdm import tqdm

from navsvc.session import SessionConfig, VehicleSession
from navsvc.sim.evaluate import Evaluation, evaluate
from navsvc.sim.simulate import SENSOR_KINDS, DriveSpec, simulate_drive
from navsvc.wire.positions import position_json
from roadgraph import RoadGraph

OUTAGE = (300.0, 60.0)


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


def _row(seed: int, method: str, e: Evaluation) -> dict[str, Any]:
    outage = next((o for o in e.outages if o.start_s <= OUTAGE[0] + 1.0 <= o.end_s), None)
    return {"seed": seed, "method": method,
            "intersections_correct": e.intersections_correct,
            "intersections_total": e.intersections_total,
            "right_road_share": e.on_right_road_share, "position_rms_m": e.position.rms_m,
            "fused_rms_m": e.fused.rms_m, "raw_gps_rms_m": e.raw_gps.rms_m,
            "outage_end_error_m": outage.end_error_m if outage else None,
            "outage_drift_pct": outage.drift_pct if outage else None}


def _one_drive(job: tuple[str, int, float]) -> list[dict[str, Any]]:
    map_path, seed, duration = job
    graph = RoadGraph.open(map_path)
    drive = simulate_drive(graph, DriveSpec(duration_s=duration, seed=seed, outages=(OUTAGE,),
                                            tunnels_block_gps=False))
    packets = [r for r in drive if r["kind"] in set(SENSOR_KINDS["gyro_odometer"])]
    rows = [_row(seed, "nearest road (raw GPS)",
                 evaluate(drive, nearest_road_baseline(graph, drive)))]
    for feedback in (False, True):
        session = VehicleSession(SessionConfig(map_feedback=feedback), graph)
        out = [position_json(p, graph.frame) for p in session.add_records(packets).positions]
        rows.append(_row(seed, "matcher + feedback" if feedback else "matcher",
                         evaluate(drive, out)))
    return rows


def main() -> None:
    args = drives_parser(__doc__).parse_args()
    jobs = [(str(args.map), seed, args.duration) for seed in range(1, args.drives + 1)]
    rows: list[dict[str, Any]] = []
    with ProcessPoolExecutor(args.workers) as pool:
        for found in tqdm(pool.map(_one_drive, jobs), total=len(jobs), desc="drives"):
            rows += found
    table = []
    for method in dict.fromkeys(r["method"] for r in rows):
        g = [r for r in rows if r["method"] == method]
        correct = sum(r["intersections_correct"] for r in g)
        total = sum(r["intersections_total"] for r in g)
        drift = [r["outage_drift_pct"] for r in g if r["outage_drift_pct"] is not None]
        table.append([method, f"{correct}/{total}", 100.0 * correct / max(total, 1),
                      100.0 * statistics.mean(r["right_road_share"] for r in g),
                      100.0 * min(r["right_road_share"] for r in g),
                      statistics.median(r["position_rms_m"] for r in g),
                      statistics.median(drift) if drift else float("nan"),
                      max(drift) if drift else float("nan")])
    print_table(f"Online matching, {args.drives} drives x {args.duration:.0f} s, gyro + odometer, "
                f"60 s outage at 300 s",
                ["method", "intersections", "correct %", "right road % (mean)",
                 "right road % (worst drive)", "position RMS m (median)",
                 "outage drift % (median)", "drift max %"], table)
    write_json("matching_eval", {"drives": args.drives, "duration_s": args.duration,
                                 "rows": rows})


if __name__ == "__main__":
    main()
