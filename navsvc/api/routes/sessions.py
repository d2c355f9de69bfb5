"""Sessions: create, inspect, delete; packets in by POST; the latest position."""

from __future__ import annotations

import asyncio
import logging
import sqlite3
import time
from typing import Any

from fastapi import APIRouter, Body, HTTPException, Query, Request, Response

from navsvc.api.deps import API_KEY_HEADER, AppState, OwnerDep, StateDep
from navsvc.api.fleet import Scope, ask_workers, other_workers
from navsvc.api.models import BatchReply, ErrorBody, SessionCreate, SessionInfo, SessionList
from navsvc.errors import ConfigError
from navsvc.session import MAX_CLIENT_SEQ, LiveSession
from navsvc.triplog import CommitGroup
from navsvc.wire.bulk import Batch
from navsvc.wire.positions import position_json

router = APIRouter(prefix="/sessions", tags=["sessions"],
                   responses={401: {"model": ErrorBody}, 404: {"model": ErrorBody}})
log = logging.getLogger(__name__)


def session_info(state: AppState, s: LiveSession) -> SessionInfo:
    position = s.vehicle.last_position
    return SessionInfo(
        id=s.id, vehicle_id=s.vehicle_id, map=state.graph.map_id, options=s.options,
        created_unix=s.created_unix, packets_accepted=s.packets, packets_rejected=s.rejected,
        position=None if position is None else position_json(position, state.graph.frame))


async def ingest(state: AppState, session: LiveSession, packets: list[Any] | Batch,
                 client_seq: int | None = None) -> dict[str, Any]:
    """Apply a batch (API and WebSocket alike; a :class:`Batch` when the WebSocket decoded
    and validated it whole), count it, and return its reply, the JSON of a
    :class:`BatchReply`, once the trip log has committed it.

    Group commit: the batch joins the trip log's open transaction, committed once the event
    loop has run every message it had ready (:func:`committed`), so the batches of one turn
    share one commit; the reply waits for it. A lost commit is a 503, as a failed write is."""
    limit = state.settings.max_batch_packets
    if len(packets) > limit:
        raise HTTPException(413, f"{len(packets)} packets in one batch; the limit is {limit}")
    start = time.perf_counter()
    try:
        done = state.store.ingest(session, packets, client_seq, defer_commit=True)
        if done.group is not None:
            await committed(state, done.group)
    except sqlite3.Error as exc:
        raise HTTPException(503, f"the trip log cannot be written ({exc}); the batch was not "
                                 "applied, send it again") from exc
    m = state.metrics
    if done.result is not None:  # not a resend answered from memory
        m.batch_seconds.observe(time.perf_counter() - start)
        m.packets_accepted.inc(done.result.accepted)
        for r in done.result.rejections:
            m.packets_rejected.labels(r.reason.code).inc()
        m.positions.inc(len(done.result.positions))
        if session.id in state.viewers:  # the records are decoded only for a viewer
            state.viewers.publish(session.id, done.result.records, done.reply)
    return done.reply


async def committed(state: AppState, group: CommitGroup) -> None:
    """Return once ``group`` is committed; raise its error (sqlite3.Error) if it was lost.

    The first waiter of a group schedules its commit with ``call_soon``: it runs after the
    callbacks the event loop already has ready (the other connections' messages of this
    turn), which join the group meanwhile."""
    future: asyncio.Future[BaseException | None] = asyncio.get_running_loop().create_future()

    def done(error: BaseException | None) -> None:
        if not future.done():  # the waiter may be gone (its connection closed)
            future.set_result(error)

    group.when_done(done)
    if not group.scheduled and not group.finished:
        group.scheduled = True
        asyncio.get_running_loop().call_soon(_commit, state)
    error = await future
    if error is not None:
        raise error


def _commit(state: AppState) -> None:
    try:
        state.store.checkpoint_due()  # a few at a time, in this group
        state.store.triplog.commit()
    except sqlite3.Error as exc:  # the group's waiters have it, and answer 503
        log.error("trip log commit failed: %s", exc)


