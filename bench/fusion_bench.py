"""Fusion speed: median µs per predict step and per measurement update, per configuration,
side by side with FilterPy's ExtendedKalmanFilter running the same model in the same run.

Both filters get identical state, covariance, Jacobians and noise from
``navsvc.fusion.road``; the timed work is what each filter does with them (FilterPy's
``predict``/``update``, our ``kalman.predict``/``correct`` with its gate), plus the
shared model evaluation. Needs the ``bench`` extra (``pip install -e '.[bench]'``).

Then the whole engine a packet at a time, and the ingest of issue 17 in messages of 0.1 s
of a drive (10 IMU packets; gyro_odometer adds 5 odometer ones; a GPS fix a second), per IMU
packet (all the message's time over its IMU packets), the batched path beside the
per-packet reference in the same run, rounds interleaved:

- engine: ``FusionEngine.add_run`` over the runs between fixes (made beforehand, as the
  session makes them from the decoded message), ``add`` for the fixes, against ``add`` for
  every packet;
- ingest: a session's whole message: decode and validate the JSON text
  (``navsvc.wire.bulk``), filter, matcher steps, reply, trip-log append (a real SQLite file),
  as ``SessionStore.ingest`` does it for the WebSocket; against ``json.loads``, the pydantic
  parser and ``add`` packet by packet (``VehicleSession.add_records_per_packet``) and the log
  append that encodes the records; and the batched ingest with the service's group commit
  (``GROUP_BATCHES`` messages a commit). Where its time goes: a cProfile of one batched
  round (a commit each message).

    python bench/fusion_bench.py [--steps 20000] [--seconds 60] [--rounds 5]
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter
from report import median_us, print_table, write_json

from navsvc.fusion import PROFILES, FilterKind, FusionConfig, SensorConfig, kalman
from navsvc.fusion.kalman import Linearised
from navsvc.fusion.road import motion
from navsvc.fusion.road.measurements import GpsPosition, GyroRate, SteeringRate
from navsvc.fusion.road.motion import N_STATES
from roadgraph import RoadGraph

ROOT = Path(__file__).resolve().parent.parent

DT_S = 0.01  # 100 Hz inertial rate
GROUP_BATCHES = 20  # messages a trip-log commit holds in the "grouped" ingest (the service
# commits the messages of one event-loop turn together: 40-65 at 200 real-rate sessions)


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


def _messages(graph: RoadGraph, sensors: SensorConfig, seconds: float
              ) -> list[list[dict[str, Any]]]:
    """The packets of each 0.1 s of a simulated drive (as bench/service_load.py sends them)."""
    from navsvc.sim.simulate import SENSOR_KINDS, DriveSpec, simulate_drive

    kinds = set(SENSOR_KINDS[sensors.value])
    drive = [r for r in simulate_drive(graph, DriveSpec(duration_s=seconds, seed=7,
                                                        tunnels_block_gps=False))
             if r["kind"] in kinds]
    ticks: list[list[dict[str, Any]]] = [[] for _ in range(int(drive[-1]["t"] / 0.1) + 1)]
    for r in drive:
        ticks[int(r["t"] / 0.1)].append(r)
    return [t for t in ticks if t]


def _as_runs(packets: list[Any]) -> list[Any]:
    """A message's packets as the session hands them to the engine: the fixes, and runs of
    the samples between them (built before the clock starts: the session builds its runs from
    the decoded message, inside the ingest rows)."""
    from navsvc.fusion.road.batch import SampleRun
    from navsvc.types import GpsFix

    items: list[Any] = []
    i = 0
    while i < len(packets):
        if isinstance(packets[i], GpsFix):
            items.append(packets[i])
            i += 1
            continue
        j = i + 1
        while j < len(packets) and not isinstance(packets[j], GpsFix):
            j += 1
        items.append(SampleRun.of(packets[i:j]))
        i = j
    return items


def _engine_over(engine: Any, items: list[Any]) -> None:
    """A message's fixes and runs through the engine (``add``, ``add_run``)."""
    from navsvc.fusion.road.batch import SampleRun

    for item in items:
        if isinstance(item, SampleRun):
            k = 0
            while k < len(item):
                k = engine.add_run(item, k)[0]
        else:
            engine.add(item)


