"""The trip log: every accepted packet of every live session, on disk before it is acknowledged.

An SQLite file beside the road-graph database (``maps/monaco.db`` → ``maps/monaco.trips.db``)
in WAL mode. A batch's accepted packets (in the form they were validated in, which is the form
replayed; a message accepted whole, as its own JSON text, not encoded again) are written in
one statement, committed before the reply leaves, so a server killed
at any moment has every acknowledged packet on disk. The API's batches are committed in
groups (:class:`CommitGroup`): the batches of every message the event loop took in one turn
go into one transaction, committed once, and each reply leaves only after that commit (a
commit per message was a tenth of the server's CPU at 200 sessions; in one of 20 batches each
costs a third). Now and then a session's whole pipeline is
saved as a *checkpoint*; on restart :class:`navsvc.session.SessionStore` loads each open
session's checkpoint and replays only the batches logged after it. With ``synchronous=NORMAL``
(the default here) a commit survives the process crashing; pass ``sync="full"`` to also
survive the machine losing power, at an fsync per batch.

Only the API's event loop uses a TripLog, so one connection serves it. WAL checkpoints
(copying the WAL into the database file, with an fsync) run every second in a thread of their
own, on their own connection, instead of inside whichever commit crossed SQLite's 1,000-page
mark: there they stalled the event loop for 20 ms every 0.6 s with 1,000 GPS-only sessions.
Once few pages are left to copy and the WAL holds ``restart_wal_frames`` pages (256 MB),
a short blocking pass lets the WAL start over instead of growing under load. Short, but it
holds the writer (the event loop) for its fsyncs: 15-45 ms on this machine's disk when
busy, where it ran every second and made the p99 latency at 200 real-rate sessions; at 256 MB
it runs every ~13 s at that load (5,000 pages a second). An ended session is only marked;
:meth:`TripLog.drop_closed` deletes its batches later, a chunk at a time.
"""

from __future__ import annotations

import fcntl
import json
import logging
import os
import sqlite3
import threading
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from navsvc.errors import TripLogInUse

log = logging.getLogger(__name__)

_ENCODER = json.JSONEncoder(separators=(",", ":"))
PASSIVE_CHECKPOINTS = 8  # at most, each second
FRAMES_LEFT_FOR_RESTART = 256  # that one copies no more than about this many pages
RESTART_WAL_FRAMES = 65_536  # and the WAL holds this many (256 MB of 4 kB pages)
DROP_CHUNK_BATCHES = 64  # batches of ended sessions deleted in one transaction (a few ms)

SCHEMA = """
CREATE TABLE IF NOT EXISTS sessions (
    id TEXT PRIMARY KEY,
    owner TEXT NOT NULL,          -- SHA-256 of the API key that created it ('' when open)
    vehicle_id TEXT NOT NULL,
    options TEXT NOT NULL,        -- the creation request, JSON
    created_unix REAL NOT NULL,
    closed INTEGER NOT NULL DEFAULT 0
);
CREATE TABLE IF NOT EXISTS batches (  -- one row a batch, in the order they were applied
    session_id TEXT NOT NULL REFERENCES sessions(id),
    seq INTEGER NOT NULL,         -- packets the session had accepted before this batch
    count INTEGER NOT NULL,       -- packets accepted in the batch
    records TEXT NOT NULL,        -- the accepted packets as validated, a JSON array
    rejected INTEGER NOT NULL DEFAULT 0,  -- packets of the batch refused
    client_seq INTEGER,           -- the client's batch number, when it sent one
    reply TEXT                    -- the reply it got (JSON), kept to answer a resend
);
CREATE INDEX IF NOT EXISTS batches_of_session ON batches (session_id);
CREATE INDEX IF NOT EXISTS numbered_batches ON batches (session_id) WHERE client_seq IS NOT NULL;
CREATE TABLE IF NOT EXISTS checkpoints (  -- a session's pipeline, saved now and then
    session_id TEXT PRIMARY KEY REFERENCES sessions(id),
    batch_rowid INTEGER NOT NULL, -- the last batch it has applied
    packets INTEGER NOT NULL,     -- accepted and rejected packets counted up to it
    rejected INTEGER NOT NULL,
    state BLOB NOT NULL           -- navsvc.session.dump_vehicle
);
"""

# Older layouts are moved over when opened: one row a packet (``packets``), batches in a
# WITHOUT ROWID table (its rows of a kilobyte or more spilled to overflow pages, and each
# commit rewrote five pages), and batches keyed by (session, first packet), which could not
# hold a batch whose packets were all refused.
_OLD_BATCHES = "INSERT INTO batches (session_id, seq, count, records) SELECT session_id, " \
    "seq, count, records FROM {table} ORDER BY session_id, seq; DROP TABLE {table};"
