"""SessionStore: a failed trip-log write leaves memory exactly as the log says."""

from __future__ import annotations

import asyncio
import json
import sqlite3
import time
from pathlib import Path

import pytest

from navsvc.api.app import _drop_closed_logs
from navsvc.errors import BatchAlreadyApplied, SessionNotFound, TripLogInUse
from navsvc.session import SessionStore
from navsvc.triplog import LoggedSession, TripLog
from navsvc.wire.positions import position_json
from roadgraph import RoadGraph

GPS = [{"t": float(i), "kind": "gps", "lat": 43.7384 + 1e-4 * i, "lon": 7.4246,
        "speed_mps": 11.0, "heading_deg": 0.0} for i in range(6)]


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
    store.triplog.close()  # the server stops (a crash releases the log as well)
    log = TripLog(tmp_path / "trips.db")
    assert list(log.packets(session.id)) == GPS
    restored = SessionStore(sample_graph, log)
    restored.restore()
    again = restored.get(session.id, "")
    assert again.packets == 6
    assert again.rejected == 1  # the count of refused packets survives the restart
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


OLD_BATCHES = {  # the batches tables of older layouts
    "without_rowid": """CREATE TABLE batches (session_id TEXT NOT NULL, seq INTEGER NOT NULL,
        count INTEGER NOT NULL, records TEXT NOT NULL,
        PRIMARY KEY (session_id, seq)) WITHOUT ROWID;""",
    "keyed_by_first_packet": """CREATE TABLE batches (session_id TEXT NOT NULL
        REFERENCES sessions(id), seq INTEGER NOT NULL, count INTEGER NOT NULL,
        records TEXT NOT NULL, PRIMARY KEY (session_id, seq));""",
}


@pytest.mark.parametrize("layout", OLD_BATCHES)
def test_batches_of_an_older_layout_are_moved_over(tmp_path: Path, layout: str) -> None:
    """Batches keyed by (session, first packet) could not hold a batch of refused packets;
    the WITHOUT ROWID table spilled its rows to overflow pages."""
    path = tmp_path / "trips.db"
    db = sqlite3.connect(path)
    db.executescript(f"""
        CREATE TABLE sessions (id TEXT PRIMARY KEY, owner TEXT NOT NULL,
            vehicle_id TEXT NOT NULL, options TEXT NOT NULL, created_unix REAL NOT NULL,
            closed INTEGER NOT NULL DEFAULT 0);
        {OLD_BATCHES[layout]}
        INSERT INTO sessions (id, owner, vehicle_id, options, created_unix)
            VALUES ('s1', '', 'car', '{{}}', 0);
        INSERT INTO batches VALUES ('s1', 2, 1, '[{{"t":2.0}}]'),
                                   ('s1', 0, 2, '[{{"t":0.0}},{{"t":1.0}}]');
    """)
    db.close()
    log = TripLog(path)
    assert list(log.packets("s1")) == [{"t": 0.0}, {"t": 1.0}, {"t": 2.0}]
    sql = log._db.execute("SELECT sql FROM sqlite_master WHERE name = 'batches'").fetchone()[0]
    assert "WITHOUT ROWID" not in sql.upper() and "client_seq" in sql
    log.append("s1", 3, [{"t": 3.0}])
    log.append("s1", 4, [], rejected=2)  # a batch of refused packets has a row now
    assert list(log.packets("s1")) == [{"t": 0.0}, {"t": 1.0}, {"t": 2.0}, {"t": 3.0}]
    assert [b.rejected for b in log.batches_after("s1")] == [0, 0, 0, 2]