def _ingest_grouped(store: Any, options: dict[str, Any], texts: list[str]) -> None:
    """The batched ingest as the WebSocket route does it, with its group commit
    (``GROUP_BATCHES`` messages a commit)."""
    from navsvc.session import MAX_CLIENT_SEQ
    from navsvc.wire import bulk

    session = store.create("", "bench", options)
    for n, text in enumerate(texts):
        decoded = bulk.decode_batch(text, MAX_CLIENT_SEQ)
        assert decoded is not None
        store.ingest(session, decoded[1], decoded[0], defer_commit=True)
        if n % GROUP_BATCHES == GROUP_BATCHES - 1:
            store.triplog.commit()
    store.triplog.commit()


def _cases(graph: RoadGraph, sensors: SensorConfig, messages: list[list[dict[str, Any]]],
           store: Any) -> dict[str, Callable[[], None]]:
    """The timed runs over the messages: engine and ingest, batched and per packet, and the
    batched ingest with group commit."""
    from navsvc.fusion import FusionEngine
    from navsvc.session import MAX_CLIENT_SEQ
    from navsvc.wire import bulk
    from navsvc.wire.packets import parse

    texts = [json.dumps({"type": "batch", "seq": n, "packets": m}) for n, m in
             enumerate(messages)]
    parsed = [[parse(r) for r in m] for m in messages]
    runs = [_as_runs(packets) for packets in parsed]
    options = {"sensors": sensors.value}
    config = FusionConfig(sensors=sensors)

    def engine_batched() -> None:
        engine = FusionEngine(config, frame=graph.frame)
        for items in runs:
            _engine_over(engine, items)

    def engine_per_packet() -> None:
        engine = FusionEngine(config, frame=graph.frame)
        for packets in parsed:
            for p in packets:
                engine.add(p)

    def ingest_batched() -> None:  # as the WebSocket route does it
        session = store.create("", "bench", options)
        for text in texts:
            decoded = bulk.decode_batch(text, MAX_CLIENT_SEQ)
            assert decoded is not None
            store.ingest(session, decoded[1], decoded[0])

    def ingest_per_packet() -> None:  # as it did before issue 17
        session = store.create("", "bench", options)
        session.vehicle.add_records = session.vehicle.add_records_per_packet
        for text in texts:
            message = json.loads(text)
            store.ingest(session, message["packets"], message["seq"])

    return {"engine batched": engine_batched, "engine per packet": engine_per_packet,
            "ingest batched": ingest_batched, "ingest per packet": ingest_per_packet,
            "ingest grouped": lambda: _ingest_grouped(store, options, texts)}


def ingest_us_per_imu_packet(graph: RoadGraph, sensors: SensorConfig, seconds: float,
                             rounds: int, tmp: Path) -> dict[str, Any]:
    """The engine and the whole ingest, batched and per packet, µs per IMU packet (medians
    of ``rounds`` interleaved rounds over a ``seconds`` drive)."""
    from navsvc.session import SessionStore
    from navsvc.triplog import TripLog

    messages = _messages(graph, sensors, seconds)
    imu = sum(r["kind"] == "imu" for m in messages for r in m)
    log = TripLog(tmp / f"{sensors.value}.trips.db")
    cases = _cases(graph, sensors, messages, SessionStore(graph, log))
    for fn in cases.values():  # compile, fill caches
        fn()
    times: dict[str, list[float]] = {name: [] for name in cases}
    cpu: dict[str, list[float]] = {name: [] for name in cases}
    for _ in range(rounds):
        for name, fn in cases.items():
            started, started_cpu = time.perf_counter(), time.process_time()
            fn()
            cpu[name].append((time.process_time() - started_cpu) / imu)
            times[name].append((time.perf_counter() - started) / imu)
    result: dict[str, Any] = {name: median_us(t) for name, t in times.items()}
    result |= {f"{name} cpu": median_us(t) for name, t in cpu.items()}
    result["imu_packets"] = imu
    result["packets"] = sum(map(len, messages))
    result["where_ingest_time_goes_pct"] = _profile(cases["ingest batched"])
    log.close()
    return result


