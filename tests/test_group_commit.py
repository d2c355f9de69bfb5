"""Group commit of the trip log: the API's batches of one turn of the event loop share one
commit, no reply leaves before the commit that holds its batch, and a lost commit rebuilds
its sessions and answers 503 (navsvc/triplog.py, navsvc/session.py, navsvc/api/routes)."""

from __future__ import annotations

import asyncio
import shutil
import sqlite3
from pathlib import Path
from typing import Any

import pytest
from fastapi import HTTPException

from navsvc.api import Settings, create_app
from navsvc.api.deps import AppState
from navsvc.api.routes.sessions import ingest
from navsvc.session import SessionStore
from navsvc.triplog import TripLog
from roadgraph import RoadGraph

GPS = [{"t": float(i), "kind": "gps", "lat": 43.7384 + 1e-4 * i, "lon": 7.4246,
        "speed_mps": 11.0, "heading_deg": 0.0} for i in range(6)]


def logged_rows(path: Path) -> int:
    """Batches committed, as another connection (a restarted server) sees them."""
    with sqlite3.connect(path) as other:
        count: int = other.execute("SELECT count(*) FROM batches").fetchone()[0]
    return count


class FailingCommit:
    """The trip log's connection, with every COMMIT failing as a full disk makes it fail."""

    def __init__(self, db: sqlite3.Connection) -> None:
        self._db = db

    def execute(self, sql: str, *args: Any) -> sqlite3.Cursor:
        if sql == "COMMIT":
            raise sqlite3.OperationalError("database or disk is full")
        return self._db.execute(sql, *args)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._db, name)


def test_deferred_batches_are_committed_together(tmp_path: Path) -> None:
    log = TripLog(tmp_path / "trips.db")
    outcomes: list[BaseException | None] = []
    try:
        first = log.append("s1", 0, [GPS[0]], commit=False)
        second = log.append("s2", 0, [GPS[1]], commit=False)
        group = log.group
        assert group is not None and group.batches == 2 and second == first + 1
        group.when_done(outcomes.append)
        assert logged_rows(log.path) == 0 and outcomes == []  # not yet: nothing acknowledged
        log.commit()
        assert logged_rows(log.path) == 2 and outcomes == [None] and log.group is None
        group.when_done(outcomes.append)  # once finished, a new waiter learns it at once
        assert outcomes == [None, None]
        log.append("s1", 1, [GPS[2]], commit=False)
        log.append("s1", 2, [GPS[3]])  # a committed append commits the open group first
        assert logged_rows(log.path) == 4 and log.group is None
    finally:
        log.close()


def test_other_writes_commit_the_open_group_first(tmp_path: Path) -> None:
    log = TripLog(tmp_path / "trips.db")
    try:
        log.append("s1", 0, [GPS[0]], commit=False)
        log.close_session("s1")
        assert logged_rows(log.path) == 1 and log.group is None
        log.append("s1", 1, [GPS[1]], commit=False)
    finally:
        log.close()  # commits what is open
    assert logged_rows(tmp_path / "trips.db") == 2


def test_a_lost_group_rebuilds_its_sessions_from_the_log(sample_graph: RoadGraph,
                                                         tmp_path: Path) -> None:
    store = SessionStore(sample_graph, TripLog(tmp_path / "trips.db"))
    a = store.create("", "a", {"sensors": "gps_only"})
    b = store.create("", "b", {"sensors": "gps_only"})
    store.ingest(a, GPS[:3])
    done_a = store.ingest(a, GPS[3:], defer_commit=True)
    done_b = store.ingest(b, GPS[:2], defer_commit=True)
    group = done_a.group
    assert group is not None and done_b.group is group
    assert store.get(a.id, "").packets == 6  # applied, not yet logged
    outcomes: list[BaseException | None] = []
    group.when_done(outcomes.append)
    real = store.triplog._db
    store.triplog._db = FailingCommit(real)  # type: ignore[assignment]
    with pytest.raises(sqlite3.OperationalError):
        store.triplog.commit()
    store.triplog._db = real
    assert isinstance(outcomes[0], sqlite3.OperationalError)
    assert logged_rows(tmp_path / "trips.db") == 1  # only the batch committed before
    rebuilt_a, rebuilt_b = store.get(a.id, ""), store.get(b.id, "")
    assert rebuilt_a.packets == 3 and rebuilt_a.vehicle.engine.t == GPS[2]["t"]
    assert rebuilt_b.packets == 0 and rebuilt_b.vehicle.engine.t is None
    store.ingest(rebuilt_a, GPS[3:])  # the client sends the batch again
    assert store.get(a.id, "").packets == 6
    store.triplog.close()


