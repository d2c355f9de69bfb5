"""Restart: how soon a restarted server serves its sessions again, and that nothing is lost.

Builds the trip log a crashed server leaves: ``--sessions`` open sessions with ``--duration``
seconds of data each (100 Hz IMU and 1 Hz GPS by default, sent in 0.1 s batches), saved as the
service saves them (a checkpoint every 200 packets, at most every second of packet time), each cut
at a random moment of its last seconds, so that each has a tail logged after its last
checkpoint. The
sessions are ``--drives`` distinct simulated drives, each copied to sessions/drives sessions of
the log with new ids: what that many vehicles on those routes would have written; running the
pipeline once per drive instead of once per session keeps the build affordable.

Then ``navsvc serve`` is started on it (a real process on loopback), timed from the moment it
is started:

- healthy: ``/v1/healthz`` answers 200;
- all sessions: every session has answered ``GET /v1/sessions/{id}`` with the packets it had
  acknowledged and the position the uninterrupted pipeline had (checked, one request after
  another, as the background restore runs); p50/p99 of those requests;
- background done: the server's log line for the last session rebuilt.

Rows: after a crash (``kill -9``, the tails replayed), after a graceful stop (checkpoints saved
at shutdown: nothing to replay), the same log without checkpoints (every session replays its
whole log, today's way before checkpoints; on ``--baseline-sessions`` sessions), and the floor:
the same server on an empty trip log. Medians of ``--repeats`` starts each.

    python bench/restart.py [--map maps/monaco.db] [--sessions 1000] [--drives 10]
        [--duration 600] [--imu-hz 100] [--repeats 3] [--baseline-sessions 50]
"""

from __future__ import annotations

import argparse
import re
import secrets
import shutil
import signal
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np
from report import print_table, write_json
from tqdm import tqdm

from navsvc.session import SessionStore
from navsvc.sim.simulate import DriveSpec, simulate_drive
from navsvc.triplog import TripLog, triplog_path_for
from navsvc.wire.positions import position_json
from roadgraph import RoadGraph

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # for tests.api.server
from tests.api.server import free_port  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


def build_drive_sessions(graph: RoadGraph, log_path: Path, drives: int, duration_s: float,
                         imu_hz: float) -> list[dict[str, Any]]:
    """Run each drive through a real SessionStore on the log (packet time as its clock), stop
    at a random moment of its last 5 s; return what each session had acknowledged."""
    clock = [0.0]  # the drives one after another: a store's clock never goes back
    store = SessionStore(graph, TripLog(log_path), clock=lambda: clock[0])
    rng = np.random.default_rng(7)
    expected = []
    for seed in tqdm(range(1, drives + 1), desc="drives", unit="drive"):
        start = clock[0]
        spec = DriveSpec(duration_s=duration_s, seed=seed, imu_rate_hz=imu_hz,
                         sensors=("imu", "gps"))
        stop_t = duration_s - rng.uniform(0.0, 5.0)
        packets = [r for r in simulate_drive(graph, spec) if r["kind"] != "truth"
                   and r["t"] <= stop_t]
        session = store.create("", f"car-{seed}", {"sensors": "gyro_accel"})
        batch: list[dict[str, Any]] = []
        for packet in packets:  # a message every 0.1 s, as a vehicle at real rate sends
            if batch and int(packet["t"] * 10) != int(batch[0]["t"] * 10):
                clock[0] = start + batch[-1]["t"]
                store.ingest(session, batch)
                batch = []
            batch.append(packet)
        store.ingest(session, batch)
        clock[0] = start + duration_s
        position = session.vehicle.last_position
        assert position is not None
        expected.append({"id": session.id, "packets": session.packets,
                         "position": position_json(position, graph.frame)})
    store.triplog.close()  # a crash: no checkpoint at shutdown
    return expected