_MIGRATIONS = {
    "packets": """
        INSERT INTO batches (session_id, seq, count, records)
            SELECT session_id, seq, 1, '[' || record || ']' FROM packets
            ORDER BY session_id, seq;
        DROP TABLE packets;""",
    "batches_without_rowid": _OLD_BATCHES.format(table="batches_without_rowid"),
    "batches_by_seq": _OLD_BATCHES.format(table="batches_by_seq"),
}


_INSERT_BATCH = "INSERT INTO batches (session_id, seq, count, records, rejected, client_seq, " \
    "reply) VALUES (?, ?, ?, ?, ?, ?, ?)"
_SAVE_CHECKPOINT = "INSERT OR REPLACE INTO checkpoints (session_id, batch_rowid, packets, " \
    "rejected, state) VALUES (?, ?, ?, ?, ?)"


def triplog_path_for(map_db: Path) -> Path:
    """The trip log beside a road-graph database."""
    return map_db.with_name(map_db.stem + ".trips.db")


@dataclass(frozen=True)
class LoggedSession:
    id: str
    owner: str
    vehicle_id: str
    options: dict[str, Any]
    created_unix: float


@dataclass(frozen=True)
class Checkpoint:
    """A session's saved pipeline and what it had counted when it was saved."""

    batch_rowid: int
    packets: int
    rejected: int
    state: bytes


@dataclass(frozen=True)
class LoggedBatch:
    """One logged batch, as replayed after a checkpoint."""

    rowid: int
    records: list[Any]
    rejected: int


@dataclass(frozen=True)
class LoggedReply:
    """The reply to a batch the client numbered."""

    client_seq: int
    reply: dict[str, Any]


@dataclass(eq=False)
class CommitGroup:
    """The batches written in one open transaction (``TripLog.append(..., commit=False)``),
    committed together. Whoever waits on one of them registers a callback, called once with
    None when the group is committed or with the error when it is not (then none of its
    batches is in the log)."""

    batches: int = 0
    scheduled: bool = False  # the caller's flag: a commit of it is on its way
    outcome: BaseException | None = None
    finished: bool = False
    _callbacks: list[Callable[[BaseException | None], None]] = field(default_factory=list)

    def when_done(self, callback: Callable[[BaseException | None], None]) -> None:
        """Call ``callback(error or None)`` once the group is committed or lost (now, if it
        is already)."""
        if self.finished:
            callback(self.outcome)
        else:
            self._callbacks.append(callback)

    def _finish(self, outcome: BaseException | None) -> None:
        self.finished, self.outcome = True, outcome
        callbacks, self._callbacks = self._callbacks, []
        for callback in callbacks:
            try:
                callback(outcome)
            except Exception:  # one waiter's fault must not keep the others waiting
                log.exception("trip log commit callback failed")


