"""The trip log: every accepted packet of every live session, on disk before it is acknowledged.

An SQLite file beside the road-graph database (``maps/monaco.db`` → ``maps/monaco.trips.db``)
in WAL mode. A batch's accepted packets are written in one transaction and committed before the
reply leaves, so a server killed at any moment has every acknowledged packet on disk; on restart
:class:`navsvc.session.SessionStore` replays the open sessions' logs through fresh sessions.
With ``synchronous=NORMAL`` (the default here) a commit survives the process crashing; pass
``sync="full"`` to also survive the machine losing power, at an fsync per batch.

Only the API's event loop uses a TripLog, so one connection serves it. Checkpoints (copying
the WAL into the database file, with an fsync) run every second in a thread of their own, on
their own connection, instead of inside whichever commit crossed SQLite's 1,000-page mark:
there they stalled the event loop for 20 ms every 0.6 s with 1,000 GPS-only sessions. Once
few pages are left to copy, a short blocking pass lets the WAL start over instead of growing
under load. An ended session is only marked; :meth:`TripLog.drop_closed` deletes its batches
later, a chunk at a time.
"""

from __future__ import annotations

import json
import logging
import sqlite3
import threading
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)

_ENCODER = json.JSONEncoder(separators=(",", ":"))
PASSIVE_CHECKPOINTS = 8  # at most, each second
FRAMES_LEFT_FOR_RESTART = 256  # that one copies no more than about this many pages
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
CREATE TABLE IF NOT EXISTS batches (
    session_id TEXT NOT NULL REFERENCES sessions(id),
    seq INTEGER NOT NULL,         -- number of the batch's first packet (0, 1, 2 ... per session,
                                  -- in the order they were applied)
    count INTEGER NOT NULL,       -- packets in the batch
    records TEXT NOT NULL,        -- the accepted packets as received, a JSON array
    PRIMARY KEY (session_id, seq)
);
"""

# Older layouts are moved over when opened: one row a packet (``packets``), and batches in a
# WITHOUT ROWID table (its rows of a kilobyte or more spilled to overflow pages, and each
# commit rewrote five pages).
_MIGRATIONS = {
    "packets": """
        INSERT INTO batches (session_id, seq, count, records)
            SELECT session_id, seq, 1, '[' || record || ']' FROM packets;
        DROP TABLE packets;""",
    "batches_without_rowid": """
        INSERT INTO batches SELECT * FROM batches_without_rowid;
        DROP TABLE batches_without_rowid;""",
}


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


class TripLog:
    """Append-only log of sessions and their accepted packets."""

    def __init__(self, path: Path, sync: str = "normal", checkpoint_every_s: float = 1.0) -> None:
        if sync not in ("normal", "full"):
            raise ValueError(f"sync must be 'normal' or 'full', got {sync!r}")
        self.path = path
        self._db = sqlite3.connect(path, isolation_level=None, check_same_thread=False)
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute(f"PRAGMA synchronous={sync.upper()}")
        self._db.execute("PRAGMA wal_autocheckpoint=0")  # the checkpointer thread does it
        batches = self._db.execute("SELECT sql FROM sqlite_master WHERE name = 'batches'"
                                   ).fetchone()
        if batches is not None and "WITHOUT ROWID" in batches[0].upper():
            self._db.execute("ALTER TABLE batches RENAME TO batches_without_rowid")
        self._db.executescript(SCHEMA)
        for table, script in _MIGRATIONS.items():
            if self._db.execute("SELECT 1 FROM sqlite_master WHERE name = ?", (table,)
                                ).fetchone():
                self._db.executescript(f"BEGIN; {script} COMMIT;")
        self._closing = threading.Event()
        self._checkpointer = threading.Thread(target=self._checkpoint, args=(checkpoint_every_s,),
                                              name=f"checkpoint {path.name}", daemon=True)
        self._checkpointer.start()

    def _checkpoint(self, every_s: float) -> None:
        db = sqlite3.connect(self.path, isolation_level=None)
        try:
            while not self._closing.wait(every_s):
                try:
                    # Passive checkpoints never wait for the writer, but under steady load
                    # one never catches up with it, and only a complete checkpoint lets the
                    # WAL start over (it grew by 40 MB/s at 2,000 batches/s). So: passive
                    # ones until few frames are left, then one that holds the writer off
                    # while it copies those (if the writer outruns them all, next time).
                    for _ in range(PASSIVE_CHECKPOINTS):
                        _, frames, copied = db.execute("PRAGMA wal_checkpoint(PASSIVE)"
                                                       ).fetchone()
                        if frames - copied <= FRAMES_LEFT_FOR_RESTART:
                            db.execute("PRAGMA wal_checkpoint(RESTART)")
                            break
                except sqlite3.Error as exc:  # try again next time: the WAL only grows
                    log.warning("trip log checkpoint failed: %s", exc)
        finally:
            db.close()

    def close(self) -> None:
        self._closing.set()
        self._checkpointer.join()
        self._db.close()

    def create_session(self, session: LoggedSession) -> None:
        self._db.execute(  # one statement: its own transaction
            "INSERT INTO sessions (id, owner, vehicle_id, options, created_unix) "
            "VALUES (?, ?, ?, ?, ?)",
            (session.id, session.owner, session.vehicle_id, json.dumps(session.options),
             session.created_unix))

    def append(self, session_id: str, first_seq: int, records: Sequence[Any],
               records_json: str | None = None) -> None:
        """Write a batch of accepted packets (seq numbers from ``first_seq``) and commit;
        ``records_json`` is their JSON array when the caller has it already.

        One row a batch: encoding and inserting packet by packet cost a fifth of the
        service's time per packet."""
        if not records:
            return
        self._db.execute(  # one statement: its own transaction, committed when it returns
            "INSERT INTO batches (session_id, seq, count, records) VALUES (?, ?, ?, ?)",
            (session_id, first_seq, len(records),
             _ENCODER.encode(records) if records_json is None else records_json))

    def close_session(self, session_id: str) -> None:
        """Mark a session ended (deleted or expired); :meth:`drop_closed` removes its log."""
        self._db.execute("UPDATE sessions SET closed = 1 WHERE id = ?", (session_id,))

    def drop_closed(self, max_batches: int = DROP_CHUNK_BATCHES) -> int:
        """Delete up to ``max_batches`` logged batches of ended sessions, and the ended
        sessions once none is left; return how many batches went.

        A chunk at a time, as the caller's turn allows: a session's batches lie among every
        other session's (about three to a page), so each one dropped rewrites a page; at
        close, 25 s of one session's batches took 30 ms, an hour's would take seconds."""
        with self._db:
            self._db.execute("BEGIN")
            dropped: int = self._db.execute(
                "DELETE FROM batches WHERE rowid IN (SELECT b.rowid FROM sessions s CROSS "
                "JOIN batches b ON b.session_id = s.id WHERE s.closed = 1 LIMIT ?)",
                (max_batches,)).rowcount
            if dropped < max_batches:  # none left
                self._db.execute("DELETE FROM sessions WHERE closed = 1")
        return dropped

    def open_sessions(self) -> list[LoggedSession]:
        rows = self._db.execute(
            "SELECT id, owner, vehicle_id, options, created_unix FROM sessions "
            "WHERE closed = 0 ORDER BY created_unix").fetchall()
        return [LoggedSession(r[0], r[1], r[2], json.loads(r[3]), r[4]) for r in rows]

    def packets(self, session_id: str) -> Iterator[Any]:
        """A session's packets in the order they were applied."""
        cursor = self._db.execute(
            "SELECT records FROM batches WHERE session_id = ? ORDER BY seq", (session_id,))
        for (records,) in cursor:
            yield from json.loads(records)
