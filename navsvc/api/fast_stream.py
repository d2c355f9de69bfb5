"""The session stream on picows: ``ws://HOST:NAVSVC_STREAM_PORT/v1/sessions/{id}/stream``.

The same WebSocket as :mod:`navsvc.api.routes.stream` (its messages, replies, errors, close
codes 4401 and 4404, the API key in ``X-API-Key`` or ``?api_key=``, the reply queue that drops
the oldest when a client does not read), answered by the same function
(:func:`navsvc.api.routes.stream.answer`, hence the same ingest and group commit), but on
picows's WebSocket server instead of uvicorn and the ASGI stack: a second port, served in
the same process and event loop, over the same session store. Opt-in
(``navsvc serve --stream-port``, ``NAVSVC_STREAM_PORT``); the uvicorn endpoint stays.

Why: the transport was a third of the server's CPU per packet. The bare stacks answering
200 real-rate sessions without doing any work (``bench/service_load.py --floor-stacks
uvicorn,picows``): uvicorn 6.7 us of CPU per packet, picows 2.5.

Per connection, messages are answered one at a time in order, as the uvicorn route does: a
frame that arrives while one is being answered waits; past ``MAX_WAITING_FRAMES`` waiting,
the socket is not read until they are answered.
"""

from __future__ import annotations

import asyncio
import logging
import re
from collections import deque
from typing import Any
from urllib.parse import parse_qs, unquote, urlsplit

from picows import (
    WSCloseCode,
    WSFrame,
    WSListener,
    WSMsgType,
    WSTransport,
    WSUpgradeRequest,
    ws_create_server,
)

from navsvc.api.deps import API_KEY_HEADER, AppState, check_key
from navsvc.api.routes.stream import answer, encode_reply
from navsvc.errors import SessionNotFound

log = logging.getLogger(__name__)

MAX_WAITING_FRAMES = 32  # frames of one connection waiting to be answered, before it is
# no longer read (uvicorn's websockets implementation stops reading at 32 too)
MAX_MESSAGE_BYTES = 16 * 1024 * 1024  # uvicorn's ws_max_size
PING_IDLE_S = 20.0  # as navsvc serve's uvicorn: a ping after 20 s without traffic,
PING_REPLY_S = 20.0  # and the connection closed when its pong takes longer than 20 s
_PATH = re.compile(r"/v1/sessions/([^/]+)/stream")


