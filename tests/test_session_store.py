"""SessionStore: a failed trip-log write leaves memory exactly as the log says."""

from __future__ import annotations

import asyncio
import json
import sqlite3
import time
from pathlib import Path

import pytest

from navsvc.api.app import _drop_closed_logs
from navsvc.session import SessionStore
from navsvc.triplog import LoggedSession, TripLog
from roadgraph import RoadGraph

GPS = [{"t": float(i), "kind": "gps", "lat": 43.7384 + 1e-4 * i, "lon": 7.4246,
        "speed_mps": 11.0} for i in range(6)]


def test_failed_log_write_rebuilds_the_session_from_the_log(
        sample_graph: RoadGraph, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    store = SessionStore(sample_graph, TripLog(tmp_path / "trips.db"))
    session = store.create("", "car", {"sensors": "gps_only"})
    store.ingest(session, GPS[:3])

    def broken(*args: object) -> None:
        raise sqlite3.OperationalError("disk I/O error")

    monkeypatch.setattr(store.triplog, "append", broken)
    with pytest.raises(sqlite3.OperationalError):
        store.ingest(session, GPS[3:])
    rebuilt = store.get(session.id, "")
    assert rebuilt.packets == 3  # the failed batch is not in memory either
    assert rebuilt.vehicle.engine.t == GPS[2]["t"]
    monkeypatch.undo()
    store.ingest(rebuilt, GPS[3:])  # the client sends the batch again
    assert store.get(session.id, "").packets == 6


def test_log_keeps_packets_in_order_across_batches_and_restores(
        sample_graph: RoadGraph, tmp_path: Path) -> None:
    store = SessionStore(sample_graph, TripLog(tmp_path / "trips.db"))
    session = store.create("", "car", {"sensors": "gps_only"})
    bad = {"t": 2.5, "kind": "gps", "lat": 91.0, "lon": 7.4246}
    store.ingest(session, [*GPS[:3], bad])  # the refused fix is not logged
    store.ingest(session, GPS[3:])
    log = TripLog(tmp_path / "trips.db")
    assert list(log.packets(session.id)) == GPS
    restored = SessionStore(sample_graph, log)
    restored.restore()
    again = restored.get(session.id, "")
    assert again.packets == 6
    assert again.vehicle.engine.t == session.vehicle.engine.t


def test_log_written_a_row_a_packet_is_moved_to_batches(tmp_path: Path) -> None:
    path = tmp_path / "trips.db"
    TripLog(path).close()
    db = sqlite3.connect(path)
    db.executescript("""
        CREATE TABLE packets (session_id TEXT NOT NULL, seq INTEGER NOT NULL,
                              record TEXT NOT NULL, PRIMARY KEY (session_id, seq));
        INSERT INTO sessions (id, owner, vehicle_id, options, created_unix)
            VALUES ('s1', '', 'car', '{}', 0);
        INSERT INTO packets VALUES ('s1', 1, '{"t":1.0}'), ('s1', 0, '{"t":0.0}');
    """)
    db.close()
    log = TripLog(path)
    assert list(log.packets("s1")) == [{"t": 0.0}, {"t": 1.0}]
    assert log._db.execute("SELECT name FROM sqlite_master WHERE name = 'packets'"
                           ).fetchone() is None


def test_batches_of_a_without_rowid_table_are_moved_over(tmp_path: Path) -> None:
    path = tmp_path / "trips.db"
    db = sqlite3.connect(path)
    db.executescript("""
        CREATE TABLE sessions (id TEXT PRIMARY KEY, owner TEXT NOT NULL,
            vehicle_id TEXT NOT NULL, options TEXT NOT NULL, created_unix REAL NOT NULL,
            closed INTEGER NOT NULL DEFAULT 0);
        CREATE TABLE batches (session_id TEXT NOT NULL, seq INTEGER NOT NULL,
            count INTEGER NOT NULL, records TEXT NOT NULL,
            PRIMARY KEY (session_id, seq)) WITHOUT ROWID;
        INSERT INTO sessions (id, owner, vehicle_id, options, created_unix)
            VALUES ('s1', '', 'car', '{}', 0);
        INSERT INTO batches VALUES ('s1', 2, 1, '[{"t":2.0}]'),
                                   ('s1', 0, 2, '[{"t":0.0},{"t":1.0}]');
    """)
    db.close()
    log = TripLog(path)
    assert list(log.packets("s1")) == [{"t": 0.0}, {"t": 1.0}, {"t": 2.0}]
    sql = log._db.execute("SELECT sql FROM sqlite_master WHERE name = 'batches'").fetchone()[0]
    assert "WITHOUT ROWID" not in sql.upper()
    log.append("s1", 3, [{"t": 3.0}])
    assert list(log.packets("s1")) == [{"t": 0.0}, {"t": 1.0}, {"t": 2.0}, {"t": 3.0}]


def test_batch_json_as_received_is_logged_only_when_all_are_accepted(
        sample_graph: RoadGraph, tmp_path: Path) -> None:
    store = SessionStore(sample_graph, TripLog(tmp_path / "trips.db"))
    session = store.create("", "car", {"sensors": "gps_only"})
    text = json.dumps(GPS[:3], indent=1)  # as a client might format it
    store.ingest(session, json.loads(text), text)
    bad = [GPS[3], {"t": 3.5, "kind": "gps", "lat": 91.0, "lon": 7.4246}]
    store.ingest(session, bad, json.dumps(bad))  # one refused: the text is not logged
    rows = store.triplog._db.execute("SELECT records FROM batches ORDER BY seq").fetchall()
    assert rows[0][0] == text
    assert json.loads(rows[1][0]) == [GPS[3]]
    assert list(store.triplog.packets(session.id)) == GPS[:4]


def test_the_checkpointer_moves_the_wal_into_the_database(tmp_path: Path) -> None:
    """Commits leave pages in the WAL (no checkpoint on the writer's path); the thread copies
    them into the database file."""
    path = tmp_path / "trips.db"
    log = TripLog(path, checkpoint_every_s=0.05)
    assert log._db.execute("PRAGMA wal_autocheckpoint").fetchone()[0] == 0
    log.create_session(LoggedSession("s1", "", "car", {}, 0.0))
    batch = [{**GPS[0], "note": "x" * 1000}] * 100
    for k in range(20):  # about 2 MB
        log.append("s1", 100 * k, batch)
    deadline = time.monotonic() + 10.0
    while path.stat().st_size < 1_000_000 and time.monotonic() < deadline:
        time.sleep(0.05)
    assert path.stat().st_size >= 1_000_000
    log.close()
    assert not log._checkpointer.is_alive()


def test_the_wal_starts_over_under_steady_writes(tmp_path: Path) -> None:
    """A passive checkpoint alone never completes while the writer keeps committing, and the
    WAL then grows for as long as the load lasts; the checkpointer finishes each one."""
    path = tmp_path / "trips.db"
    log = TripLog(path, checkpoint_every_s=0.05)
    log.create_session(LoggedSession("s1", "", "car", {}, 0.0))
    batch = json.dumps([{**GPS[0], "note": "x" * 4000}])
    wal = path.with_name(path.name + "-wal")
    seq, written, largest_wal = 0, 0, 0
    start = time.monotonic()
    while time.monotonic() - start < 2.0:
        log.append("s1", seq, [None], batch)
        seq, written = seq + 1, written + len(batch)
        largest_wal = max(largest_wal, wal.stat().st_size)
        time.sleep(0.0005)  # the service does other work between commits
    log.close()
    assert written > 2_000_000
    assert largest_wal < written / 3


def test_an_ended_sessions_log_is_dropped_a_chunk_at_a_time(
        sample_graph: RoadGraph, tmp_path: Path) -> None:
    store = SessionStore(sample_graph, TripLog(tmp_path / "trips.db"))
    ended, kept = (store.create("", "car", {"sensors": "gps_only"}) for _ in range(2))
    for fix in GPS:
        store.ingest(ended, [fix])
        store.ingest(kept, [fix])
    log = store.triplog
    store.delete(ended.id, "")  # cheap: only marked
    assert log._db.execute("SELECT count(*) FROM batches").fetchone()[0] == 12
    assert [s.id for s in log.open_sessions()] == [kept.id]
    assert [log.drop_closed(max_batches=4) for _ in range(3)] == [4, 2, 0]
    assert log._db.execute("SELECT count(*) FROM batches").fetchone()[0] == 6
    assert log._db.execute("SELECT id FROM sessions").fetchall() == [(kept.id,)]
    assert list(log.packets(kept.id)) == GPS


def test_a_server_drops_ended_sessions_logs_in_the_background(
        sample_graph: RoadGraph, tmp_path: Path) -> None:
    """The API's upkeep task: a deleted session's batches go within a few seconds."""
    store = SessionStore(sample_graph, TripLog(tmp_path / "trips.db"))
    session = store.create("", "car", {"sensors": "gps_only"})
    for fix in GPS:
        store.ingest(session, [fix])
    store.delete(session.id, "")

    async def run() -> int:
        task = asyncio.create_task(_drop_closed_logs(store.triplog, period_s=0.01))
        for _ in range(200):
            await asyncio.sleep(0.01)
            left = store.triplog._db.execute("SELECT count(*) FROM batches").fetchone()[0]
            if left == 0:
                break
        task.cancel()
        return int(left)

    assert asyncio.run(run()) == 0
