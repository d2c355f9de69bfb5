"""The trip log: every accepted packet of every live session, on disk before it is acknowledged.

An SQLite file beside the road-graph database (``maps/monaco.db`` → ``maps/monaco.trips.db``)
in WAL mode. A batch's accepted packets are written in one transaction and committed before the
reply leaves, so a server killed at any moment has every acknowledged packet on disk; on restart
:class:`navsvc.session.SessionStore` replays the open sessions' logs through fresh sessions.
With ``synchronous=NORMAL`` (the default here) a commit survives the process crashing; pass
``sync="full"`` to also survive the machine losing power, at an fsync per batch.

Only the API's event loop uses a TripLog, so one connection serves it.
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

SCHEMA = """
CREATE TABLE IF NOT EXISTS sessions (
    id TEXT PRIMARY KEY,
    owner TEXT NOT NULL,          -- SHA-256 of the API key that created it ('' when open)
    vehicle_id TEXT NOT NULL,
    options TEXT NOT NULL,        -- the creation request, JSON
    created_unix REAL NOT NULL,
    closed INTEGER NOT NULL DEFAULT 0
);
CREATE TABLE IF NOT EXISTS packets (
    session_id TEXT NOT NULL REFERENCES sessions(id),
    seq INTEGER NOT NULL,         -- 0, 1, 2 ... per session, in the order they were applied
    record TEXT NOT NULL,         -- the packet as received, JSON
    PRIMARY KEY (session_id, seq)
) WITHOUT ROWID;
"""


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

    def __init__(self, path: Path, sync: str = "normal") -> None:
        if sync not in ("normal", "full"):
            raise ValueError(f"sync must be 'normal' or 'full', got {sync!r}")
        self.path = path
        self._db = sqlite3.connect(path, isolation_level=None, check_same_thread=False)
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute(f"PRAGMA synchronous={sync.upper()}")
        self._db.executescript(SCHEMA)

    def close(self) -> None:
        self._db.close()

    def create_session(self, session: LoggedSession) -> None:
        with self._db:
            self._db.execute("BEGIN")
            self._db.execute(
                "INSERT INTO sessions (id, owner, vehicle_id, options, created_unix) "
                "VALUES (?, ?, ?, ?, ?)",
                (session.id, session.owner, session.vehicle_id, json.dumps(session.options),
                 session.created_unix))

    def append(self, session_id: str, first_seq: int, records: Sequence[Any]) -> None:
        """Write a batch of accepted packets (seq numbers from ``first_seq``) and commit."""
        if not records:
            return
        with self._db:
            self._db.execute("BEGIN")
            self._db.executemany(
                "INSERT INTO packets (session_id, seq, record) VALUES (?, ?, ?)",
                [(session_id, first_seq + i, json.dumps(r, separators=(",", ":")))
                 for i, r in enumerate(records)])

    def close_session(self, session_id: str) -> None:
        """Mark a session ended (deleted or expired) and drop its packets."""
        with self._db:
            self._db.execute("BEGIN")
            self._db.execute("UPDATE sessions SET closed = 1 WHERE id = ?", (session_id,))
            self._db.execute("DELETE FROM packets WHERE session_id = ?", (session_id,))

    def open_sessions(self) -> list[LoggedSession]:
        rows = self._db.execute(
            "SELECT id, owner, vehicle_id, options, created_unix FROM sessions "
            "WHERE closed = 0 ORDER BY created_unix").fetchall()
        return [LoggedSession(r[0], r[1], r[2], json.loads(r[3]), r[4]) for r in rows]

    def packets(self, session_id: str) -> Iterator[Any]:
        """A session's packets in the order they were applied."""
        cursor = self._db.execute(
            "SELECT record FROM packets WHERE session_id = ? ORDER BY seq", (session_id,))
        for (record,) in cursor:
            yield json.loads(record)

    def packet_count(self, session_id: str) -> int:
        row = self._db.execute("SELECT COUNT(*) FROM packets WHERE session_id = ?",
                               (session_id,)).fetchone()
        return int(row[0])