def test_the_log_holds_packets_as_validated_not_as_received(
        sample_graph: RoadGraph, tmp_path: Path) -> None:
    """Unknown fields are dropped before logging: one nested 963 arrays deep was logged and
    then broke the restart (RecursionError while replaying)."""
    store = SessionStore(sample_graph, TripLog(tmp_path / "trips.db"))
    session = store.create("", "car", {"sensors": "gps_only"})
    deep: object = 0
    for _ in range(963):
        deep = [deep]
    store.ingest(session, [{**GPS[0], "extra": deep}, *GPS[1:3]])
    (records,) = store.triplog._db.execute("SELECT records FROM batches").fetchone()
    assert json.loads(records) == GPS[:3]
    store.triplog.close()
    restored = SessionStore(sample_graph, TripLog(tmp_path / "trips.db"))
    assert restored.restore() == 1
    assert restored.get(session.id, "").packets == 3


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
    WAL then grows for as long as the load lasts; the checkpointer finishes one once the WAL
    holds ``restart_wal_frames`` pages."""
    path = tmp_path / "trips.db"
    log = TripLog(path, checkpoint_every_s=0.05, restart_wal_frames=64)
    log.create_session(LoggedSession("s1", "", "car", {}, 0.0))
    batch = [{**GPS[0], "note": "x" * 4000}]
    size = len(json.dumps(batch))
    wal = path.with_name(path.name + "-wal")
    written, largest_wal = 0, 0
    # A count of commits, not a time: on a busy machine two seconds held too few of them
    # (the test went red under CPU contention).
    for seq in range(750):
        log.append("s1", seq, batch)
        written += size
        largest_wal = max(largest_wal, wal.stat().st_size)
        time.sleep(0.002)  # the service does other work between commits
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


def _drive(sample_graph: RoadGraph, seconds: float = 40.0) -> list[dict[str, object]]:
    from navsvc.sim.simulate import SENSOR_KINDS, DriveSpec, simulate_drive
    kinds = set(SENSOR_KINDS["gyro_odometer"])
    return [r for r in simulate_drive(sample_graph, DriveSpec(duration_s=seconds, seed=2))
            if r["kind"] in kinds]


def _batches(packets: list[dict[str, object]], size: int = 25) -> list[list[dict[str, object]]]:
    return [packets[i:i + size] for i in range(0, len(packets), size)]


def test_a_restart_loads_the_checkpoint_and_replays_only_the_tail(
        sample_graph: RoadGraph, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The restored pipeline continues exactly as the one that never stopped."""
    monkeypatch.setattr("navsvc.session.CHECKPOINT_EVERY_PACKETS", 400)
    packets = _batches(_drive(sample_graph))
    ticks = iter(range(10**6))  # a clock a second ahead at each reading
    store = SessionStore(sample_graph, TripLog(tmp_path / "trips.db"),
                         clock=lambda: float(next(ticks)))
    session = store.create("", "car", {})
    half = len(packets) // 2
    for batch in packets[:half]:
        store.ingest(session, batch)
    checkpoint = store.triplog.checkpoint(session.id)
    assert checkpoint is not None and 0 < checkpoint.packets < session.packets
    store.triplog.close()  # crash: no checkpoint at shutdown

    log = TripLog(tmp_path / "trips.db")
    replayed: list[int] = []
    original = log.batches_after
    monkeypatch.setattr(log, "batches_after", lambda sid, rowid=0, limit=-1: (
        replayed.append(rowid) or original(sid, rowid, limit)))
    restored = SessionStore(sample_graph, log)
    restored.restore()
    assert replayed[0] == checkpoint.batch_rowid  # the tail only
    again = restored.get(session.id, "")
    assert (again.packets, again.rejected) == (session.packets, session.rejected)
    assert session.vehicle.last_position is not None
    compared = 0
    for batch in packets[half:]:
        a = session.vehicle.add_records(batch)
        b = again.vehicle.add_records(batch)
        frame = sample_graph.frame
        assert [position_json(p, frame) for p in a.positions] == \
            [position_json(p, frame) for p in b.positions]
        compared += len(a.positions)
    assert compared >= 15


