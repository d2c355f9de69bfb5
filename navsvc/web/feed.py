"""The viewer feed: what the map page of a live session is sent, and how slow viewers are kept
from slowing the vehicles.

The ingest path calls :meth:`ViewerHub.publish` after each batch. A session nobody has looked at
costs one dict lookup there; from a viewer's first subscription on, the session's feed keeps
its recent history (raw GPS fixes and matched positions, at most ``history`` batches) so that a
viewer that connects later, or reloads, sees the track so far. Each viewer has a bounded queue
(as the vehicles' reply queues): when a viewer reads too slowly, the oldest waiting update is
dropped and the next one says ``"dropped": n``; the page then asks for a fresh snapshot. So a
viewer costs the ingest path a ``put_nowait`` per batch, whatever it does.

Messages to a viewer: ``{"type": "snapshot", "fixes": [...], "positions": [...]}`` first (and on
request), then ``{"type": "update", "fixes", "positions", "accepted", "rejected"}`` per batch,
``{"type": "ended"}`` when the session ends. A fix is ``{"t", "lat", "lon", "accuracy_m",
"hdop"}`` (NMEA and Oncore fixes decoded); a position is the matched position of
docs/interfaces.md.
"""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from navsvc.errors import PacketError
from navsvc.types import GpsFix
from navsvc.wire.packets import parse

GPS_KINDS = ("gps", "nmea", "oncore")


def fixes_of(records: Iterable[dict[str, Any]]) -> list[dict[str, Any]]:
    """The raw GPS fixes among a batch's accepted records (as validated), for drawing."""
    fixes = []
    for record in records:
        kind = record.get("kind")
        if kind == "gps":
            fixes.append({"t": record["t"], "lat": record["lat"], "lon": record["lon"],
                          "accuracy_m": record.get("accuracy_m"), "hdop": record.get("hdop")})
        elif kind in GPS_KINDS:
            try:
                fix = parse(record)
            except PacketError:  # accepted once, so it parses; be safe all the same
                continue
            if isinstance(fix, GpsFix):
                fixes.append({"t": fix.t, "lat": fix.lat_deg, "lon": fix.lon_deg,
                              "accuracy_m": fix.accuracy_m, "hdop": fix.hdop})
    return fixes


class ViewerQueue:
    """One viewer's outgoing messages, bounded; the oldest is dropped when full."""

    def __init__(self, size: int, on_drop: Callable[[], None] = lambda: None) -> None:
        self._queue: asyncio.Queue[dict[str, Any]] = asyncio.Queue(size)
        self._on_drop = on_drop
        self.dropped = 0

    def put(self, message: dict[str, Any]) -> None:
        if self._queue.full():
            self._queue.get_nowait()
            self.dropped += 1
            self._on_drop()
        self._queue.put_nowait(message)

    async def get(self) -> dict[str, Any]:
        """The next message, with ``"dropped": n`` when messages were dropped before it."""
        message = await self._queue.get()
        if self.dropped:
            message = {**message, "dropped": self.dropped}
            self.dropped = 0
        return message


@dataclass
class SessionFeed:
    """A watched session: its recent batches and its viewers."""

    history: deque[tuple[list[dict[str, Any]], list[dict[str, Any]]]]
    viewers: set[ViewerQueue] = field(default_factory=set)

    def snapshot(self, latest: dict[str, Any] | None) -> dict[str, Any]:
        fixes = [f for batch_fixes, _ in self.history for f in batch_fixes]
        positions = [p for _, batch_positions in self.history for p in batch_positions]
        if not positions and latest is not None:
            positions = [latest]
        return {"type": "snapshot", "fixes": fixes, "positions": positions}


class ViewerHub:
    """The feeds of the watched sessions, by session id."""

    def __init__(self, history_batches: int = 20_000, queue_messages: int = 64,
                 on_drop: Callable[[], None] = lambda: None) -> None:
        self.history_batches = history_batches
        self.queue_messages = queue_messages
        self._on_drop = on_drop
        self._feeds: dict[str, SessionFeed] = {}

    def __contains__(self, session_id: str) -> bool:
        return session_id in self._feeds

    def subscribe(self, session_id: str) -> ViewerQueue:
        """A new viewer of the session; from now on the session's batches are kept."""
        feed = self._feeds.get(session_id)
        if feed is None:
            feed = self._feeds[session_id] = SessionFeed(deque(maxlen=self.history_batches))
        viewer = ViewerQueue(self.queue_messages, self._on_drop)
        feed.viewers.add(viewer)
        return viewer

    def unsubscribe(self, session_id: str, viewer: ViewerQueue) -> None:
        """The viewer left; the session's history stays for the next one."""
        feed = self._feeds.get(session_id)
        if feed is not None:
            feed.viewers.discard(viewer)

    def snapshot(self, session_id: str, latest: dict[str, Any] | None) -> dict[str, Any]:
        feed = self._feeds.get(session_id)
        if feed is None:
            return {"type": "snapshot", "fixes": [], "positions": [] if latest is None
                    else [latest]}
        return feed.snapshot(latest)

    def publish(self, session_id: str, records: list[dict[str, Any]],
                reply: dict[str, Any]) -> None:
        """After a batch (``records``: the accepted, as validated; ``reply``: its reply):
        keep it and push it to the session's viewers. Nothing when nobody ever watched."""
        feed = self._feeds.get(session_id)
        if feed is None:
            return
        fixes, positions = fixes_of(records), reply["positions"]
        if not fixes and not positions and not reply["rejected"]:
            return
        feed.history.append((fixes, positions))
        if feed.viewers:
            update = {"type": "update", "fixes": fixes, "positions": positions,
                      "accepted": reply["accepted"], "rejected": reply["rejected"]}
            for viewer in feed.viewers:
                viewer.put(update)

    def end(self, session_id: str) -> None:
        """The session ended: tell its viewers, forget its history."""
        feed = self._feeds.pop(session_id, None)
        if feed is not None:
            for viewer in feed.viewers:
                viewer.put({"type": "ended"})
