"""Generalisation: fusion and matching on every map we have, under the harsh-urban profile.

The fusion met its targets on our own simulator and did worse than raw GPS on data it had never
seen (issue 15). This bench scores it where it cannot have been tuned: every map in the
repository (Monaco, Andorra, GraphHopper's test maps, FMM's Stockholm), each drive with its own
error levels drawn from its seed (``navsvc.sim.harsh``), a 60 s GPS outage in the middle, and
on every third seed the real urban-canyon GNSS error of UrbanNav Hong Kong replayed in place
of the synthetic one (``navsvc.sim.gnss_replay``; its own gaps come on top of the outage).
Tunnels block GPS as they do on the road. The car keeps its lane, off the centre line the map
holds (so map feedback gains only what it would on a real road).

Seeds come in three disjoint sets: TUNE for trying changes, VALIDATE for checking that a
change chosen on TUNE holds on drives it was not chosen on (a failure rate that TUNE's drives
under-sample shows there: Stockholm's drives past a target were 1 in 120 of TUNE and 5 in 100
of fresh seeds), REPORT for the figures quoted (use it once per change, never to choose
parameters). Each drive replays the same packets through ``VehicleSession`` (the code of
``navsvc run``) for each configuration: gyro_odometer with the EKF alone by default, every
sensor configuration x GPS mode with ``--all-configs``.
Scores and targets: ``navsvc.sim.scorecard``. Maps are imported with ``roadgraph import`` into
bench/.cache when missing.

    python bench/generalisation_eval.py [--split tune|validate|report] [--drives-per-map 6]
        [--duration 300] [--maps monaco,andorra,...] [--all-configs] [--workers 2]
"""

from __future__ import annotations

import argparse
import math
import shutil
import statistics
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, fields
from itertools import product
from pathlib import Path
from typing import Any

from report import print_table, write_json
from tqdm import tqdm

from navsvc.fusion import FusionConfig, GpsMode, SensorConfig
from navsvc.session import SessionConfig, VehicleSession
from navsvc.sim.gnss_replay import GnssErrorRecording, parse_urbannav
from navsvc.sim.harsh import harsh_urban_spec
from navsvc.sim.scorecard import (
    PHASES,
    Scorecard,
    check,
    circle_by_phase,
    pooled_circle_share,
    score,
)
from navsvc.sim.simulate import SENSOR_KINDS, DriveSpec, simulate_drive
from navsvc.wire.positions import position_json
from roadgraph import RoadGraph

ROOT = Path(__file__).resolve().parent.parent
CACHE = ROOT / "bench" / ".cache"
DATA = ROOT / "tests" / "data"
MAPS: dict[str, tuple[Path, float]] = {  # name: (source, consolidate_m)
    "monaco": (ROOT / "maps" / "monaco.osm.gz", 8.0),
    "andorra": (DATA / "graphhopper" / "andorra.osm.pbf", 8.0),
    "gh-issue-70": (DATA / "graphhopper" / "issue-70.osm.gz", 8.0),
    "gh-issue-13": (DATA / "graphhopper" / "map-issue13.osm.gz", 8.0),
    "stockholm": (DATA / "fmm" / "stockholm.graphml", 0.0),  # FMM's network, taken as it is
}
TUNE_SEEDS = tuple(range(1, 1001))  # for trying changes
REPORT_SEEDS = tuple(range(100_001, 100_201))  # for the figures quoted; never for choosing
VALIDATE_SEEDS = tuple(range(200_001, 200_201))  # a change chosen on TUNE, checked before
# REPORT
SPLITS = {"tune": TUNE_SEEDS, "validate": VALIDATE_SEEDS, "report": REPORT_SEEDS}
URBANNAV_EVERY = 3  # seeds divisible by this replay the UrbanNav error
OUTAGE_LENGTH_S = 60.0
EKF_ONLY = (SensorConfig.GPS_ONLY, SensorConfig.STRAPDOWN)
DEFAULT_CONFIG = (SensorConfig.GYRO_ODOMETER, GpsMode.EKF)

assert len(set().union(*SPLITS.values())) == sum(len(s) for s in SPLITS.values())


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--split", choices=list(SPLITS), default="tune",
                        help="which seeds (default tune; validate to check a change chosen on "
                        "tune; report only for quoted figures)")
    parser.add_argument("--drives-per-map", type=int, default=6, help="drives on each map")
    parser.add_argument("--duration", type=float, default=300.0, help="seconds per drive")
    parser.add_argument("--maps", default=",".join(MAPS),
                        help=f"comma-separated subset of {', '.join(MAPS)}")
    parser.add_argument("--all-configs", action="store_true",
                        help="every sensor configuration x GPS mode (default: gyro_odometer "
                        "+ ekf)")
    parser.add_argument("--configs", metavar="SENSORS:MODE,...",
                        help="these configurations instead, e.g. gyro_odometer:rules,"
                        "gyro_accel:ekf (the first counts as the default in the tables)")
    parser.add_argument("--workers", type=int, default=2, help="processes (at most 2 here)")
    parser.add_argument("--map-feedback", action=argparse.BooleanOptionalAction,
                        default=True, help="sessions with or without map feedback (the "
                        "matched road corrects the filter; default: with, as a session)")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="override a FusionConfig number for every run (tuning; "
                        "repeatable), e.g. --set gps_bias_tau_s=60")
    return parser