def test_a_checkpoint_written_by_other_code_is_not_loaded(
        sample_graph: RoadGraph, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    store = SessionStore(sample_graph, TripLog(tmp_path / "trips.db"))
    session = store.create("", "car", {"sensors": "gps_only"})
    store.ingest(session, GPS)
    store.checkpoint(session)
    store.triplog.close()
    monkeypatch.setattr("navsvc.session.code_id", lambda: "another version")
    restored = SessionStore(sample_graph, TripLog(tmp_path / "trips.db"))
    restored.restore()  # the whole log replayed instead
    again = restored.get(session.id, "")
    assert again.packets == 6 and again.vehicle.engine.t == GPS[-1]["t"]


def test_a_fault_in_the_engine_refuses_that_packet_alone(
        sample_graph: RoadGraph, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Today's OverflowError on odometer.ticks = 10**400 failed the whole batch with 500,
    and its good packets were applied but never logged."""
    store = SessionStore(sample_graph, TripLog(tmp_path / "trips.db"))
    session = store.create("", "car", {"sensors": "gps_only"})
    store.ingest(session, GPS[:2])
    engine_add = type(session.vehicle.engine).add

    def fragile(engine: object, packet: object) -> object:
        if getattr(packet, "t", None) == GPS[3]["t"]:
            raise OverflowError("int too large to convert to float")
        return engine_add(engine, packet)  # type: ignore[arg-type]

    monkeypatch.setattr(type(session.vehicle.engine), "add", fragile)
    done = store.ingest(session, GPS[2:])
    assert done.result is not None
    assert [r["code"] for r in done.reply["rejected"]] == ["unusable"]
    assert done.reply["rejected"][0]["index"] == 1
    assert done.result.accepted == 3
    monkeypatch.undo()
    live = store.get(session.id, "")
    assert live.packets == 5 and live.rejected == 1
    assert list(store.triplog.packets(session.id)) == [g for g in GPS if g is not GPS[3]]
    store.triplog.close()
    restored = SessionStore(sample_graph, TripLog(tmp_path / "trips.db"))
    restored.restore()
    again = restored.get(session.id, "")
    assert (again.packets, again.rejected) == (5, 1)
    frame = sample_graph.frame
    assert position_json(again.vehicle.last_position, frame) == \
        position_json(live.vehicle.last_position, frame)  # type: ignore[arg-type]


def test_hostile_values_are_refused_alone_and_the_rest_is_logged(
        sample_graph: RoadGraph, tmp_path: Path) -> None:
    store = SessionStore(sample_graph, TripLog(tmp_path / "trips.db"))
    session = store.create("", "car", {})
    hostile = [{"t": 0.5, "kind": "odometer", "ticks": 10**400},
               {"t": 0.6, "kind": "odometer", "distance_m": 1e300},
               {"t": 1e308, "kind": "imu", "yaw_rate_dps": 0.0},
               {"t": 1.7e12, "kind": "imu", "yaw_rate_dps": 0.0},
               {"t": 5000.0, "kind": "imu", "yaw_rate_dps": 0.0}]  # over an hour ahead
    batch = [GPS[0], *hostile, GPS[1]]
    done = store.ingest(session, batch)
    assert [r["index"] for r in done.reply["rejected"]] == [1, 2, 3, 4, 5]
    assert "milliseconds" in done.reply["rejected"][3]["message"]
    assert "3600" in done.reply["rejected"][4]["message"]
    assert list(store.triplog.packets(session.id)) == [GPS[0], GPS[1]]
    assert store.ingest(session, GPS[2:]).reply["accepted"] == 4  # the session still works


def test_a_resent_numbered_batch_is_answered_and_not_applied_again(
        sample_graph: RoadGraph, tmp_path: Path) -> None:
    store = SessionStore(sample_graph, TripLog(tmp_path / "trips.db"))
    session = store.create("", "car", {"sensors": "gps_only"})
    first = store.ingest(session, GPS[:3], client_seq=7).reply
    resent = store.ingest(session, GPS[:3], client_seq=7)
    assert resent.result is None and resent.reply == {**first, "duplicate": True}
    assert session.packets == 3
    store.ingest(session, GPS[3:], client_seq=8)
    assert list(store.triplog.packets(session.id)) == GPS
    with pytest.raises(BatchAlreadyApplied):
        store.ingest(session, GPS[3:], client_seq=5)  # never sent: numbers went backwards
    store.triplog.close()
    restored = SessionStore(sample_graph, TripLog(tmp_path / "trips.db"))
    restored.restore()
    again = restored.get(session.id, "")
    after_restart = restored.ingest(again, GPS[:3], client_seq=7)  # resent after a restart
    assert after_restart.result is None and after_restart.reply["accepted"] == 3
    assert again.packets == 6


def test_a_second_server_cannot_open_a_trip_log_in_use(tmp_path: Path) -> None:
    log = TripLog(tmp_path / "trips.db")
    with pytest.raises(TripLogInUse, match="in use by another navsvc server"):
        TripLog(tmp_path / "trips.db")
    log.close()
    TripLog(tmp_path / "trips.db").close()  # free again once the first has stopped


def test_reopened_sessions_are_rebuilt_when_named_or_one_at_a_time(
        sample_graph: RoadGraph, tmp_path: Path) -> None:
    store = SessionStore(sample_graph, TripLog(tmp_path / "trips.db"))
    mine = [store.create("me", f"car-{i}", {"sensors": "gps_only"}) for i in range(3)]
    theirs = store.create("them", "van", {"sensors": "gps_only"})
    for session in (*mine, theirs):
        store.ingest(session, GPS)
    store.triplog.close()
    restarted = SessionStore(sample_graph, TripLog(tmp_path / "trips.db"))
    assert restarted.reopen() == 4 and len(restarted) == 4
    assert restarted._sessions == {}  # nothing rebuilt yet
    with pytest.raises(SessionNotFound):
        restarted.get(theirs.id, "me")  # another key's session stays hidden, and pending
    assert restarted.get(mine[1].id, "me").packets == 6  # rebuilt on demand
    assert set(restarted._sessions) == {mine[1].id}
    assert {s.id for s in restarted.sessions("me")} == {s.id for s in mine}
    while restarted.restore_next():  # the last one, in the background
        pass
    assert set(restarted._sessions) == {*(s.id for s in mine), theirs.id}
    assert restarted.get(theirs.id, "them").vehicle.engine.t == GPS[-1]["t"]
    assert len(restarted) == 4


def test_a_long_rebuild_in_the_background_goes_a_few_batches_at_a_time(
        sample_graph: RoadGraph, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A session without a usable checkpoint (after an upgrade) replays its whole log: in
    steps, between requests, and at once when a request names it."""
    monkeypatch.setattr("navsvc.session.REPLAY_STEP_BATCHES", 5)
    packets = _batches(_drive(sample_graph, seconds=20.0), size=10)
    store = SessionStore(sample_graph, TripLog(tmp_path / "trips.db"))
    first, second = store.create("", "car", {}), store.create("", "van", {})
    for batch in packets:
        store.ingest(first, batch)
        store.ingest(second, batch)
    store.triplog.close()
    monkeypatch.setattr("navsvc.session.code_id", lambda: "an upgrade")  # no checkpoint loads
    restarted = SessionStore(sample_graph, TripLog(tmp_path / "trips.db"))
    restarted.reopen()
    steps = 0
    while restarted.restore_next() and not restarted._sessions:
        steps += 1
    assert steps >= len(packets) // 5  # the first session went a step at a time
    assert len(restarted) == 2
    named = restarted.get(second.id, "")  # half rebuilt, or not started: finished now
    assert not restarted.restore_next() or not restarted.restore_next()
    frame = sample_graph.frame
    for live, again in ((first, restarted.get(first.id, "")), (second, named)):
        assert again.packets == live.packets
        assert position_json(again.vehicle.last_position, frame) == \
            position_json(live.vehicle.last_position, frame)  # type: ignore[arg-type]
