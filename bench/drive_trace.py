"""One drive of the generalisation bench, epoch by epoch: where the fusion went wrong.

The generalisation bench (``bench/generalisation_eval.py``) scores drives as a whole; a drive
past a target needs looking into, epoch by epoch: the fused and matched errors against the
truth, the reported sigma, speed and heading beside the true ones, the fix's own error, the
match state and what the fusion did with the last fix (used or refused, and why). The drive is
the bench's own (same map, seed and duration give the same packets), replayed through
``VehicleSession`` as the bench replays it.

    python bench/drive_trace.py MAP SEED [--sensors gyro_odometer] [--mode ekf]
        [--start 0] [--end 300] [--every 10] [--set NAME=VALUE] [--json]
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from generalisation_eval import MAPS, _map_db, _overrides, _profile, harsh_drive

from navsvc.fusion import FusionConfig, GpsMode, SensorConfig
from navsvc.session import SessionConfig, VehicleSession
from navsvc.sim.simulate import SENSOR_KINDS
from roadgraph import RoadGraph


@dataclass(frozen=True)
class Epoch:
    """One output of the session beside the truth (metres, m/s, degrees clockwise from
    north; None where there is nothing to say)."""

    t: float
    fused_error_m: float
    matched_error_m: float
    sigma_m: float
    fix_error_m: float | None  # of a fix at this epoch
    speed_mps: float
    true_speed_mps: float
    heading_deg: float | None  # None while initialising
    heading_sigma_deg: float | None
    true_heading_deg: float
    state: str
    edge: str | None
    gps: str | None  # "used w0.85: accepted (nis 1.2)" or "refused: ..."


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("map", choices=sorted(MAPS), help="the bench's map")
    parser.add_argument("seed", type=int, help="the drive's seed (the bench's tune split: "
                        "1-1000, report: 100001-100200, validate: 200001-200200)")
    parser.add_argument("--sensors", default=SensorConfig.GYRO_ODOMETER.value,
                        choices=[c.value for c in SensorConfig], help="sensor configuration "
                        "(default gyro_odometer)")
    parser.add_argument("--mode", default=GpsMode.EKF.value, choices=[m.value for m in GpsMode],
                        help="GPS mode (default ekf)")
    parser.add_argument("--duration", type=float, default=300.0,
                        help="seconds of drive, as the bench's --duration (default 300)")
    parser.add_argument("--start", type=float, default=0.0, help="first epoch shown, s")
    parser.add_argument("--end", type=float, default=math.inf, help="last epoch shown, s")
    parser.add_argument("--every", type=int, default=1, help="show every Nth epoch")
    parser.add_argument("--map-feedback", action=argparse.BooleanOptionalAction,
                        default=True, help="the matched road corrects the filter "
                        "(default: with, as the bench)")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="override a FusionConfig number (repeatable)")
    parser.add_argument("--json", action="store_true",
                        help="print the drive's profile and epochs as JSON instead of a table")
    return parser


def _gps_note(estimate: Any) -> str | None:
    usage = estimate.gps
    if usage is None:
        return None
    nis = "" if usage.nis is None else f" (nis {usage.nis:.1f})"
    verdict = f"used w{usage.weight:.2f}" if usage.used else "refused"
    return f"{verdict}: {usage.reason}{nis}"


def trace(graph: RoadGraph, seed: int, duration_s: float, sensors: SensorConfig,
          mode: GpsMode, overrides: dict[str, float], map_feedback: bool
          ) -> tuple[dict[str, Any], list[Epoch]]:
    """The drive's error profile and every output of the session, beside the truth."""
    drive, spec, _ = harsh_drive(graph, seed, duration_s)
    frame = graph.frame
    truth = sorted((r for r in drive if r["kind"] == "truth"), key=lambda r: r["t"])
    true_t = np.array([r["t"] for r in truth])
    true_xy = np.array([frame.to_local(r["lon"], r["lat"]) for r in truth])
    true_speed = np.array([r["speed_mps"] for r in truth])
    true_heading = np.array([r["heading_deg"] for r in truth])
    fix_errors = {}
    for fix in (r for r in drive if r["kind"] == "gps"):
        x, y = frame.to_local(fix["lon"], fix["lat"])
        fix_errors[round(fix["t"], 3)] = math.hypot(
            x - np.interp(fix["t"], true_t, true_xy[:, 0]),
            y - np.interp(fix["t"], true_t, true_xy[:, 1]))
    kinds = set(SENSOR_KINDS[sensors.value]) | {"truth"}
    fusion = FusionConfig(sensors=sensors, gps_mode=mode, **overrides)  # type: ignore[arg-type]
    session = VehicleSession(SessionConfig(fusion, map_feedback=map_feedback), graph)
    result = session.add_records([r for r in drive if r["kind"] in kinds])
    epochs = []
    for position in result.positions:
        e = position.estimate
        x, y = np.interp(e.t, true_t, true_xy[:, 0]), np.interp(e.t, true_t, true_xy[:, 1])
        i = min(int(np.searchsorted(true_t, e.t)), len(true_t) - 1)
        edge = position.edge
        epochs.append(Epoch(
            t=round(e.t, 3), fused_error_m=math.hypot(e.x_m - x, e.y_m - y),
            matched_error_m=math.hypot(position.x_m - x, position.y_m - y),
            sigma_m=e.position_sigma_m, fix_error_m=fix_errors.get(round(e.t, 3)),
            speed_mps=e.speed_mps, true_speed_mps=float(true_speed[i]),
            heading_deg=math.degrees(e.heading_rad) % 360.0 if e.initialized else None,
            heading_sigma_deg=math.degrees(e.heading_sigma_rad) if e.initialized else None,
            true_heading_deg=float(true_heading[i]), state=position.state.value,
            edge=f"{edge.u}-{edge.v}" if edge else None, gps=_gps_note(e)))
    return _profile(spec), epochs


def _cell(value: float | None, digits: int = 1) -> str:
    return "-" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def _print(profile: dict[str, Any], epochs: list[Epoch]) -> None:
    print("profile:", ", ".join(f"{k} {v}" for k, v in profile.items()))
    print(f"{'t s':>7} {'fused m':>7} {'match m':>7} {'sigma m':>7} {'fix m':>6} "
          f"{'speed':>11} {'heading':>9} {'h sig':>5}  state       edge / GPS")
    for e in epochs:
        print(f"{e.t:7.1f} {e.fused_error_m:7.1f} {e.matched_error_m:7.1f} {e.sigma_m:7.1f} "
              f"{_cell(e.fix_error_m):>6} {_cell(e.speed_mps):>5}/{_cell(e.true_speed_mps):<5} "
              f"{_cell(e.heading_deg, 0):>4}/{_cell(e.true_heading_deg, 0):<4} "
              f"{_cell(e.heading_sigma_deg, 0):>5}  {e.state:<11} {e.edge or '-'}  "
              f"{e.gps or ''}")


def main() -> None:
    args = _parser().parse_args()
    graph = RoadGraph.open(_map_db(args.map))
    profile, epochs = trace(graph, args.seed, args.duration, SensorConfig(args.sensors),
                            GpsMode(args.mode), _overrides(args.set), args.map_feedback)
    shown = [e for e in epochs if args.start <= e.t <= args.end][::max(args.every, 1)]
    if args.json:
        print(json.dumps({"profile": profile, "epochs": [asdict(e) for e in shown]}))
    else:
        _print(profile, shown)


if __name__ == "__main__":
    main()