def test_a_resend_waits_for_the_commit_of_the_batch_it_repeats(sample_graph: RoadGraph,
                                                               tmp_path: Path) -> None:
    store = SessionStore(sample_graph, TripLog(tmp_path / "trips.db"))
    session = store.create("", "a", {"sensors": "gps_only"})
    first = store.ingest(session, GPS[:3], client_seq=1, defer_commit=True)
    resent = store.ingest(session, GPS[:3], client_seq=1, defer_commit=True)
    assert resent.reply["duplicate"] and resent.group is first.group is not None
    store.triplog.commit()
    assert store.ingest(session, GPS[:3], client_seq=1, defer_commit=True).group is None
    store.triplog.close()


def app_state(sample_db: Path, tmp_path: Path) -> AppState:
    db = tmp_path / "city.db"
    shutil.copy(sample_db, db)
    app = create_app(Settings(map_path=db))
    state: AppState = app.state.navsvc
    return state


def test_the_api_commits_the_batches_of_one_turn_once_before_replying(
        sample_db: Path, tmp_path: Path) -> None:
    state = app_state(sample_db, tmp_path)
    sessions = [state.store.create("", f"car {k}", {"sensors": "gps_only"}) for k in range(3)]
    path = state.store.triplog.path
    seen_before_commit: list[int] = []

    async def look() -> None:  # runs in the same turn, after the three ingests
        seen_before_commit.append(logged_rows(path))

    async def turn() -> list[dict[str, Any]]:
        replies = [asyncio.ensure_future(ingest(state, s, GPS[:2])) for s in sessions]
        await asyncio.gather(*replies, look())
        return [r.result() for r in replies]

    replies = asyncio.run(turn())
    assert [r["accepted"] for r in replies] == [2, 2, 2]
    assert seen_before_commit == [0] and logged_rows(path) == 3
    text = state.metrics.text().decode()
    assert "navsvc_triplog_commit_batches_count 1.0" in text
    assert "navsvc_triplog_commit_batches_sum 3.0" in text
    state.store.triplog.close()


def test_a_lost_commit_is_a_503_and_the_batch_can_be_sent_again(
        sample_db: Path, tmp_path: Path) -> None:
    state = app_state(sample_db, tmp_path)
    session = state.store.create("", "car", {"sensors": "gps_only"})
    real = state.store.triplog._db
    state.store.triplog._db = FailingCommit(real)  # type: ignore[assignment]
    with pytest.raises(HTTPException) as refused:
        asyncio.run(ingest(state, session, GPS[:3]))
    assert refused.value.status_code == 503 and "disk is full" in str(refused.value.detail)
    state.store.triplog._db = real
    again = state.store.get(session.id, "")
    assert again.packets == 0
    assert asyncio.run(ingest(state, again, GPS[:3]))["accepted"] == 3
    assert logged_rows(state.store.triplog.path) == 1
    state.store.triplog.close()


def test_deferred_checkpoints_are_taken_a_few_before_each_commit(
        sample_graph: RoadGraph, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Sessions that come due together are checkpointed over several commits (budget 0: one
    a commit), in the group they join; a closed or rebuilt session is skipped."""
    monkeypatch.setattr("navsvc.session.CHECKPOINT_EVERY_PACKETS", 2)
    ticks = iter(range(10**6))  # a clock a second ahead at each reading
    store = SessionStore(sample_graph, TripLog(tmp_path / "trips.db"),
                         clock=lambda: float(next(ticks)))
    cars = [store.create("", f"car {k}", {"sensors": "gps_only"}) for k in range(4)]
    for car in cars:
        store.ingest(car, GPS[:3], defer_commit=True)
    assert [store.triplog.checkpoint(c.id) for c in cars] == [None] * 4  # none yet
    store.delete(cars[1].id, "")
    store._sessions[cars[2].id] = store._load(cars[2].logged())  # as after a lost group
    assert store.checkpoint_due(budget_s=0.0) == 1
    store.triplog.commit()
    first = store.triplog.checkpoint(cars[0].id)
    assert first is not None and first.packets == 3
    assert store.triplog.checkpoint(cars[3].id) is None  # the next commit's
    assert store.checkpoint_due(budget_s=0.0) == 1
    assert store.checkpoint_due(budget_s=0.0) == 0
    assert store.triplog.checkpoint(cars[2].id) is None
    checkpoint = store.triplog.checkpoint(cars[3].id)
    assert checkpoint is not None and checkpoint.packets == 3
    store.triplog.close()


def test_an_ingest_without_deferred_commit_checkpoints_at_once(
        sample_graph: RoadGraph, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("navsvc.session.CHECKPOINT_EVERY_PACKETS", 2)
    ticks = iter(range(10**6))
    store = SessionStore(sample_graph, TripLog(tmp_path / "trips.db"),
                         clock=lambda: float(next(ticks)))
    car = store.create("", "car", {"sensors": "gps_only"})
    store.ingest(car, GPS[:3])
    checkpoint = store.triplog.checkpoint(car.id)
    assert checkpoint is not None and checkpoint.packets == 3
    assert store.checkpoint_due() == 0
    store.triplog.close()