def named_profile(state: AppState, name: str) -> dict[str, Any]:
    """A profile of ``navsvc serve --profiles DIR`` by name, as the options keep it (its
    parameters inline, so a restored session does not depend on the folder)."""
    known = state.settings.profiles()
    if name not in known:
        raise ConfigError(f"no profile {name!r} on this server (known: "
                          f"{', '.join(sorted(known)) or 'none; start it with --profiles DIR'})")
    return {"name": name, "parameters": known[name]["parameters"]}


@router.post("", status_code=201, response_model=SessionInfo,
             responses={422: {"model": ErrorBody}, 429: {"model": ErrorBody}})
async def create_session(body: SessionCreate, state: StateDep, owner: OwnerDep) -> SessionInfo:
    """Start a session for one vehicle."""
    options = body.options()
    if isinstance(body.profile, str):
        options["profile"] = named_profile(state, body.profile)
    session = state.store.create(owner, body.vehicle_id, options)
    state.metrics.sessions.set(len(state.store))
    return session_info(state, session)


@router.get("", response_model=SessionList)
async def list_sessions(request: Request, state: StateDep, owner: OwnerDep,
                        scope: Scope = Query(  # noqa: B008
                            "fleet", description="fleet: on every worker (behind the "
                            "balancer); worker: on the worker that answers")) -> SessionList:
    """The caller's open sessions (on every worker)."""
    mine = SessionList(sessions=[session_info(state, s) for s in state.store.sessions(owner)])
    workers = other_workers(state.settings, scope)
    key = request.headers.get(API_KEY_HEADER)
    for answer in await ask_workers(workers, "/v1/sessions", {API_KEY_HEADER: key} if key
                                    else {}):
        if answer.body is None:
            mine.workers_unreachable.append(answer.worker_id)
        else:
            mine.sessions += SessionList.model_validate_json(answer.body).sessions
    return mine


@router.get("/{session_id}", response_model=SessionInfo)
async def get_session(session_id: str, state: StateDep, owner: OwnerDep) -> SessionInfo:
    return session_info(state, state.store.get(session_id, owner))


@router.delete("/{session_id}", status_code=204)
async def delete_session(session_id: str, state: StateDep, owner: OwnerDep) -> Response:
    """End a session and drop its trip log."""
    state.store.delete(session_id, owner)
    state.viewers.end(session_id)
    state.metrics.sessions.set(len(state.store))
    return Response(status_code=204)


@router.post("/{session_id}/packets", response_model=BatchReply,
             responses={409: {"model": ErrorBody}, 413: {"model": ErrorBody},
                        422: {"model": ErrorBody}})
async def post_packets(
    session_id: str, state: StateDep, owner: OwnerDep,
    packets: list[Any] = Body(  # noqa: B008 (FastAPI's way to declare a bare array body)
        description="sensor packets (interfaces.md), oldest first; a bad packet is rejected "
                    "alone and reported by index", examples=[[
                        {"t": 0.0, "kind": "gps", "lat": 43.7384, "lon": 7.4246},
                        {"t": 0.01, "kind": "imu", "yaw_rate_dps": 1.5}]]),
    batch_seq: int | None = Query(  # noqa: B008
        None, ge=0, le=MAX_CLIENT_SEQ,
        description="the client's number for this batch, increasing per session: a batch "
                    "sent again with the same number (say, after a lost reply) is not applied "
                    "twice but answered with its first reply plus \"duplicate\": true; "
                    "409 when that reply is no longer kept (the last 64 are)"),
) -> dict[str, Any]:
    """Apply packets in order; the reply comes once the accepted ones are in the trip log."""
    return await ingest(state, state.store.get(session_id, owner), packets, batch_seq)


@router.get("/{session_id}/position", responses={200: {"description": "matched position"}})
async def get_position(session_id: str, state: StateDep, owner: OwnerDep) -> dict[str, Any]:
    """The session's latest matched position (reading it changes nothing, so a restored
    session answers the same)."""
    session = state.store.get(session_id, owner)
    position = session.vehicle.last_position
    if position is None:
        raise HTTPException(404, f"session {session_id!r} has no position yet (no GPS fix)")
    return position_json(position, state.graph.frame)