class StreamListener(WSListener):
    """One connection: its session, the frames waiting for an answer, the replies waiting
    for the client to read."""

    def __init__(self, state: AppState, session_id: str, key: str | None,
                 open_listeners: set[StreamListener]) -> None:
        self.state, self.session_id, self._key = state, session_id, key
        self.owner = ""
        self._open = open_listeners
        self._transport: WSTransport | None = None
        self._waiting: deque[dict[str, Any]] = deque()  # frames, as ASGI's receive events
        self._busy = False  # a task is answering this connection's frames
        self._paused_reading = False
        self._unsent: deque[dict[str, Any]] = deque()  # replies while the client is not read
        self._writing_paused = False
        self._dropped = 0
        self._fragments: list[bytes] = []  # of a message sent in several frames
        self._fragment_type = WSMsgType.TEXT

    def on_ws_connected(self, transport: WSTransport) -> None:
        self._transport = transport
        try:
            self.owner = check_key(self.state, self._key)
            self.state.store.get(self.session_id, self.owner)
        except SessionNotFound as exc:
            self._close(4404, str(exc))
            return
        except Exception as exc:  # noqa: BLE001 (check_key's HTTPException 401)
            self._close(4401, str(getattr(exc, "detail", exc)))
            return
        self._open.add(self)

    def on_ws_disconnected(self, transport: WSTransport) -> None:
        self._open.discard(self)
        self._waiting.clear()

    def on_ws_frame(self, transport: WSTransport, frame: WSFrame) -> None:
        kind = frame.msg_type
        if kind == WSMsgType.CLOSE:
            transport.send_close(frame.get_close_code(), frame.get_close_message())
            transport.disconnect()
            return
        if kind not in (WSMsgType.TEXT, WSMsgType.BINARY, WSMsgType.CONTINUATION):
            return  # ping and pong: picows answers pings itself
        payload: bytes | None
        if kind != WSMsgType.CONTINUATION and frame.fin:  # a message in one frame
            self._fragments, self._fragment_type = [], kind
            payload = frame.get_payload_as_bytes()
        else:
            payload = self._reassemble(kind, frame)
        if payload is None:
            return
        if self._fragment_type == WSMsgType.TEXT:
            try:
                event: dict[str, Any] = {"text": payload.decode()}
            except UnicodeDecodeError:
                self._close(int(WSCloseCode.INVALID_TEXT.value), "invalid UTF-8 in a text message")
                return
        else:
            event = {"bytes": payload}
        self._waiting.append(event)
        if not self._busy:
            self._busy = True
            asyncio.get_running_loop().create_task(self._answer_waiting())
        elif len(self._waiting) > MAX_WAITING_FRAMES and not self._paused_reading:
            transport.underlying_transport.pause_reading()
            self._paused_reading = True

    def _reassemble(self, kind: WSMsgType, frame: WSFrame) -> bytes | None:
        """A message sent in several frames: its payload once its last frame is in."""
        if kind != WSMsgType.CONTINUATION:
            self._fragments, self._fragment_type = [], kind
        self._fragments.append(frame.get_payload_as_bytes())
        if sum(map(len, self._fragments)) > MAX_MESSAGE_BYTES:
            self._close(int(WSCloseCode.MESSAGE_TOO_BIG.value), "message too big")
            return None
        if not frame.fin:
            return None
        payload, self._fragments = b"".join(self._fragments), []
        return payload

    async def _answer_waiting(self) -> None:
        """Answer the waiting frames in order, each once the one before is answered."""
        try:
            while self._waiting:
                event = self._waiting.popleft()
                if self._paused_reading and len(self._waiting) <= MAX_WAITING_FRAMES // 2:
                    self._paused_reading = False
                    self._transport_or_none().underlying_transport.resume_reading()
                self._send(await answer(self.state, self.session_id, self.owner, event))
        finally:
            self._busy = False

    def _transport_or_none(self) -> Any:
        assert self._transport is not None
        return self._transport

    def _send(self, reply: dict[str, Any]) -> None:
        """Send a reply, or queue it while the client does not read (the oldest dropped past
        ``NAVSVC_WS_QUEUE``; the next reply sent says how many)."""
        transport = self._transport
        if transport is None or transport.is_disconnected:
            return
        if self._writing_paused:
            if len(self._unsent) >= self.state.settings.ws_queue_messages:
                self._unsent.popleft()
                self._dropped += 1
                self.state.metrics.ws_dropped.inc()
            self._unsent.append(reply)
            return
        if self._dropped:
            reply, self._dropped = {**reply, "dropped": self._dropped}, 0
        transport.send(WSMsgType.TEXT, encode_reply(reply))

    def pause_writing(self) -> None:
        self._writing_paused = True

    def resume_writing(self) -> None:
        self._writing_paused = False
        while self._unsent and not self._writing_paused:
            self._send(self._unsent.popleft())

    def _close(self, code: int, reason: str) -> None:
        if self._transport is not None and not self._transport.is_disconnected:
            self._transport.send_close(code, reason.encode()[:120])  # type: ignore[arg-type]
            self._transport.disconnect()

    def close_for_shutdown(self) -> None:
        self._close(int(WSCloseCode.SERVICE_RESTART.value), "server shutting down")


def _listener_factory(state: AppState, open_listeners: set[StreamListener]) -> Any:
    def factory(request: WSUpgradeRequest) -> StreamListener | None:
        url = urlsplit(request.path.decode("latin-1"))
        match = _PATH.fullmatch(url.path)
        if request.method != b"GET" or match is None:
            return None  # 404
        key = request.headers.get(API_KEY_HEADER) or \
            next(iter(parse_qs(url.query).get("api_key", [])), None)
        return StreamListener(state, unquote(match.group(1)), key, open_listeners)
    return factory


class FastStream:
    """The picows server of one app, started and stopped by its lifespan."""

    def __init__(self, state: AppState, host: str, port: int) -> None:
        self.state, self.host, self.port = state, host, port
        self._server: asyncio.Server | None = None
        self._open: set[StreamListener] = set()

    async def start(self) -> None:
        self._server = await ws_create_server(
            _listener_factory(self.state, self._open), self.host, self.port,
            enable_auto_ping=True, auto_ping_idle_timeout=PING_IDLE_S,
            auto_ping_reply_timeout=PING_REPLY_S, max_frame_size=MAX_MESSAGE_BYTES)
        log.info("session streams (picows) on ws://%s:%d/v1/sessions/{id}/stream", self.host,
                 self.port)

    async def stop(self) -> None:
        if self._server is None:
            return
        self._server.close()
        for listener in list(self._open):
            listener.close_for_shutdown()
        await self._server.wait_closed()