def _overrides(pairs: list[str]) -> dict[str, float]:
    """--set NAME=VALUE pairs, checked against FusionConfig's numeric fields."""
    numeric = {f.name: f.type for f in fields(FusionConfig) if f.type in ("float", "int")}
    out: dict[str, float] = {}
    for pair in pairs:
        name, _, value = pair.partition("=")
        if name not in numeric:
            raise SystemExit(f"--set {pair}: not a numeric FusionConfig field "
                             f"(choose from {', '.join(sorted(numeric))})")
        out[name] = int(value) if numeric[name] == "int" else float(value)
    return out


def _map_db(name: str) -> Path:
    """The map's database in bench/.cache, imported with `roadgraph import` when missing."""
    db = CACHE / f"{name}.db"
    if not db.exists():
        source, consolidate_m = MAPS[name]
        CACHE.mkdir(parents=True, exist_ok=True)
        exe = shutil.which("roadgraph") or str(Path(sys.executable).parent / "roadgraph")
        subprocess.run([exe, "import", str(source), "-o", str(db), "-q",
                        "--consolidate-m", str(consolidate_m)], check=True)
    return db


def _urbannav() -> GnssErrorRecording:
    folder = DATA / "urbannav"
    return parse_urbannav((folder / "spp_fixes.csv").read_text(),
                          (folder / "groundTruth_TST.csv").read_text())


def _configs(all_configs: bool, chosen: str | None = None
             ) -> list[tuple[SensorConfig, GpsMode]]:
    if chosen:
        pairs = [item.split(":") for item in chosen.split(",") if item]
        return [(SensorConfig(s), GpsMode(m)) for s, m in pairs]
    if not all_configs:
        return [DEFAULT_CONFIG]
    return [(s, m) for s, m in product(SensorConfig, GpsMode) if s not in EKF_ONLY
            or m == GpsMode.EKF]


def _profile(spec: DriveSpec) -> dict[str, Any]:
    """What the harsh profile drew for a drive (the JSON's record of it)."""
    e = spec.errors
    return {"gps_rate_hz": spec.gps_rate_hz, "odometer_rate_hz": spec.odometer_rate_hz,
            "odometer_reports": spec.odometer_reports,
            "gps_reports_velocity": spec.gps_reports_velocity,
            "gps_reports_hdop": spec.gps_reports_hdop,
            "gps_reports_height": spec.gps_reports_height,
            "start_standstill_s": round(spec.start_standstill_s, 1),
            "gps_markov_sigma_m": round(e.gps_markov_sigma_m, 2),
            "gps_markov_tau_s": round(e.gps_markov_tau_s, 1),
            "gps_nlos_rate_per_s": round(e.gps_nlos_rate_per_s, 5),
            "gps_latency_s": round(e.gps_latency_s, 3),
            "gyro_turn_on_bias_dps": e.gyro_turn_on_bias_dps,
            "gyro_scale_error": e.gyro_scale_error, "odometer_scale": e.odometer_scale,
            "imu_mount_deg": [round(a, 2) for a in e.imu_mount_deg]}


def harsh_drive(graph: RoadGraph, seed: int, duration: float
                ) -> tuple[list[dict[str, Any]], DriveSpec, float]:
    """One drive of this bench: its records, its spec and the start of its outage (also the
    drives of bench/tune_eval.py)."""
    urbannav = seed % URBANNAV_EVERY == 0
    outage_start = max(duration / 2.0 - OUTAGE_LENGTH_S / 2.0, 0.0)
    spec = harsh_urban_spec(DriveSpec(
        duration_s=duration, seed=seed, outages=((outage_start, OUTAGE_LENGTH_S),),
        full_imu=True, gps_error_replay=_urbannav() if urbannav else None))
    return simulate_drive(graph, spec), spec, outage_start


