"""The floor under the service's WebSocket path: the same FastAPI app shape and settings as
``navsvc serve``, with the API's session and stream routes doing nothing but decode each
message and answer one reply (a position for each GPS fix). What the service costs above
this is validation, fusion, matching and the trip log.

A text frame is JSON, a binary frame MessagePack; the reply is in the same format (both
through msgspec, as the service decodes). The stack is chosen by ``--server``, to measure the
alternatives side by side (``bench/service_load.py --floor-servers``):

- ``uvicorn`` (as ``navsvc serve``), with ``--ws websockets-sansio`` (uvicorn's default and
  the service's), ``websockets`` (the legacy asyncio implementation) or ``wsproto``;
- ``granian``: the same ASGI app under granian (a Rust HTTP/WebSocket server);
- ``picows``: no ASGI at all, picows's WebSocket server on its own, with a bare asyncio HTTP
  responder on the port for the bench's session calls (its WebSocket listens on PORT + 1):
  what a WebSocket path outside FastAPI could cost.

    python bench/ws_floor.py PORT [--server uvicorn|granian|picows] [--ws IMPL]
"""

from __future__ import annotations

import argparse
import asyncio
import secrets
import sys
from pathlib import Path
from typing import Any

import msgspec
from fastapi import FastAPI, Response, WebSocket, WebSocketDisconnect

app = FastAPI()
_JSON_DECODE = msgspec.json.Decoder(list[dict[str, Any]]).decode
_PACK_DECODE = msgspec.msgpack.Decoder(list[dict[str, Any]]).decode
_JSON_ENCODE = msgspec.json.Encoder().encode
_PACK_ENCODE = msgspec.msgpack.Encoder().encode


def reply_to(batch: list[dict[str, Any]]) -> dict[str, Any]:
    """The floor's reply: the batch counted, a position for each GPS fix."""
    positions = [{"t": p["t"], "lat": p["lat"], "lon": p["lon"]}
                 for p in batch if p.get("kind") == "gps"]
    return {"type": "result", "accepted": len(batch), "rejected": [], "positions": positions}


@app.get("/v1/healthz")
async def healthz() -> dict[str, str]:
    return {"status": "ok"}


@app.post("/v1/sessions", status_code=201)
async def create_session() -> dict[str, str]:
    return {"id": secrets.token_hex(8)}


@app.delete("/v1/sessions/{session_id}", status_code=204)
async def delete_session(session_id: str) -> Response:
    return Response(status_code=204)


@app.websocket("/v1/sessions/{session_id}/stream")
async def stream(websocket: WebSocket, session_id: str) -> None:
    await websocket.accept()
    try:
        while True:
            message = await websocket.receive()
            if message["type"] == "websocket.disconnect":
                break
            text = message.get("text")
            if text is not None:
                await websocket.send_text(_JSON_ENCODE(reply_to(_JSON_DECODE(text))).decode())
            else:
                await websocket.send_bytes(_PACK_ENCODE(reply_to(_PACK_DECODE(
                    message.get("bytes") or b""))))
    except WebSocketDisconnect:
        pass


async def _http_stub(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    """The session calls and health checks of the picows floor, answered canned."""
    try:
        while request := await reader.readuntil(b"\r\n\r\n"):
            method = request.split(b" ", 1)[0]
            for line in request.lower().split(b"\r\n"):
                if line.startswith(b"content-length:"):
                    await reader.readexactly(int(line.split(b":")[1]))  # the body
            if method == b"POST":
                status, body = b"201 Created", b'{"id":"%s"}' % secrets.token_hex(8).encode()
            elif method == b"DELETE":
                status, body = b"204 No Content", b""
            else:
                status, body = b"200 OK", b'{"status":"ok"}'
            writer.write(b"HTTP/1.1 %s\r\ncontent-type: application/json\r\n"
                         b"content-length: %d\r\n\r\n%s" % (status, len(body), body))
            await writer.drain()
    except (asyncio.IncompleteReadError, ConnectionError):
        writer.close()


def serve_picows(port: int) -> None:
    """picows's WebSocket server on ``port + 1``; the session calls and health checks on
    ``port`` answered by a few lines of asyncio."""
    import uvloop
    from picows import WSFrame, WSListener, WSMsgType, WSTransport, ws_create_server

    class Listener(WSListener):
        def on_ws_frame(self, transport: WSTransport, frame: WSFrame) -> None:
            if frame.msg_type == WSMsgType.TEXT:
                transport.send(WSMsgType.TEXT, _JSON_ENCODE(reply_to(_JSON_DECODE(
                    frame.get_payload_as_bytes()))))
            elif frame.msg_type == WSMsgType.BINARY:
                transport.send(WSMsgType.BINARY, _PACK_ENCODE(reply_to(_PACK_DECODE(
                    frame.get_payload_as_bytes()))))
            elif frame.msg_type == WSMsgType.CLOSE:
                transport.send_close(frame.get_close_code(), frame.get_close_message())
                transport.disconnect()

    async def main() -> None:
        await ws_create_server(lambda _: Listener(), "127.0.0.1", port + 1)
        server = await asyncio.start_server(_http_stub, "127.0.0.1", port)
        await server.serve_forever()

    uvloop.run(main())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("port", type=int)
    parser.add_argument("--server", choices=("uvicorn", "granian", "picows"), default="uvicorn")
    parser.add_argument("--ws", choices=("websockets-sansio", "websockets", "wsproto"),
                        default="websockets-sansio", help="uvicorn's WebSocket implementation")
    args = parser.parse_args()
    if args.server == "picows":
        serve_picows(args.port)
    elif args.server == "granian":
        from granian import Granian
        from granian.constants import Interfaces, Loops

        Granian("ws_floor:app", address="127.0.0.1", port=args.port,
                interface=Interfaces.ASGI, loop=Loops.uvloop, workers=1, websockets=True,
                working_dir=Path(__file__).parent, log_access=False).serve()
    else:
        import uvicorn

        # as navsvc serve (navsvc/cli.py)
        uvicorn.run(app, host="127.0.0.1", port=args.port, ws=args.ws, ws_ping_interval=20.0,
                    ws_ping_timeout=20.0, ws_per_message_deflate=False, log_level="warning")


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).parent))
    main()