PROFILE_PARTS = {  # (module path, function) whose cumulative time is a part of the ingest
    "decode + validate (msgspec)": ("navsvc/wire/bulk.py", "decode_batch"),
    "filter (engine add_run/add)": ("navsvc/fusion/engine.py", "add_run"),
    "filter, GPS fixes (engine add)": ("navsvc/fusion/engine.py", "add"),
    "matcher steps": ("navsvc/matching/online.py", "update"),
    "reply (positions JSON)": ("navsvc/session.py", "batch_reply"),
    "trip log append (SQLite)": ("navsvc/triplog.py", "append"),
    "checkpoints (pickle + SQLite)": ("navsvc/session.py", "checkpoint"),
}


def _profile(fn: Callable[[], None]) -> dict[str, float]:
    """Shares of ``fn``'s time (cProfile, cumulative) of the parts of the ingest."""
    import cProfile
    import pstats

    profiler = cProfile.Profile()
    profiler.runcall(fn)
    stats = pstats.Stats(profiler).stats  # type: ignore[attr-defined]
    total = max(ct for (_, _, _, ct, _) in stats.values())
    shares = {}
    for part, (path, name) in PROFILE_PARTS.items():
        cumulative = sum(ct for (file, _, fname), (_, _, _, ct, _) in stats.items()
                         if file.endswith(path) and fname == name)
        shares[part] = 100.0 * cumulative / total
    shares["engine: of which the compiled runs"] = 100.0 * sum(
        ct for (file, _, fname), (_, _, _, ct, _) in stats.items()
        if file.endswith("navsvc/fusion/road/batch.py") and fname == "run_samples") / total
    return shares


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--steps", type=int, default=20000)
    parser.add_argument("--seconds", type=float, default=60.0,
                        help="drive length of the ingest rows")
    parser.add_argument("--rounds", type=int, default=5, help="interleaved rounds")
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
    graph = RoadGraph.open(ROOT / "maps" / "monaco.db")
    ingest = {}
    with tempfile.TemporaryDirectory() as tmp:
        for sensors in (SensorConfig.GYRO_ACCEL, SensorConfig.GYRO_ODOMETER):
            ingest[sensors.value] = ingest_us_per_imu_packet(graph, sensors, args.seconds,
                                                             args.rounds, Path(tmp))
    print_table(f"Ingest in messages of 0.1 s (10 IMU packets), median µs per IMU packet of "
                f"{args.rounds} interleaved rounds over a {args.seconds:.0f} s drive "
                "(target <= 5; wall clock, and this process's CPU time, which a shared "
                "machine inflates less)",
                ["sensors", "path", "batched µs", "per packet µs", "per packet / batched",
                 "batched CPU µs", "per packet CPU µs"],
                [[name, part, r[f"{part} batched"], r[f"{part} per packet"],
                  r[f"{part} per packet"] / r[f"{part} batched"], r[f"{part} batched cpu"],
                  r[f"{part} per packet cpu"]]
                 for name, r in ingest.items() for part in ("engine", "ingest")])
    print_table(f"Ingest with the service's group commit ({GROUP_BATCHES} messages a "
                "commit; one session here, whose rows share pages as many sessions' do not), "
                "median µs per IMU packet", ["sensors", "grouped µs", "grouped CPU µs",
                                            "commit each / grouped (CPU)"],
                [[name, r["ingest grouped"], r["ingest grouped cpu"],
                  r["ingest batched cpu"] / r["ingest grouped cpu"]]
                 for name, r in ingest.items()])
    print_table("Where the batched ingest's time goes (% of it, cProfile cumulative; parts "
                "overlap: the matcher's share includes its map feedback into the filter)",
                ["part", *ingest], [[part, *(r["where_ingest_time_goes_pct"][part]
                                             for r in ingest.values())]
                                    for part in next(iter(ingest.values()))[
                                        "where_ingest_time_goes_pct"]])
    write_json("fusion_bench", {"steps": args.steps, "results": data,
                                "engine_us_per_packet": engine,
                                "ingest_us_per_imu_packet": ingest})


if __name__ == "__main__":
    main()
