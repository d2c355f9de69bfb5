"""What route handlers receive: the app's state and the caller's identity."""

from __future__ import annotations

import secrets
from dataclasses import dataclass, field
from functools import cached_property
from typing import Annotated, Any

from fastapi import Depends, HTTPException, Request, WebSocket
from fastapi.security import APIKeyHeader

from navsvc.api.settings import Settings
from navsvc.errors import SessionNotFound
from navsvc.metrics import Metrics
from navsvc.session import LiveSession, SessionStore, key_bytes, owner_of
from navsvc.web.feed import ViewerHub
from roadgraph import RoadGraph

API_KEY_HEADER = "X-API-Key"
_api_key = APIKeyHeader(name=API_KEY_HEADER, auto_error=False,
                        description="required when the server has NAVSVC_API_KEYS set")


@dataclass
class AppState:
    settings: Settings
    graph: RoadGraph
    store: SessionStore
    metrics: Metrics
    viewers: ViewerHub = field(default_factory=ViewerHub)  # the map page's live feeds
    replay: dict[str, Any] | None = None  # the file `navsvc view` replays, if any

    @cached_property
    def api_keys(self) -> tuple[bytes, ...]:
        """The accepted keys as bytes, encoded once (they are compared at every request)."""
        return tuple(key_bytes(k) for k in self.settings.api_keys)


def get_state(request: Request) -> AppState:
    state: AppState = request.app.state.navsvc
    return state


def check_key(state: AppState, key: str | None) -> str:
    """The owner the key stands for; 401 when keys are required and this one is not valid.

    Compared as bytes (any characters a client sends), with every accepted key, so that the
    time taken says nothing about which key came close."""
    keys = state.api_keys
    if keys:
        given, valid = key_bytes(key), False
        for k in keys:
            valid |= secrets.compare_digest(given, k)
        if not (key and valid):
            raise HTTPException(401, "missing or unknown API key (header X-API-Key)")
    return owner_of(key)


def get_owner(request: Request, key: Annotated[str | None, Depends(_api_key)]) -> str:
    return check_key(get_state(request), key)


def websocket_state(websocket: WebSocket) -> AppState:
    state: AppState = websocket.app.state.navsvc
    return state


StateDep = Annotated[AppState, Depends(get_state)]
OwnerDep = Annotated[str, Depends(get_owner)]


async def accept_session_socket(websocket: WebSocket,
                                session_id: str) -> tuple[AppState, str, LiveSession] | None:
    """Accept a session's WebSocket and check the caller's key (header or ``?api_key=``):
    the app state, the key's owner and the session. None when refused: the socket is then
    closed with 4401 (key) or 4404 (no such session for this key), a code and reason the
    client can read, as it could not after a refused handshake."""
    state = websocket_state(websocket)
    await websocket.accept()
    try:
        owner = check_key(state, websocket.headers.get(API_KEY_HEADER)
                          or websocket.query_params.get("api_key"))
        return state, owner, state.store.get(session_id, owner)
    except HTTPException as exc:
        await websocket.close(code=4401, reason=str(exc.detail))
    except SessionNotFound as exc:
        await websocket.close(code=4404, reason=str(exc))
    return None