def copy_sessions(log_path: Path, originals: list[dict[str, Any]], sessions: int,
                  checkpoints: bool) -> list[dict[str, Any]]:
    """Copy the drives' sessions (rows, and checkpoints when asked) until the log holds
    ``sessions``; the originals are closed. Returns each session's expected reply."""
    db = sqlite3.connect(log_path, isolation_level=None)
    db.execute("PRAGMA cache_size=-2000000")  # 2 GB: the index inserts stay in memory
    db.execute("BEGIN")
    expected = []
    for k in tqdm(range(sessions), desc="copy sessions", unit="session"):
        original = originals[k % len(originals)]
        new_id = secrets.token_hex(8)
        db.execute("INSERT INTO sessions (id, owner, vehicle_id, options, created_unix) "
                   "SELECT ?, owner, vehicle_id || '-' || ?, options, created_unix "
                   "FROM sessions WHERE id = ?", (new_id, k, original["id"]))
        (base,) = db.execute("SELECT coalesce(max(rowid), 0) FROM batches").fetchone()
        rowids = [r for (r,) in db.execute(
            "SELECT rowid FROM batches WHERE session_id = ? ORDER BY rowid",
            (original["id"],))]
        db.execute("INSERT INTO batches (session_id, seq, count, records, rejected, "
                   "client_seq, reply) SELECT ?, seq, count, records, rejected, client_seq, "
                   "reply FROM batches WHERE session_id = ? ORDER BY rowid",
                   (new_id, original["id"]))
        row = db.execute("SELECT batch_rowid, packets, rejected, state FROM checkpoints "
                         "WHERE session_id = ?", (original["id"],)).fetchone()
        assert row is not None, f"drive session {original['id']} has no checkpoint"
        if checkpoints:
            db.execute("INSERT INTO checkpoints VALUES (?, ?, ?, ?, ?)",
                       (new_id, base + 1 + rowids.index(row[0]), *row[1:]))
        expected.append({**original, "id": new_id})
    marks = ",".join("?" * len(originals))
    db.execute(f"UPDATE sessions SET closed = 1 WHERE id IN ({marks})",
               [o["id"] for o in originals])
    db.execute("COMMIT")
    db.execute("PRAGMA wal_checkpoint(TRUNCATE)")  # as a server's own checkpointer leaves it
    db.close()
    return expected


def time_start(db: Path, log: Path, expected: list[dict[str, Any]]) -> dict[str, Any]:
    """Start a server on ``db``; time it to healthy and to every session checked."""
    port = free_port()
    url = f"http://127.0.0.1:{port}/v1"
    start = time.monotonic()
    with log.open("w") as out:
        process = subprocess.Popen(
            [sys.executable, "-m", "navsvc", "serve", "--map", str(db), "--host", "127.0.0.1",
             "--port", str(port)], stdout=out, stderr=subprocess.STDOUT)
    client = httpx.Client(base_url=url, timeout=60.0)
    while True:
        try:
            if client.get("/healthz").status_code == 200:
                break
        except httpx.TransportError:
            if process.poll() is not None:
                raise RuntimeError(f"server exited: {log.read_text()}") from None
        time.sleep(0.01)
    healthy = time.monotonic() - start
    latencies, wrong = [], 0
    for e in expected:
        t = time.monotonic()
        try:
            info = client.get(f"/sessions/{e['id']}").json()
        except httpx.TimeoutException:
            process.kill()
            raise RuntimeError(f"GET /sessions/{e['id']} timed out; server log:\n"
                               f"{log.read_text()[-3000:]}") from None
        latencies.append(time.monotonic() - t)
        wrong += info["packets_accepted"] != e["packets"] or info["position"] != e["position"]
    all_sessions = time.monotonic() - start
    while expected and "restored in the background" not in log.read_text():
        time.sleep(0.05)
    text = log.read_text()
    background = re.search(r"(\d+) sessions restored in the background in ([\d.]+) s", text)
    return {"process": process, "healthy_s": healthy, "all_sessions_s": all_sessions,
            "wrong": wrong, "p50_ms": 1e3 * statistics.median(latencies) if latencies else 0.0,
            "p99_ms": 1e3 * float(np.percentile(latencies, 99)) if latencies else 0.0,
            "background_s": float(background.group(2)) if background else 0.0}


