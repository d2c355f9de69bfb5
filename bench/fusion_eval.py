"""Fusion accuracy on simulated urban drives: three GPS modes x five sensor configurations.

Each drive (fixed seeds) lasts 10 minutes on the sample map with a 60 s GPS outage starting
at 300 s. Every combination replays the same packets through ``VehicleSession`` (the code of
``navsvc run``) and is scored by ``navsvc.sim.evaluate``. Tunnels block GPS in the row group
``tunnels`` only (their gaps are long and vary by route, which blurs the outage figure).

    python bench/fusion_eval.py [--map maps/monaco.db] [--drives 10] [--duration 600]
"""

from __future__ import annotations

import statistics
from concurrent.futures import ProcessPoolExecutor
from itertools import product
from typing import Any

from report import drives_parser, print_table, write_json
from tqdm import tqdm

from navsvc.fusion import PROFILES, FusionConfig, GpsMode, SensorConfig
from navsvc.session import SessionConfig, VehicleSession
from navsvc.sim.evaluate import evaluate
from navsvc.sim.simulate import DriveSpec, simulate_drive
from navsvc.wire.positions import position_json
from roadgraph import RoadGraph

OUTAGE = (300.0, 60.0)


def _one_drive(job: tuple[str, int, float, bool]) -> list[dict[str, Any]]:
    map_path, seed, duration, tunnels = job
    graph = RoadGraph.open(map_path)
    spec = DriveSpec(duration_s=duration, seed=seed, outages=(OUTAGE,),
                     tunnels_block_gps=tunnels, full_imu=True)
    drive = simulate_drive(graph, spec)
    rows = []
    combos = [(s, m) for s, m in product(SensorConfig, GpsMode)
              if m in PROFILES[s].gps_modes] if not tunnels else \
        [(SensorConfig.GYRO_ODOMETER, GpsMode.EKF)]
    for sensors, mode in combos:
        kinds = PROFILES[sensors].packets | {"truth"}
        session = VehicleSession(SessionConfig(FusionConfig(sensors=sensors, gps_mode=mode)),
                                 graph)
        result = session.add_records([r for r in drive if r["kind"] in kinds])
        out = [position_json(p, graph.frame) for p in result.positions]
        e = evaluate(drive, out)
        outage = next((o for o in e.outages if o.start_s <= OUTAGE[0] + 1.0 <= o.end_s), None)
        rows.append({"seed": seed, "sensors": sensors.value, "mode": mode.value,
                     "tunnels": tunnels, "fused_rms_m": e.fused.rms_m,
                     "raw_gps_rms_m": e.raw_gps.rms_m, "ratio": e.fused_to_raw_ratio,
                     "heading_rms_deg": e.heading_rms_deg,
                     "outage_distance_m": outage.distance_m if outage else None,
                     "outage_end_error_m": outage.end_error_m if outage else None,
                     "outage_drift_pct": outage.drift_pct if outage else None})
    return rows


def _median(rows: list[dict[str, Any]], key: str) -> float:
    values = [r[key] for r in rows if r[key] is not None]
    return statistics.median(values) if values else float("nan")


def _max(rows: list[dict[str, Any]], key: str) -> float:
    values = [r[key] for r in rows if r[key] is not None]
    return max(values) if values else float("nan")


def main() -> None:
    args = drives_parser(__doc__).parse_args()
    jobs = [(str(args.map), seed, args.duration, tunnels)
            for tunnels in (False, True) for seed in range(1, args.drives + 1)]
    rows: list[dict[str, Any]] = []
    with ProcessPoolExecutor(args.workers) as pool:
        for found in tqdm(pool.map(_one_drive, jobs), total=len(jobs), desc="drives"):
            rows += found
    table = []
    groups = sorted({(r["tunnels"], r["sensors"], r["mode"]) for r in rows})
    for tunnels, sensors, mode in groups:
        g = [r for r in rows if (r["tunnels"], r["sensors"], r["mode"]) == (tunnels, sensors,
                                                                            mode)]
        table.append(["tunnels" if tunnels else "open sky", sensors, mode,
                      _median(g, "fused_rms_m"), _median(g, "raw_gps_rms_m"),
                      _median(g, "ratio"), _max(g, "ratio"), _median(g, "outage_drift_pct"),
                      _max(g, "outage_drift_pct"), _median(g, "heading_rms_deg")])
    print_table(f"Fusion accuracy, {args.drives} drives x {args.duration:.0f} s, 60 s outage at "
                f"300 s (medians over drives; max where said)",
                ["GPS", "sensors", "mode", "fused RMS m", "raw GPS RMS m", "ratio",
                 "ratio max", "outage drift %", "drift max %", "heading RMS deg"], table)
    write_json("fusion_eval", {"drives": args.drives, "duration_s": args.duration,
                               "outage": OUTAGE, "rows": rows})


if __name__ == "__main__":
    main()
