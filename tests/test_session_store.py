"""SessionStore: a failed trip-log write leaves memory exactly as the log says."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest

from navsvc.session import SessionStore
from navsvc.triplog import TripLog
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