def _one_drive(job: tuple[str, int, float, bool, dict[str, float], str | None, bool]
               ) -> list[dict[str, Any]]:
    map_name, seed, duration, all_configs, overrides, chosen, feedback = job
    graph = RoadGraph.open(_map_db(map_name))
    urbannav = seed % URBANNAV_EVERY == 0
    drive, spec, outage_start = harsh_drive(graph, seed, duration)
    rows = []
    for sensors, mode in _configs(all_configs, chosen):
        started = time.perf_counter()
        kinds = set(SENSOR_KINDS[sensors.value]) | {"truth"}
        fusion = FusionConfig(sensors=sensors, gps_mode=mode, **overrides)  # type: ignore[arg-type]
        session = VehicleSession(SessionConfig(fusion, map_feedback=feedback), graph)
        result = session.add_records([r for r in drive if r["kind"] in kinds])
        estimates = [position_json(p, graph.frame) for p in result.positions]
        card = score(drive, estimates, outage_start)
        rows.append({"map": map_name, "seed": seed, "gps_error": "urbannav" if urbannav
                     else "synthetic", "sensors": sensors.value, "mode": mode.value,
                     "run_s": round(time.perf_counter() - started, 2), **asdict(card),
                     "circle_by_phase": circle_by_phase(drive, estimates, outage_start,
                                                        OUTAGE_LENGTH_S),
                     "profile": _profile(spec)})
    return rows


def _cards(rows: list[dict[str, Any]]) -> list[Scorecard]:
    fields = Scorecard.__dataclass_fields__
    return [Scorecard(**{k: r[k] for k in fields}) for r in rows]


def _values(rows: list[dict[str, Any]], key: str) -> list[float]:
    """The scores of ``key`` there are: an infinite one (no output) counts, None or NaN not."""
    return [r[key] for r in rows if r[key] is not None and not math.isnan(r[key])]


def _median(rows: list[dict[str, Any]], key: str) -> float:
    values = _values(rows, key)
    return statistics.median(values) if values else math.nan


def _worst(rows: list[dict[str, Any]], key: str) -> float:
    values = _values(rows, key)
    return max(values) if values else math.nan


def _pooled(rows: list[dict[str, Any]]) -> float:
    """The share of all the rows' epochs inside 2.45 sigma (:func:`pooled_circle_share`)."""
    pooled = pooled_circle_share(_cards(rows))
    return math.nan if pooled is None else pooled


def _no_output(rows: list[dict[str, Any]]) -> int:
    return sum(r["output_share"] == 0.0 for r in rows)


def _pct(value: float) -> float:
    return 100.0 * value


def _print_targets(rows: list[dict[str, Any]], title: str) -> None:
    table = []
    for name, median, worst, text, met in check(_cards(rows)):
        scale = 100.0 if name == "circle_share" else 1.0
        table.append([name, median * scale, worst * scale, text, "yes" if met else "NO"])
    pooled = _pooled(rows)
    table.append(["circle_share pooled %", _pct(pooled), math.nan,
                  "90-98 % of all the drives' epochs", "yes" if 0.90 <= pooled <= 0.98
                  else "NO"])
    table.append(["right_road_share %", _pct(_median(rows, "right_road_share")),
                  _pct(min((r["right_road_share"] for r in rows
                            if r["right_road_share"] is not None), default=math.nan)),
                  "(no target; worst = lowest)", ""])
    table.append(["mean NEES per dof", _median(rows, "mean_nees_per_dof"),
                  _worst(rows, "mean_nees_per_dof"), "(1 when consistent)", ""])
    table.append(["fixes to recover after outage", _median(rows, "recovery_fixes"),
                  _worst(rows, "recovery_fixes"),
                  "(issue: within 2x raw GPS RMS in <= 5 fixes, one a second)", ""])
    table.append(["output share %", _pct(_median(rows, "output_share")),
                  _pct(min(r["output_share"] for r in rows)),
                  f"(no target; worst = lowest; {_no_output(rows)} drives without output)", ""])
    print_table(title, ["score", "median", "worst drive", "target", "met"], table)


def _print_breakdown(rows: list[dict[str, Any]], key: str, title: str) -> None:
    table = []
    for value in sorted({r[key] for r in rows}):
        g = [r for r in rows if r[key] == value]
        table.append([value, len(g), _median(g, "raw_gps_rms_m"), _median(g, "fused_rms_m"),
                      _median(g, "fused_to_raw_ratio"), _worst(g, "fused_to_raw_ratio"),
                      _median(g, "outage_drift_pct"), _worst(g, "outage_drift_pct"),
                      _pct(_median(g, "circle_share")), _pct(_pooled(g)),
                      _worst(g, "max_matched_error_with_gps_m"),
                      _pct(_median(g, "right_road_share"))])
    print_table(title, [key, "drives", "raw GPS RMS m", "fused RMS m", "ratio", "ratio max",
                        "drift %", "drift max %", "in 2.45σ %", "pooled in 2.45σ %",
                        "max err w/ GPS m", "right road %"], table)


