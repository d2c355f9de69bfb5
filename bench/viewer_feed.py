"""The map viewer feed's cost on the ingest path (navsvc/web/feed.py).

A simulated drive (gyro_odometer: 100 Hz IMU, 50 Hz odometer, 1 Hz GPS) goes through a real
SessionStore and trip log in batches of 10 packets, as a vehicle sends them; after each batch
``ViewerHub.publish`` runs as the API runs it. Rows: no hub call at all (the floor: the
timer's own cost), a session nobody watches (one dict lookup), and a watched session (fixes
decoded, history kept, an update queued for a viewer). Medians per batch, and the hub's share
of the whole ingest time; ``--repeats`` runs of each, alternating.

    python bench/viewer_feed.py [--map maps/monaco.db] [--duration 120] [--repeats 3]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from navsvc.session import SessionStore
from navsvc.sim.simulate import SENSOR_KINDS, DriveSpec, simulate_drive
from navsvc.triplog import TripLog
from navsvc.web.feed import ViewerHub
from roadgraph import RoadGraph

MODES = ("floor", "unwatched", "watched")


async def _run(graph: RoadGraph, batches: list[list[dict[str, Any]]], mode: str
               ) -> tuple[float, float, float]:
    with tempfile.TemporaryDirectory() as folder:
        triplog = TripLog(Path(folder) / "trips.db")
        store = SessionStore(graph, triplog)
        hub = ViewerHub()
        session = store.create("", "bench", {})
        viewer = hub.subscribe(session.id) if mode == "watched" else None
        ingest_ns, hub_ns = [], []
        for batch in batches:
            t0 = time.perf_counter_ns()
            done = store.ingest(session, batch)
            t1 = time.perf_counter_ns()
            if mode != "floor":
                assert done.result is not None
                hub.publish(session.id, done.result.records, done.reply)
            t2 = time.perf_counter_ns()
            ingest_ns.append(t1 - t0)
            hub_ns.append(t2 - t1)
            while viewer is not None and not viewer._queue.empty():  # a viewer that reads
                viewer._queue.get_nowait()
        triplog.close()
    return (statistics.median(ingest_ns) / 1e3, statistics.median(hub_ns) / 1e3,
            100.0 * sum(hub_ns) / sum(ingest_ns))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--map", type=Path, default=Path("maps/monaco.db"))
    parser.add_argument("--duration", type=float, default=120.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, default=Path("bench/results/viewer_feed.json"))
    args = parser.parse_args()
    graph = RoadGraph.open(args.map)
    kinds = set(SENSOR_KINDS["gyro_odometer"])
    drive = [r for r in simulate_drive(graph, DriveSpec(duration_s=args.duration, seed=2))
             if r["kind"] in kinds]
    batches = [drive[i:i + 10] for i in range(0, len(drive), 10)]
    runs: dict[str, list[tuple[float, float, float]]] = {m: [] for m in MODES}
    asyncio.run(_run(graph, batches[:200], "watched"))  # warm the kernels
    for _ in range(args.repeats):
        for mode in MODES:
            runs[mode].append(asyncio.run(_run(graph, batches, mode)))
    rows = {m: {"ingest_us_per_batch": statistics.median(r[0] for r in runs[m]),
                "hub_us_per_batch": statistics.median(r[1] for r in runs[m]),
                "hub_share_pct": statistics.median(r[2] for r in runs[m])} for m in MODES}
    print(f"{len(batches)} batches of 10 packets, medians of {args.repeats} runs")
    print(f"{'session':<12}{'ingest us/batch':>17}{'hub us/batch':>14}{'hub share %':>13}")
    for mode, row in rows.items():
        print(f"{mode:<12}{row['ingest_us_per_batch']:>17.1f}{row['hub_us_per_batch']:>14.2f}"
              f"{row['hub_share_pct']:>13.2f}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"batches": len(batches), "repeats": args.repeats,
                                    "rows": rows}, indent=2))


if __name__ == "__main__":
    main()
