"""What route handlers receive: the app's state and the caller's identity."""

from __future__ import annotations

import asyncio
import secrets
import sqlite3
from dataclasses import dataclass
from typing import Annotated

from fastapi import Depends, HTTPException, Request, WebSocket
from fastapi.security import APIKeyHeader

from navsvc.api.settings import Settings
from navsvc.metrics import Metrics
from navsvc.session import SessionStore, owner_of
from roadgraph import RoadGraph

API_KEY_HEADER = "X-API-Key"
_api_key = APIKeyHeader(name=API_KEY_HEADER, auto_error=False,
                        description="required when the server has NAVSVC_API_KEYS set")


class GroupCommit:
    """One trip-log commit for all the batches ingested in one turn of the event loop.

    A commit costs 30-90 µs whatever it holds; with hundreds of sessions each sending ten
    messages a second that was a tenth of the server's time. A handler ingests its batch
    without committing, then awaits :meth:`durable`; the first one in a turn schedules the
    commit for the start of the next turn, after every handler that was ready has ingested.
    Replies wait for it, so nothing is acknowledged before it is on disk.
    """

    def __init__(self, store: SessionStore) -> None:
        self._store = store
        self._next: asyncio.Future[None] | None = None
        self._rollbacks_before = 0

    async def durable(self) -> None:
        """Return once everything ingested so far is committed; raises sqlite3.Error if it
        was not (the store has then rebuilt the sessions concerned from the log)."""
        if self._next is None:
            loop = asyncio.get_running_loop()
            self._next = loop.create_future()
            self._rollbacks_before = self._store.rollbacks
            loop.call_soon(self._commit)
        await asyncio.shield(self._next)  # a waiter that goes away must not cancel the rest

    def _commit(self) -> None:
        done, self._next = self._next, None
        assert done is not None
        try:
            self._store.commit()
            if self._store.rollbacks != self._rollbacks_before:  # another write failed first
                raise sqlite3.OperationalError("the trip log dropped this turn's batches")
        except sqlite3.Error as exc:
            done.set_exception(exc)
            done.exception()  # retrieved here too: every waiter may be gone
        else:
            done.set_result(None)


@dataclass
class AppState:
    settings: Settings
    graph: RoadGraph
    store: SessionStore
    metrics: Metrics
    commits: GroupCommit


def get_state(request: Request) -> AppState:
    state: AppState = request.app.state.navsvc
    return state


def check_key(state: AppState, key: str | None) -> str:
    """The owner the key stands for; 401 when keys are required and this one is not valid."""
    keys = state.settings.api_keys
    if keys and not (key and any(secrets.compare_digest(key, k) for k in keys)):
        raise HTTPException(401, "missing or unknown API key (header X-API-Key)")
    return owner_of(key)


def get_owner(request: Request, key: Annotated[str | None, Depends(_api_key)]) -> str:
    return check_key(get_state(request), key)


def websocket_state(websocket: WebSocket) -> AppState:
    state: AppState = websocket.app.state.navsvc
    return state


StateDep = Annotated[AppState, Depends(get_state)]
OwnerDep = Annotated[str, Depends(get_owner)]