def measure(name: str, db: Path, work: Path, expected: list[dict[str, Any]], repeats: int,
            stop: str) -> dict[str, Any]:
    """Median of ``repeats`` starts; each ended with ``stop`` ("kill" keeps the tails)."""
    runs = []
    for i in range(repeats):
        run = time_start(db, work / f"{name}-{i}.log", expected)
        process = run.pop("process")
        process.send_signal(signal.SIGKILL if stop == "kill" else signal.SIGTERM)
        process.wait(timeout=120)
        runs.append(run)
    keys = ("healthy_s", "all_sessions_s", "background_s", "p50_ms", "p99_ms")
    return {"scenario": name, "sessions": len(expected),
            "wrong": sum(r["wrong"] for r in runs),
            **{k: statistics.median(r[k] for r in runs) for k in keys}, "runs": runs}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--map", type=Path, default=ROOT / "maps" / "monaco.db",
                        help="road-graph database (default maps/monaco.db)")
    parser.add_argument("--sessions", type=int, default=1000, help="open sessions in the log")
    parser.add_argument("--drives", type=int, default=10, help="distinct simulated drives")
    parser.add_argument("--duration", type=float, default=600.0, help="seconds of data each")
    parser.add_argument("--imu-hz", type=float, default=100.0, help="IMU rate (GPS is 1 Hz)")
    parser.add_argument("--repeats", type=int, default=3, help="starts per scenario")
    parser.add_argument("--baseline-sessions", type=int, default=50,
                        help="sessions in the no-checkpoint baseline (it replays everything)")
    args = parser.parse_args()
    graph = RoadGraph.open(args.map)
    with tempfile.TemporaryDirectory(prefix="navsvc-restart-") as tmp:
        work = Path(tmp)
        db, empty = work / "map.db", work / "empty" / "map.db"
        empty.parent.mkdir()
        shutil.copy(args.map, db)
        shutil.copy(args.map, empty)
        log_path = triplog_path_for(db)
        originals = build_drive_sessions(graph, log_path, args.drives, args.duration,
                                         args.imu_hz)
        baseline_db = work / "baseline" / "map.db"
        baseline_db.parent.mkdir()
        shutil.copy(args.map, baseline_db)
        shutil.copy(log_path, triplog_path_for(baseline_db))
        expected = copy_sessions(log_path, originals, args.sessions, checkpoints=True)
        baseline = copy_sessions(triplog_path_for(baseline_db), originals,
                                 args.baseline_sessions, checkpoints=False)
        packets = sum(e["packets"] for e in expected)
        print(f"trip log: {args.sessions} sessions, {packets:,} packets, "
              f"{log_path.stat().st_size / 1e9:.2f} GB")
        rows = [measure("floor: empty trip log", empty, work, [], args.repeats, "term"),
                measure("after a crash (kill -9)", db, work, expected, args.repeats, "kill"),
                measure("after a graceful stop", db, work, expected, 1, "term"),
                measure("after a graceful stop", db, work, expected, args.repeats, "term"),
                measure("no checkpoints (whole logs)", baseline_db, work, baseline, 1, "kill")]
        del rows[2]  # that start only made the shutdown checkpoints of the next row
    print_table(
        f"Restart with {args.sessions} sessions x {args.duration:.0f} s "
        f"({args.imu_hz:.0f} Hz IMU + 1 Hz GPS), median of {args.repeats} starts",
        ["scenario", "sessions", "healthy s", "all sessions checked s", "background done s",
         "GET p50 ms", "GET p99 ms", "wrong"],
        [[r["scenario"], r["sessions"], r["healthy_s"], r["all_sessions_s"], r["background_s"],
          r["p50_ms"], r["p99_ms"], r["wrong"]] for r in rows])
    write_json("restart", {"sessions": args.sessions, "duration_s": args.duration,
                           "imu_hz": args.imu_hz, "packets": packets,
                           "rows": [{k: v for k, v in r.items() if k != "runs"} for r in rows]})
    return 1 if any(r["wrong"] for r in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
