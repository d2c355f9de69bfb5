"""WebSocket ``/sessions/{id}/stream``: packets in, matched positions and errors out.

Client messages: one packet object, an array of packets, a numbered batch
``{"type": "batch", "seq": N, "packets": [...]}`` (``seq`` as ``batch_seq`` of ``POST
/packets``: a resend is answered with the first reply, ``"duplicate": true``, and not applied
again), or ``{"type": "ping"}``. For each message the server sends ``{"type": "result",
"accepted", "rejected", "positions"}`` (the reply of ``POST /packets``, with ``"seq"`` for a
numbered batch), or ``{"type": "error", "code", "message"}`` when the message itself is
unusable (not JSON, not UTF-8, too deep, too many packets, ...), or ``{"type": "pong"}``. The
API key goes in the ``X-API-Key`` header or, for browsers, the ``api_key`` query parameter
(never written to the server's log). An unknown session closes the socket with code 4404, a
missing or wrong key with 4401 (the reason says which).

A result leaves once its batch is committed to the trip log, in the group commit of every
message the event loop took in the same turn (:func:`navsvc.api.routes.sessions.ingest`);
``unavailable`` when that commit failed (nothing of the batch was applied).

Slow readers: replies wait in a queue of ``NAVSVC_WS_QUEUE`` messages; when it is full the
oldest waiting reply is dropped (a newer one holds the newer positions), the next reply sent
carries ``"dropped": n``, and ``navsvc_websocket_messages_dropped`` counts it. So a client that
does not read costs the server at most that many messages.
"""

from __future__ import annotations

import asyncio
import json
import logging
from collections.abc import Mapping
from typing import Any

import msgspec
from fastapi import APIRouter, HTTPException, WebSocket, WebSocketDisconnect

from navsvc.api.deps import AppState, accept_session_socket
from navsvc.api.routes.sessions import ingest
from navsvc.errors import BatchAlreadyApplied, SessionNotFound
from navsvc.session import MAX_CLIENT_SEQ
from navsvc.wire import bulk

router = APIRouter(tags=["sessions"])
log = logging.getLogger(__name__)

# Replies as JSON: msgspec, 0.1 us for a reply without positions and 1.0 us with one, against
# 3.3 and 9.7 us for json.dumps (the same values; text beyond ASCII as UTF-8, not escaped)
encode_reply = msgspec.json.Encoder().encode


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
            await websocket.send_text(encode_reply(message).decode())


@router.websocket("/sessions/{session_id}/stream")
async def stream(websocket: WebSocket, session_id: str) -> None:
    accepted = await accept_session_socket(websocket, session_id)
    if accepted is None:
        return
    state, owner, _ = accepted
    # The connection's loop as a task of its own: each of its wake-ups (a message, a commit)
    # then resumes its few frames, not the twenty of the ASGI stack above this route (its
    # middleware's coroutines), which cost ~5 % of the server's CPU at 100 sessions. A
    # cancelled route (shutdown) cancels the task it awaits.
    await asyncio.create_task(_serve(websocket, state, session_id, owner))


async def _serve(websocket: WebSocket, state: AppState, session_id: str, owner: str) -> None:
    """Answer the messages of one connection, until it closes."""
    replies = ReplyQueue(state.settings.ws_queue_messages, state)
    sender = asyncio.create_task(replies.send_all(websocket))
    try:
        while True:
            message = await websocket.receive()
            if message["type"] == "websocket.disconnect":
                break
            replies.put(await answer(state, session_id, owner, message))
            await asyncio.sleep(0)  # let the sender run between messages
    except WebSocketDisconnect:
        pass
    finally:
        sender.cancel()


async def answer(state: AppState, session_id: str, owner: str, frame: Mapping[str, Any]
                 ) -> dict[str, Any]:
    """The reply to one WebSocket message (an ASGI receive event: ``text`` or ``bytes``;
    also the picows endpoint's, :mod:`navsvc.api.fast_stream`); never raises. A numbered
    batch or an array whose packets are all valid is decoded and validated in one call
    (:func:`navsvc.wire.bulk.decode_message`); any other message, or one with a bad packet,
    the careful way, which says what is wrong."""
    text = frame.get("text")
    fast = bulk.decode_message(text if text is not None else frame.get("bytes") or b"",
                               MAX_CLIENT_SEQ)
    if fast is not None:
        return await _ingest(state, session_id, owner, fast[1], fast[0])
    if text is None:
        try:
            text = (frame.get("bytes") or b"").decode()
        except UnicodeDecodeError:
            return _error("malformed", "binary message is not UTF-8 JSON text")
    try:
        message = json.loads(text)
    except (ValueError, RecursionError) as exc:  # also too deep, or an integer too long
        return _error("malformed", f"message is not usable JSON: {str(exc)[:200]}")
    if isinstance(message, dict) and message.get("type") == "ping":
        return {"type": "pong"}
    seq = None
    if isinstance(message, dict) and message.get("type") == "batch":
        seq, packets = message.get("seq"), message.get("packets")
        if not isinstance(seq, int) or isinstance(seq, bool) or not 0 <= seq <= MAX_CLIENT_SEQ:
            return _error("malformed",
                          f"batch seq must be an integer from 0 to {MAX_CLIENT_SEQ}")
        if not isinstance(packets, list):
            return _error("malformed", "batch packets must be an array")
    else:
        packets = message if isinstance(message, list) else [message]
    return await _ingest(state, session_id, owner, packets, seq)


async def _ingest(state: AppState, session_id: str, owner: str,
                  packets: list[Any] | bulk.Batch, seq: int | None) -> dict[str, Any]:
    try:
        session = state.store.get(session_id, owner)  # it may have expired meanwhile
        reply = await ingest(state, session, packets, seq)
    except SessionNotFound as exc:
        return _error("session_not_found", str(exc))
    except BatchAlreadyApplied as exc:
        return _error("batch_already_applied", str(exc))
    except HTTPException as exc:
        return _error(_HTTP_CODES.get(exc.status_code, "error"), str(exc.detail))
    except Exception:  # a fault of ours: say so, and keep serving the connection
        log.exception("session %s: message could not be handled", session_id)
        return _error("internal", "the server could not handle this message")
    return {"type": "result", **reply} if seq is None else {"type": "result", "seq": seq,
                                                             **reply}


_HTTP_CODES = {413: "too_many_packets", 503: "unavailable"}


def _error(code: str, message: str) -> dict[str, Any]:
    return {"type": "error", "code": code, "message": message}