def _print_phases(rows: list[dict[str, Any]], title: str) -> None:
    """The 2.45-sigma circle by phase of the drive, pooled over the drives, with each
    phase's share of all the epochs outside it."""
    pooled = {p: [sum(r["circle_by_phase"][p][i] for r in rows) for i in (0, 1)]
              for p in PHASES}
    missed = sum(epochs - inside for inside, epochs in pooled.values())
    table = [[p, epochs, _pct(inside / epochs) if epochs else math.nan,
              _pct((epochs - inside) / missed) if missed else math.nan]
             for p, (inside, epochs) in pooled.items()]
    print_table(title, ["phase", "epochs", "in 2.45σ %", "of all epochs outside %"], table)


def _print_configs(rows: list[dict[str, Any]],
                   configs: list[tuple[SensorConfig, GpsMode]]) -> None:
    table = []
    for sensors, mode in configs:
        g = [r for r in rows if (r["sensors"], r["mode"]) == (sensors.value, mode.value)]
        met = sum(m for *_, m in check(_cards(g)))
        table.append([sensors.value, mode.value, _median(g, "fused_to_raw_ratio"),
                      _worst(g, "fused_to_raw_ratio"), _median(g, "outage_drift_pct"),
                      _worst(g, "outage_drift_pct"), _pct(_median(g, "circle_share")),
                      _pct(_pooled(g)), _worst(g, "max_matched_error_with_gps_m"),
                      _pct(_median(g, "right_road_share")), _worst(g, "recovery_fixes"),
                      _no_output(g), f"{met}/4"])
    print_table("Every configuration (medians; max where said)",
                ["sensors", "mode", "ratio", "ratio max", "drift %", "drift max %",
                 "in 2.45σ %", "pooled in 2.45σ %", "max err w/ GPS m", "right road %",
                 "recover fixes max",
                 "no output", "targets met"], table)


def main() -> None:
    args = _parser().parse_args()
    maps = [m for m in args.maps.split(",") if m]
    unknown = set(maps) - set(MAPS)
    if unknown:
        raise SystemExit(f"unknown maps {sorted(unknown)}; choose from {', '.join(MAPS)}")
    seeds = SPLITS[args.split]
    if len(maps) * args.drives_per_map > len(seeds):
        raise SystemExit(f"at most {len(seeds)} drives per split")
    for name in maps:  # once, before the workers start
        _map_db(name)
    overrides = _overrides(args.set)
    jobs = [(name, seeds[i * len(maps) + k], args.duration, args.all_configs, overrides,
             args.configs, args.map_feedback)
            for i in range(args.drives_per_map) for k, name in enumerate(maps)]
    rows: list[dict[str, Any]] = []
    started = time.perf_counter()
    with ProcessPoolExecutor(min(args.workers, 2)) as pool:
        for found in tqdm(pool.map(_one_drive, jobs), total=len(jobs), desc="drives"):
            rows += found
    wall_s = time.perf_counter() - started
    configs = _configs(args.all_configs, args.configs)
    main_config = DEFAULT_CONFIG if DEFAULT_CONFIG in configs else configs[0]
    default = [r for r in rows if (r["sensors"], r["mode"]) == (main_config[0].value,
                                                                 main_config[1].value)]
    name = f"{main_config[0].value} + {main_config[1].value}"
    head = (f"{len(jobs)} drives x {args.duration:.0f} s on {len(maps)} maps, {args.split} "
            f"split, harsh-urban profile, {OUTAGE_LENGTH_S:.0f} s outage mid-drive")
    _print_targets(default, f"Targets, {name}: {head}")
    _print_breakdown(default, "map", f"By map ({name}; medians, max where said)")
    _print_breakdown(default, "gps_error", f"By GPS error model ({name})")
    _print_phases(default, f"The 2.45-sigma circle by phase of the drive ({name}; pooled)")
    if len(configs) > 1:
        _print_configs(rows, configs)
    print(f"\nwall time {wall_s:.0f} s with {min(args.workers, 2)} workers")
    write_json(f"generalisation_eval_{args.split}", {
        "split": args.split, "drives": len(jobs), "duration_s": args.duration, "maps": maps,
        "outage_length_s": OUTAGE_LENGTH_S, "urbannav_every": URBANNAV_EVERY,
        "all_configs": args.all_configs, "map_feedback": args.map_feedback,
        "overrides": overrides, "wall_s": round(wall_s, 1),
        "targets": [dict(zip(("score", "median", "worst", "target", "met"), t))
                    for t in check(_cards(default))],
        "pooled_circle_share": _pooled(default), "rows": rows})


if __name__ == "__main__":
    main()
