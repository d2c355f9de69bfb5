"""Fusion speed: median µs per predict step and per measurement update, per configuration,
side by side with FilterPy's ExtendedKalmanFilter running the same model in the same run.

Both filters get identical state, covariance, Jacobians and noise from
``navsvc.fusion.road``; the timed work is what each filter does with them (FilterPy's
``predict``/``update``, our ``kalman.predict``/``correct`` with its gate), plus the
shared model evaluation. Needs the ``bench`` extra (``pip install -e '.[bench]'``).

    python bench/fusion_bench.py [--steps 20000]
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter
from report import median_us, print_table, write_json

from navsvc.fusion import PROFILES, FilterKind, FusionConfig, SensorConfig, kalman
from navsvc.fusion.kalman import Linearised
from navsvc.fusion.road import motion
from navsvc.fusion.road.measurements import GpsPosition, GyroRate, SteeringRate
from navsvc.fusion.road.motion import N_STATES

ROOT = Path(__file__).resolve().parent.parent

DT_S = 0.01  # 100 Hz inertial rate


def _state() -> tuple[np.ndarray, np.ndarray]:
    x = np.array([10.0, 20.0, 0.5, 12.0, 0.05, 0.001, 1.01, 0.02, 0.01, 1.0, -1.0, 0.1])
    P = np.diag([4.0, 4.0, 0.01, 0.5, 0.01, 1e-4, 1e-3, 1e-2, 4e-4, 9.0, 9.0, 0.01])
    assert len(x) == N_STATES
    return x, P


def _inertial(config: FusionConfig) -> Callable[[np.ndarray], Linearised] | None:
    """The measurement each configuration takes at the inertial rate."""
    used = config.profile.measurements
    if SteeringRate in used:
        return SteeringRate(0.02, config.wheelbase_m, 0.005).model
    if GyroRate in used:
        return GyroRate(-0.05, config.gyro_sigma_rps).model
    return None


def _time(fn: Callable[[], None], steps: int) -> list[float]:
    out = []
    clock = time.perf_counter
    for _ in range(steps):
        t0 = clock()
        fn()
        out.append(clock() - t0)
    return out


def bench(sensors: SensorConfig, steps: int) -> dict[str, float]:
    config = FusionConfig(sensors=sensors)
    accel = 0.3 if config.profile.speed_from_accel else None
    x0, P0 = _state()
    gps = GpsPosition(11.0, 21.0, 3.0).model
    inertial = _inertial(config)

    ours = {"x": x0.copy(), "P": P0.copy()}

    def our_predict() -> None:
        x, F, q = motion.propagate(ours["x"], DT_S, accel, config.process)
        ours["P"] = kalman.predict(ours["P"], F, q)
        ours["x"] = x

    def our_update(model: Callable[[np.ndarray], Linearised]) -> Callable[[], None]:
        def run() -> None:
            z, h, H, R = model(ours["x"])
            ours["x"], ours["P"], _ = kalman.correct(ours["x"], ours["P"], z, h, H, R,
                                                     kalman.gate_limit(len(z), 1e6))
        return run

    ekf = ExtendedKalmanFilter(dim_x=N_STATES, dim_z=2)
    ekf.x, ekf.P = x0.copy(), P0.copy()

    def fp_predict() -> None:
        x, F, q = motion.propagate(ekf.x, DT_S, accel, config.process)
        ekf.F, ekf.Q = F, np.diag(q)
        ekf.predict_x = lambda u=0: None  # the state was propagated by the model
        ekf.x = x
        ekf.predict()

    def fp_update(model: Callable[[np.ndarray], Linearised]) -> Callable[[], None]:
        def run() -> None:
            z, h, H, R = model(ekf.x)
            ekf.update(z, lambda _x: H, lambda _x: h, R=R)
        return run

    result = {}
    for name, ours_fn, theirs_fn in (
            ("predict", our_predict, fp_predict),
            ("inertial update", our_update(inertial) if inertial else None,
             fp_update(inertial) if inertial else None),
            ("GPS update", our_update(gps), fp_update(gps))):
        if ours_fn is None or theirs_fn is None:
            continue
        ours["x"], ours["P"] = x0.copy(), P0.copy()
        ekf.x, ekf.P = x0.copy(), P0.copy()
        a, b = [], []
        for _ in range(5):  # interleave to share the machine's noise
            a += _time(ours_fn, steps // 5)
            b += _time(theirs_fn, steps // 5)
            ours["x"], ours["P"] = x0.copy(), P0.copy()
            ekf.x, ekf.P = x0.copy(), P0.copy()
        result[f"{name} ours_us"] = median_us(a)
        result[f"{name} filterpy_us"] = median_us(b)
        assert math.isfinite(result[f"{name} ours_us"])
    return result


def engine_us_per_packet(sensors: SensorConfig, rounds: int = 5) -> float:
    """Median µs per packet through the whole engine (reorder window, filter, outputs) on a
    120 s simulated drive of the bundled map, all its packet kinds in time order."""
    from navsvc.fusion import FusionEngine
    from navsvc.sim.simulate import SENSOR_KINDS, DriveSpec, simulate_drive
    from navsvc.wire.packets import parse
    from roadgraph import RoadGraph

    graph = RoadGraph.open(ROOT / "maps" / "monaco.db")
    drive = simulate_drive(graph, DriveSpec(duration_s=120.0, seed=2))
    packets = [parse(r) for r in drive if r["kind"] in set(SENSOR_KINDS[sensors.value])]
    times = []
    for _ in range(rounds):
        engine = FusionEngine(FusionConfig(sensors=sensors), frame=graph.frame)
        started = time.perf_counter()
        for packet in packets:
            engine.add(packet)
        times.append((time.perf_counter() - started) / len(packets))
    return median_us(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--steps", type=int, default=20000)
    args = parser.parse_args()
    rows, data = [], {}
    for sensors in (s for s in SensorConfig if PROFILES[s].filter == FilterKind.ROAD):
        r = bench(sensors, args.steps)
        data[sensors.value] = r
        for step in ("predict", "inertial update", "GPS update"):
            if f"{step} ours_us" in r:
                ours, theirs = r[f"{step} ours_us"], r[f"{step} filterpy_us"]
                rows.append([sensors.value, step, ours, theirs, ours / theirs])
    print_table(f"Fusion step time, median µs over {args.steps} steps (same model, same run)",
                ["sensors", "step", "ours µs", "FilterPy µs", "ours / FilterPy"], rows)
    engine = {s.value: engine_us_per_packet(s) for s in (SensorConfig.GYRO_ODOMETER,
                                                         SensorConfig.GYRO_ACCEL)}
    print_table("Whole engine, median µs per packet of a 120 s drive (5 rounds; gyro_accel's "
                "packets are 99 % IMU)", ["sensors", "µs per packet"],
                [[name, us] for name, us in engine.items()])
    write_json("fusion_bench", {"steps": args.steps, "results": data,
                                "engine_us_per_packet": engine})


if __name__ == "__main__":
    main()
