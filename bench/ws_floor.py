"""The floor under the service's WebSocket path: the same FastAPI + uvicorn stack and settings
as ``navsvc serve``, with the API's session and stream routes doing nothing but read each
message's JSON and answer one reply (a position for each GPS fix). What the service costs above
this is parsing, fusion, matching and the trip log.

    python bench/ws_floor.py PORT
"""

from __future__ import annotations

import json
import secrets
import sys
from typing import Any

from fastapi import FastAPI, Response, WebSocket, WebSocketDisconnect

app = FastAPI()


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
            batch: list[dict[str, Any]] = json.loads(await websocket.receive_text())
            positions = [{"t": p["t"], "lat": p["lat"], "lon": p["lon"]}
                         for p in batch if p.get("kind") == "gps"]
            await websocket.send_text(json.dumps(
                {"type": "result", "accepted": len(batch), "rejected": [],
                 "positions": positions}, separators=(",", ":")))
    except WebSocketDisconnect:
        pass


if __name__ == "__main__":
    import uvicorn

    # as navsvc serve (navsvc/cli.py)
    uvicorn.run(app, host="127.0.0.1", port=int(sys.argv[1]), ws_ping_interval=20.0,
                ws_ping_timeout=20.0, ws_per_message_deflate=False, log_level="warning")
