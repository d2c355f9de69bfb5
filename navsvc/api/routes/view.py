"""The map view: the page (``GET /``, ``/map``), its static files, its configuration, and the
viewer WebSocket ``/v1/sessions/{id}/view`` that the server pushes a session's fixes and
positions to (:mod:`navsvc.web.feed`). ``navsvc view`` serves the same page on a file: then
``GET /v1/view/replay`` holds the whole drive.
"""

from __future__ import annotations

import asyncio
import json
from typing import Any

from fastapi import APIRouter, HTTPException, WebSocket, WebSocketDisconnect
from fastapi.responses import FileResponse

from navsvc import __version__
from navsvc.api.deps import StateDep, accept_session_socket
from navsvc.api.models import ErrorBody
from navsvc.web import STATIC_DIR
from navsvc.web.feed import ViewerQueue
from navsvc.wire.positions import position_json

page = APIRouter(include_in_schema=False)
router = APIRouter(tags=["map view"])


@page.get("/")
@page.get("/map")
def map_page() -> FileResponse:
    """The live map (and, under ``navsvc view``, the replay of a file)."""
    return FileResponse(STATIC_DIR / "index.html", media_type="text/html")


@router.get("/view/config", responses={200: {"content": {"application/json": {"example": {
    "map": "monaco", "bbox": [7.409, 43.723, 7.439, 43.752], "keys_required": False,
    "replay": False, "version": "0.1.0"}}}}})
def view_config(state: StateDep) -> dict[str, Any]:
    """What the map page needs first: the map's id and bounding box (W, S, E, N degrees),
    whether an API key is needed, whether this server replays a file (``navsvc view``)."""
    return {"map": state.graph.map_id, "bbox": list(state.graph.info.bbox_wgs84),
            "keys_required": bool(state.settings.api_keys),
            "replay": state.replay is not None, "version": __version__}


@router.get("/view/replay", responses={404: {"model": ErrorBody}, 200: {
    "content": {"application/json": {"example": {
        "source": "drive.jsonl", "fixes": [{"t": 0.0, "lat": 43.7384, "lon": 7.4246,
                                            "accuracy_m": 3.0, "hdop": 0.9}],
        "positions": [], "truth": [], "rejected": 0}}}}})
def view_replay(state: StateDep) -> dict[str, Any]:
    """The whole file that ``navsvc view`` replays: raw fixes, matched positions, truth."""
    if state.replay is None:
        raise HTTPException(404, "this server replays no file (start one with navsvc view)")
    return state.replay


@router.websocket("/sessions/{session_id}/view")
async def view(websocket: WebSocket, session_id: str) -> None:
    """A viewer of a session: a snapshot, then an update per batch (navsvc.web.feed)."""
    accepted = await accept_session_socket(websocket, session_id)
    if accepted is None:
        return
    state, _, session = accepted
    info = {"id": session.id, "vehicle_id": session.vehicle_id, "options": session.options}

    def snapshot() -> dict[str, Any]:
        last = session.vehicle.last_position
        latest = None if last is None else position_json(last, state.graph.frame)
        return {**state.viewers.snapshot(session_id, latest), "session": info}

    viewer = state.viewers.subscribe(session_id)
    viewer.put(snapshot())
    sender = asyncio.create_task(_send_all(websocket, viewer))
    try:
        while True:
            message = await websocket.receive()
            if message["type"] == "websocket.disconnect":
                break
            if _asks_snapshot(message.get("text") or "") and session_id in state.viewers:
                viewer.put(snapshot())
    except (WebSocketDisconnect, RuntimeError):
        pass
    finally:
        sender.cancel()
        state.viewers.unsubscribe(session_id, viewer)


def _asks_snapshot(text: str) -> bool:
    try:
        message = json.loads(text)
    except ValueError:
        return False
    return isinstance(message, dict) and message.get("type") == "snapshot"


async def _send_all(websocket: WebSocket, viewer: ViewerQueue) -> None:
    while True:
        message = await viewer.get()
        await websocket.send_text(json.dumps(message, separators=(",", ":")))
        if message["type"] == "ended":
            await websocket.close(code=1000, reason="session ended")
            return
