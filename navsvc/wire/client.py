"""A client of the service: create a session, stream packets over its WebSocket, collect the
matched positions (``navsvc send``, and a model for integrators)."""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import httpx
from websockets.exceptions import ConnectionClosed, InvalidHandshake
from websockets.sync.client import ClientConnection, connect

from navsvc.errors import NavsvcError


class ServiceError(NavsvcError):
    """The service refused a request or could not be reached."""


@dataclass
class StreamResult:
    session_id: str
    positions: list[dict[str, Any]] = field(default_factory=list)
    rejected: list[dict[str, Any]] = field(default_factory=list)  # index: position in the file
    accepted: int = 0


def create_session(url: str, options: dict[str, Any], api_key: str | None = None) -> str:
    headers = {"X-API-Key": api_key} if api_key else {}
    try:
        r = httpx.post(f"{url}/v1/sessions", json=options, headers=headers, timeout=30.0)
    except httpx.TransportError as exc:
        raise ServiceError(f"{url}: cannot connect: {exc}") from exc
    if r.status_code != 201:
        raise ServiceError(f"{url}: session refused ({r.status_code}): {r.text}")
    session_id: str = r.json()["id"]
    return session_id


def stream_packets(url: str, session_id: str, packets: Sequence[Any], *, batch: int = 10,
                   realtime: bool = False, api_key: str | None = None,
                   progress: Callable[[int], None] | None = None) -> StreamResult:
    """Send packets in batches over the session's WebSocket, one reply per batch; with
    ``realtime`` each batch leaves when its last packet's time has come."""
    result = StreamResult(session_id)
    ws_url = url.replace("http", "ws", 1) + f"/v1/sessions/{session_id}/stream"
    headers = {"X-API-Key": api_key} if api_key else {}
    try:
        with connect(ws_url, additional_headers=headers, max_size=None) as ws:
            _stream(ws, packets, batch, realtime, progress, result)
    except (OSError, ConnectionClosed, InvalidHandshake, TimeoutError) as exc:
        raise ServiceError(f"{ws_url}: {exc}") from exc
    return result


def _stream(ws: ClientConnection, packets: Sequence[Any], batch: int, realtime: bool,
            progress: Callable[[int], None] | None, result: StreamResult) -> None:
    start_wall, start_t = time.monotonic(), _first_time(packets)
    for i in range(0, len(packets), batch):
        chunk = packets[i:i + batch]
        if realtime and start_t is not None:
            last = chunk[-1]
            t = float(last["t"]) if isinstance(last, dict) and _is_number(last.get("t")) \
                else start_t
            time.sleep(max(0.0, start_wall + t - start_t - time.monotonic()))
        ws.send(json.dumps(chunk))
        reply = json.loads(ws.recv(timeout=60))
        if reply["type"] == "error":
            raise ServiceError(f"batch at packet {i}: {reply['code']}: {reply['message']}")
        result.accepted += reply["accepted"]
        result.positions += reply["positions"]
        result.rejected += [{**r, "index": i + r["index"]} for r in reply["rejected"]]
        if progress:
            progress(len(chunk))


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _first_time(packets: Sequence[Any]) -> float | None:
    for p in packets:
        if isinstance(p, dict) and _is_number(p.get("t")):
            return float(p["t"])
    return None
