"""GroupCommit: the batches of one event-loop turn share one trip-log commit, and nothing is
acknowledged that the log does not hold."""

from __future__ import annotations

import asyncio
import sqlite3
from pathlib import Path

import pytest

from navsvc.api.deps import GroupCommit
from navsvc.session import LiveSession, SessionStore
from navsvc.triplog import TripLog
from roadgraph import RoadGraph

GPS = [{"t": float(i), "kind": "gps", "lat": 43.7384 + 1e-4 * i, "lon": 7.4246,
        "speed_mps": 11.0} for i in range(6)]


def _logged(path: Path, session_id: str) -> list[object]:
    """The session's packets as another connection sees them: committed ones only."""
    log = TripLog(path)
    try:
        return list(log.packets(session_id))
    finally:
        log.close()


@pytest.fixture()
def store(sample_graph: RoadGraph, tmp_path: Path) -> SessionStore:
    return SessionStore(sample_graph, TripLog(tmp_path / "trips.db"))


def _count_commits(store: SessionStore, monkeypatch: pytest.MonkeyPatch) -> list[int]:
    commits = [0]
    real = store.triplog.commit

    def counted() -> None:
        commits[0] += 1
        real()

    monkeypatch.setattr(store.triplog, "commit", counted)
    return commits


async def _send(store: SessionStore, group: GroupCommit, session: LiveSession,
                batch: list[dict[str, object]]) -> None:
    store.ingest(session, batch, commit=False)
    await group.durable()


def test_batches_of_one_turn_share_one_commit(store: SessionStore, tmp_path: Path,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    a = store.create("", "a", {"sensors": "gps_only"})
    b = store.create("", "b", {"sensors": "gps_only"})
    commits = _count_commits(store, monkeypatch)
    group = GroupCommit(store)

    async def main() -> None:
        await asyncio.gather(_send(store, group, a, GPS[:3]), _send(store, group, b, GPS[:2]))
        assert _logged(tmp_path / "trips.db", a.id) == GPS[:3]  # on disk once awaited
        assert _logged(tmp_path / "trips.db", b.id) == GPS[:2]
        await _send(store, group, a, GPS[3:])  # a later turn: a commit of its own

    asyncio.run(main())
    assert commits[0] == 2
    assert _logged(tmp_path / "trips.db", a.id) == GPS


def test_a_failed_commit_fails_every_waiter_and_rebuilds_their_sessions(
        store: SessionStore, monkeypatch: pytest.MonkeyPatch) -> None:
    a = store.create("", "a", {"sensors": "gps_only"})
    b = store.create("", "b", {"sensors": "gps_only"})
    store.ingest(a, GPS[:2])  # committed
    group = GroupCommit(store)

    def broken() -> None:
        raise sqlite3.OperationalError("disk I/O error")

    monkeypatch.setattr(store.triplog, "commit", broken)

    async def main() -> list[BaseException | None]:
        return list(await asyncio.gather(_send(store, group, a, GPS[2:4]),
                                         _send(store, group, b, GPS[:2]),
                                         return_exceptions=True))

    results = asyncio.run(main())
    assert all(isinstance(r, sqlite3.OperationalError) for r in results)
    assert store.get(a.id, "").packets == 2  # as the log has it
    assert store.get(b.id, "").packets == 0
    assert store.get(a.id, "").vehicle.engine.t == GPS[1]["t"]


def test_a_write_failing_elsewhere_in_the_turn_fails_the_group(
        store: SessionStore, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Session b's write fails and rolls back the turn's transaction, a's batch with it:
    a must not be told its batch is on disk."""
    a = store.create("", "a", {"sensors": "gps_only"})
    b = store.create("", "b", {"sensors": "gps_only"})
    group = GroupCommit(store)
    real_append = store.triplog.append

    def append(session_id: str, *args: object, **kwargs: object) -> None:
        if session_id == b.id:
            raise sqlite3.OperationalError("disk full")
        real_append(session_id, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(store.triplog, "append", append)

    async def main() -> list[BaseException | None]:
        return list(await asyncio.gather(_send(store, group, a, GPS[:3]),
                                         _send(store, group, b, GPS[:3]),
                                         return_exceptions=True))

    results = asyncio.run(main())
    assert all(isinstance(r, sqlite3.OperationalError) for r in results)
    assert _logged(tmp_path / "trips.db", a.id) == []
    assert store.get(a.id, "").packets == 0
