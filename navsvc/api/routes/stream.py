"""WebSocket ``/sessions/{id}/stream``: packets in, matched positions and errors out.

Client messages: one packet object, an array of packets, or ``{"type": "ping"}``. For each
message the server sends ``{"type": "result", "accepted", "rejected", "positions"}`` (the
reply of ``POST /packets``), or ``{"type": "error", "code", "message"}`` when the message
itself is unusable, or ``{"type": "pong"}``. The API key goes in the ``X-API-Key`` header or,
for browsers, the ``api_key`` query parameter. An unknown session closes the socket with code
4404, a missing or wrong key with 4401 (the reason says which).

Slow readers: replies wait in a queue of ``NAVSVC_WS_QUEUE`` messages; when it is full the
oldest waiting reply is dropped (a newer one holds the newer positions), the next reply sent
carries ``"dropped": n``, and ``navsvc_websocket_messages_dropped`` counts it. So a client that
does not read costs the server at most that many messages.
"""

from __future__ import annotations

import asyncio
import json
import logging
from typing import Any

from fastapi import APIRouter, HTTPException, WebSocket, WebSocketDisconnect

from navsvc.api.deps import API_KEY_HEADER, AppState, check_key, websocket_state
from navsvc.api.routes.sessions import ingest
from navsvc.errors import SessionNotFound

router = APIRouter(tags=["sessions"])
log = logging.getLogger(__name__)


class ReplyQueue:
    """Bounded outgoing queue that drops the oldest reply when full."""

    def __init__(self, size: int, state: AppState) -> None:
        self._queue: asyncio.Queue[dict[str, Any]] = asyncio.Queue(size)
        self._state = state
        self.dropped = 0

    def put(self, message: dict[str, Any]) -> None:
        if self._queue.full():
            self._queue.get_nowait()
            self.dropped += 1
            self._state.metrics.ws_dropped.inc()
        self._queue.put_nowait(message)

    async def send_all(self, websocket: WebSocket) -> None:
        while True:
            message = await self._queue.get()
            if self.dropped:
                message = {**message, "dropped": self.dropped}
                self.dropped = 0
            await websocket.send_text(json.dumps(message, separators=(",", ":")))


@router.websocket("/sessions/{session_id}/stream")
async def stream(websocket: WebSocket, session_id: str) -> None:
    state = websocket_state(websocket)
    await websocket.accept()  # then refusals close with a code and reason the client can read
    try:
        owner = check_key(state, websocket.headers.get(API_KEY_HEADER)
                          or websocket.query_params.get("api_key"))
        state.store.get(session_id, owner)
    except HTTPException as exc:
        await websocket.close(code=4401, reason=str(exc.detail))
        return
    except SessionNotFound as exc:
        await websocket.close(code=4404, reason=str(exc))
        return
    replies = ReplyQueue(state.settings.ws_queue_messages, state)
    sender = asyncio.create_task(replies.send_all(websocket))
    try:
        while True:
            text = await websocket.receive_text()
            replies.put(_answer(state, session_id, owner, text))
            await asyncio.sleep(0)  # let the sender run between messages
    except WebSocketDisconnect:
        pass
    finally:
        sender.cancel()


def _answer(state: AppState, session_id: str, owner: str, text: str) -> dict[str, Any]:
    try:
        message = json.loads(text)
    except json.JSONDecodeError as exc:
        return _error("malformed", f"message is not JSON: {exc}")
    if isinstance(message, dict) and message.get("type") == "ping":
        return {"type": "pong"}
    packets, packets_json = (message, text) if isinstance(message, list) else \
        ([message], f"[{text}]")
    try:
        session = state.store.get(session_id, owner)  # it may have expired meanwhile
        reply = ingest(state, session, packets, packets_json)
    except SessionNotFound as exc:
        return _error("session_not_found", str(exc))
    except HTTPException as exc:
        return _error(_HTTP_CODES.get(exc.status_code, "error"), str(exc.detail))
    return {"type": "result", **reply}


_HTTP_CODES = {413: "too_many_packets", 503: "unavailable"}


def _error(code: str, message: str) -> dict[str, Any]:
    return {"type": "error", "code": code, "message": message}