class TripLog:
    """Append-only log of sessions and their accepted packets, with checkpoints.

    One server at a time: the log is locked (``<path>.lock``) while it is open, and a second
    server refuses to start on it instead of reading the first one's live sessions.
    """

    def __init__(self, path: Path, sync: str = "normal", checkpoint_every_s: float = 1.0,
                 restart_wal_frames: int = RESTART_WAL_FRAMES) -> None:
        if sync not in ("normal", "full"):
            raise ValueError(f"sync must be 'normal' or 'full', got {sync!r}")
        self.path = path
        self._lock = _lock(path)
        self._db = sqlite3.connect(path, isolation_level=None, check_same_thread=False)
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute(f"PRAGMA synchronous={sync.upper()}")
        self._db.execute("PRAGMA wal_autocheckpoint=0")  # the checkpointer thread does it
        self._move_old_batches_aside()
        self._db.executescript(SCHEMA)
        for table, script in _MIGRATIONS.items():
            if self._db.execute("SELECT 1 FROM sqlite_master WHERE name = ?", (table,)
                                ).fetchone():
                self._db.executescript(f"BEGIN; {script} COMMIT;")
        self._group: CommitGroup | None = None  # the open transaction's batches
        self._closing = threading.Event()
        self._checkpointer = threading.Thread(target=self._checkpoint,
                                              args=(checkpoint_every_s, restart_wal_frames),
                                              name=f"checkpoint {path.name}", daemon=True)
        self._checkpointer.start()

    def _move_old_batches_aside(self) -> None:
        """Rename a batches table of an older layout, for its migration to copy."""
        row = self._db.execute("SELECT sql FROM sqlite_master WHERE name = 'batches'").fetchone()
        if row is None:
            return
        if "WITHOUT ROWID" in row[0].upper():
            self._db.execute("ALTER TABLE batches RENAME TO batches_without_rowid")
        elif "client_seq" not in row[0]:
            self._db.execute("ALTER TABLE batches RENAME TO batches_by_seq")

    def _checkpoint(self, every_s: float, restart_frames: int) -> None:
        db = sqlite3.connect(self.path, isolation_level=None)
        try:
            while not self._closing.wait(every_s):
                try:
                    # Passive checkpoints never wait for the writer, but under steady load
                    # one never catches up with it, and only a complete checkpoint lets the
                    # WAL start over (it grew by 40 MB/s at 2,000 batches/s). So: passive
                    # ones until few frames are left, then one that holds the writer off
                    # while it copies those (if the writer outruns them all, next time),
                    # once the WAL is large enough for a start over to be worth that hold.
                    for _ in range(PASSIVE_CHECKPOINTS):
                        _, frames, copied = db.execute("PRAGMA wal_checkpoint(PASSIVE)"
                                                       ).fetchone()
                        if frames < restart_frames:
                            break
                        if frames - copied <= FRAMES_LEFT_FOR_RESTART:
                            db.execute("PRAGMA wal_checkpoint(RESTART)")
                            break
                except sqlite3.Error as exc:  # try again next time: the WAL only grows
                    log.warning("trip log checkpoint failed: %s", exc)
        finally:
            db.close()

    def close(self) -> None:
        try:
            self.commit()
        except sqlite3.Error:  # its batches were not acknowledged: the clients send them again
            log.exception("trip log: the last commit group could not be committed")
        self._closing.set()
        self._checkpointer.join()
        self._db.close()
        self._lock.close()

    @property
    def group(self) -> CommitGroup | None:
        """The batches written and not committed yet (None when there are none)."""
        return self._group

    def commit(self) -> None:
        """Commit the open group of batches, if any; its callbacks learn the outcome. On an
        error the transaction is rolled back (none of its batches is logged) and the error
        raised, to this caller and to the group's callbacks."""
        group = self._group
        if group is None:
            return
        self._group = None
        try:
            self._db.execute("COMMIT")
        except sqlite3.Error as exc:
            if self._db.in_transaction:
                self._db.execute("ROLLBACK")
            group._finish(exc)
            raise
        group._finish(None)

    def _in_group(self, sql: str, parameters: Sequence[Any]) -> sqlite3.Cursor:
        """A statement inside the open group's transaction (begun if none is open). If it
        fails in a way that rolled the whole transaction back (SQLite does for a full disk
        or an I/O error), the group is lost: its callbacks are told, and the error raised."""
        if self._group is None:
            self._db.execute("BEGIN")
            self._group = CommitGroup()
        try:
            return self._db.execute(sql, parameters)
        except sqlite3.Error as exc:
            if not self._db.in_transaction:
                group, self._group = self._group, None
                group._finish(exc)
            raise

    def create_session(self, session: LoggedSession) -> None:
        self.commit()  # what was written before is committed before (and apart from) this
        self._db.execute(  # one statement: its own transaction
            "INSERT INTO sessions (id, owner, vehicle_id, options, created_unix) "
            "VALUES (?, ?, ?, ?, ?)",
            (session.id, session.owner, session.vehicle_id, json.dumps(session.options),
             session.created_unix))

    def append(self, session_id: str, first_seq: int, records: Sequence[Any] | int,
               rejected: int = 0, client_seq: int | None = None,
               reply: dict[str, Any] | None = None, encoded: str | None = None,
               commit: bool = True) -> int:
        """Write a batch: its accepted packets (seq numbers from ``first_seq``), how many of
        it were refused, and for a numbered batch its number and reply; commit, and return
        the batch's row id.

        ``commit=False``: the batch joins the open :attr:`group` instead (a transaction
        begun if none is open), committed by :meth:`commit` or by the next write of another
        kind; it must not be acknowledged before that.

        ``encoded``: the packets already as one JSON array (the message's own text, when all
        of it was accepted as it came), with ``records`` their count; it is stored as it is.

        One row a batch: encoding and inserting packet by packet cost a fifth of the
        service's time per packet."""
        if encoded is None:
            assert not isinstance(records, int)
            count, encoded = len(records), _ENCODER.encode(records)
        else:
            count = records if isinstance(records, int) else len(records)
        row = (session_id, first_seq, count, encoded, rejected, client_seq,
               None if reply is None else _ENCODER.encode(reply))
        if commit:
            self.commit()
            cursor = self._db.execute(_INSERT_BATCH, row)  # its own transaction, committed
        else:
            cursor = self._in_group(_INSERT_BATCH, row)
            assert self._group is not None
            self._group.batches += 1
        rowid: int = cursor.lastrowid  # type: ignore[assignment]
        return rowid

    def save_checkpoint(self, session_id: str, checkpoint: Checkpoint) -> None:
        """Save a checkpoint: in the open group when there is one (it names a batch of it:
        both are logged or neither), else on its own."""
        row = (session_id, checkpoint.batch_rowid, checkpoint.packets, checkpoint.rejected,
               checkpoint.state)
        if self._group is not None:
            self._in_group(_SAVE_CHECKPOINT, row)
        else:
            self._db.execute(_SAVE_CHECKPOINT, row)

    def checkpoint(self, session_id: str) -> Checkpoint | None:
        row = self._db.execute(
            "SELECT batch_rowid, packets, rejected, state FROM checkpoints WHERE session_id = ?",
            (session_id,)).fetchone()
        return None if row is None else Checkpoint(row[0], row[1], row[2], bytes(row[3]))

    def batches_after(self, session_id: str, rowid: int = 0, limit: int = -1
                      ) -> list[LoggedBatch]:
        """A session's batches logged after row ``rowid``, in the order they were applied;
        at most ``limit`` of them (-1: all)."""
        rows = self._db.execute(
            # the index, named: for "rowid > ? ORDER BY rowid" SQLite would rather walk the
            # table in rowid order, every other session's rows too (seconds in a big log)
            "SELECT rowid, records, rejected FROM batches INDEXED BY batches_of_session "
            "WHERE session_id = ? AND rowid > ? ORDER BY rowid LIMIT ?",
            (session_id, rowid, limit)).fetchall()
        return [LoggedBatch(row_id, json.loads(records), rejected)
                for row_id, records, rejected in rows]

    def packets(self, session_id: str) -> Iterator[Any]:
        """A session's packets in the order they were applied."""
        for batch in self.batches_after(session_id):
            yield from batch.records

    def last_replies(self, session_id: str, limit: int) -> list[LoggedReply]:
        """The replies to the session's last ``limit`` numbered batches, oldest first."""
        rows = self._db.execute(
            # only the numbered ones: through batches_of_session a restart read every row
            "SELECT client_seq, reply FROM batches INDEXED BY numbered_batches "
            "WHERE session_id = ? AND client_seq IS NOT NULL ORDER BY rowid DESC LIMIT ?",
            (session_id, limit)).fetchall()
        return [LoggedReply(seq, json.loads(reply)) for seq, reply in reversed(rows)]

    def close_session(self, session_id: str) -> None:
        """Mark a session ended (deleted or expired); :meth:`drop_closed` removes its log."""
        self.commit()
        self._db.execute("UPDATE sessions SET closed = 1 WHERE id = ?", (session_id,))

    def drop_closed(self, max_batches: int = DROP_CHUNK_BATCHES) -> int:
        """Delete up to ``max_batches`` logged batches of ended sessions, and the ended
        sessions (and their checkpoints) once none is left; return how many batches went.

        A chunk at a time, as the caller's turn allows: a session's batches lie among every
        other session's (about three to a page), so each one dropped rewrites a page; at
        close, 25 s of one session's batches took 30 ms, an hour's would take seconds."""
        self.commit()
        with self._db:
            self._db.execute("BEGIN")
            dropped: int = self._db.execute(
                "DELETE FROM batches WHERE rowid IN (SELECT b.rowid FROM sessions s CROSS "
                "JOIN batches b ON b.session_id = s.id WHERE s.closed = 1 LIMIT ?)",
                (max_batches,)).rowcount
            if dropped < max_batches:  # none left
                self._db.execute("DELETE FROM checkpoints WHERE session_id IN "
                                 "(SELECT id FROM sessions WHERE closed = 1)")
                self._db.execute("DELETE FROM sessions WHERE closed = 1")
        return dropped

    def open_sessions(self) -> list[LoggedSession]:
        rows = self._db.execute(
            "SELECT id, owner, vehicle_id, options, created_unix FROM sessions "
            "WHERE closed = 0 ORDER BY created_unix").fetchall()
        return [LoggedSession(r[0], r[1], r[2], json.loads(r[3]), r[4]) for r in rows]


def _lock(path: Path) -> IO[str]:
    """Hold ``<path>.lock`` for as long as the log is open; refuse when another has it."""
    lock = path.with_name(path.name + ".lock").open("a+")
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        lock.seek(0)
        holder = lock.read().strip() or "unknown"
        lock.close()
        raise TripLogInUse(
            f"trip log {path} is in use by another navsvc server (pid {holder}); stop it "
            "first, or give this one its own with --triplog / NAVSVC_TRIPLOG") from None
    lock.seek(0)
    lock.truncate()
    lock.write(f"{os.getpid()}\n")
    lock.flush()
    return lock
