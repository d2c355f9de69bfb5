"""SessionStore: a failed trip-log write leaves memory exactly as the log says."""

from __future__ import annotations

import json
import sqlite3
import time
from pathlib import Path

import pytest

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
