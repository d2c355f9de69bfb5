"""The FastAPI application: routers under ``/v1``, errors as JSON, limits, session upkeep.

``create_app(settings)`` opens the road graph and the trip log; the server then serves at
once, restoring the sessions that were open when it last stopped (crash included) in the
background (a request for one restores it first), and expires idle sessions and drops ended
sessions' trip logs in the background.
Every error body is ``{"error": {"code", "message"[, "fields"]}}``.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import logging
import sqlite3
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.staticfiles import StaticFiles
from starlette.exceptions import HTTPException
from starlette.routing import compile_path
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from navsvc import __version__
from navsvc.api.deps import AppState
from navsvc.api.fast_stream import FastStream
from navsvc.api.logs import redact_api_keys
from navsvc.api.openapi import DOCS_STATIC_DIR, DOCS_STATIC_URL, build_openapi, docs_router
from navsvc.api.routes import maps, match, ops, sessions, stream, view
from navsvc.api.settings import Settings
from navsvc.api.warmup import warm_up
from navsvc.errors import (
    BatchAlreadyApplied,
    ConfigError,
    LimitExceeded,
    NavsvcError,
    SessionNotFound,
    TraceError,
)
from navsvc.metrics import Metrics, watch_event_loop
from navsvc.session import SessionStore
from navsvc.triplog import TripLog
from navsvc.web import STATIC_DIR
from navsvc.web.feed import ViewerHub
from roadgraph import RoadGraph, RoadGraphError

log = logging.getLogger(__name__)

_STATUS = {SessionNotFound: 404, LimitExceeded: 429, ConfigError: 422, TraceError: 422,
           BatchAlreadyApplied: 409}
_CODES = {400: "bad_request", 401: "unauthorized", 404: "not_found", 405: "method_not_allowed",
          409: "conflict", 413: "too_large", 422: "invalid_request", 429: "limit_exceeded",
          503: "unavailable"}


def create_app(settings: Settings, replay: dict[str, Any] | None = None) -> FastAPI:
    """The service for one map. Opening the map or trip log fails here, not on first use.

    ``replay``: a file for the map page to replay (``navsvc view``; see navsvc.web.replay);
    such a server skips the warm-up, having run the file's packets already."""
    graph = RoadGraph.open(settings.map_path)
    triplog = TripLog(settings.triplog, sync=settings.triplog_sync)
    store = SessionStore(graph, triplog, idle_timeout_s=settings.session_idle_s,
                         max_sessions_per_owner=settings.max_sessions_per_key,
                         id_prefix=settings.session_prefix)
    metrics = Metrics()
    triplog.append = metrics.timed_append(triplog.append)  # type: ignore[method-assign]
    triplog.commit = metrics.timed_commit(triplog)  # type: ignore[method-assign]
    metrics.watch_triplog(settings.triplog)
    metrics.watch_checkpoints(store.checkpoint_lag)
    state = AppState(settings=settings, graph=graph, store=store, metrics=metrics,
                     viewers=ViewerHub(settings.view_history_batches,
                                       settings.ws_queue_messages, metrics.viewer_dropped.inc),
                     replay=replay)

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        redact_api_keys()  # here: uvicorn has set up its loggers by now
        if replay is None:
            warm_up(graph)
        reopened = store.reopen()
        gc.collect()
        gc.freeze()  # the map and libraries stay: spare them the garbage collector's scans
        # Collections far rarer than Python's default (700, 10, 10): a full one walks every
        # session's objects (30-50 ms with 1,000 sessions), which made the p99 latency.
        gc.set_threshold(20_000, 50, 100)
        state.metrics.sessions.set(reopened)
        log.info("serving map %r (%s); trip log %s; %d open sessions to restore%s",
                 graph.map_id, settings.map_path, settings.triplog, reopened,
                 "" if settings.worker_id is None else f" (worker {settings.worker_id})")
        fast_stream = None if settings.stream_port is None else \
            FastStream(state, settings.stream_host, settings.stream_port)
        if fast_stream is not None:
            await fast_stream.start()
        upkeep = [asyncio.create_task(_restore_sessions(store)),
                  asyncio.create_task(_expire_idle(state)),
                  asyncio.create_task(_drop_closed_logs(triplog)),
                  asyncio.create_task(watch_event_loop(metrics.event_loop_lag))]
        yield
        for task in upkeep:
            task.cancel()
        if fast_stream is not None:
            await fast_stream.stop()
        store.checkpoint_all()  # the next start then replays nothing
        triplog.close()

    app = FastAPI(title="navsvc", version=__version__, lifespan=lifespan,
                  description="Map-matching navigation: vehicles stream sensor packets, the "
                              "service fuses them and matches them onto the road graph.",
                  docs_url=None, redoc_url=None)  # served offline below
    app.state.navsvc = state
    for module in (sessions, stream, view, match, maps, ops):
        app.include_router(module.router, prefix="/v1")
    app.include_router(view.page)
    app.include_router(docs_router(app))
    app.mount(DOCS_STATIC_URL, StaticFiles(directory=DOCS_STATIC_DIR), name="docs-static")
    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")
    _add_error_handlers(app)
    app.add_middleware(BodySizeLimit, max_bytes=settings.max_body_bytes)
    app.openapi = lambda: build_openapi(  # type: ignore[method-assign]
        app, keys_required=bool(settings.api_keys),
        max_batch_packets=settings.max_batch_packets)
    return app


async def _restore_sessions(store: SessionStore) -> None:
    """Rebuild the reopened sessions one per turn of the event loop, between requests (a
    request for one of them rebuilds it at once)."""
    start, count = time.perf_counter(), 0
    while store.restore_next():
        count += 1
        await asyncio.sleep(0)
    if count:
        log.info("%d sessions restored in the background in %.2f s", count,
                 time.perf_counter() - start)


async def _expire_idle(state: AppState) -> None:
    period = min(30.0, state.settings.session_idle_s / 4.0)
    while True:
        await asyncio.sleep(period)
        expired = state.store.expire_idle()
        for session_id in expired:
            state.viewers.end(session_id)
        state.metrics.sessions_expired.inc(len(expired))
        state.metrics.sessions.set(len(state.store))


async def _drop_closed_logs(triplog: TripLog, period_s: float = 1.0) -> None:
    """Remove ended sessions' logs a chunk at a time, busy at most a fifth of the time: the
    rest is for requests, and for the checkpointer (a purge at full speed wrote the WAL
    faster than it was copied, and the copies stalled the commits)."""
    while True:
        await asyncio.sleep(period_s)
        try:
            while True:
                start = time.perf_counter()
                if triplog.drop_closed() == 0:
                    break
                await asyncio.sleep(4.0 * (time.perf_counter() - start))
        except sqlite3.Error as exc:  # the rows stay marked: the next round tries again
            log.warning("dropping ended sessions' trip logs failed: %s", exc)


def _error(status: int, message: str, **extra: Any) -> JSONResponse:
    code = _CODES.get(status, "error")
    return JSONResponse({"error": {"code": code, "message": message, **extra}}, status)


def _routing_message(request: Request, exc: HTTPException) -> str:
    """Say what went wrong in the router's own refusals ("Not Found", "Method Not Allowed")."""
    method, path = request.method, request.url.path
    if exc.status_code == 404 and exc.detail == "Not Found":
        return (f"no route {method} {path}: the API is under /v1 (see /docs), the map view "
                "at /")
    if exc.status_code == 405 and exc.detail == "Method Not Allowed":
        allowed = _allowed_methods(request)
        return f"{method} is not allowed on {path}" + (f" (allowed: {allowed})" if allowed
                                                       else "")
    return str(exc.detail)


def _allowed_methods(request: Request) -> str:
    """The methods of every operation on the path, from the OpenAPI document (Starlette's
    Allow names only the first route's)."""
    methods: set[str] = set()
    for template, operations in request.app.openapi()["paths"].items():
        if compile_path(template)[0].match(request.url.path):
            methods |= {m.upper() for m in operations}
    return ", ".join(sorted(methods))


def _add_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(HTTPException)
    async def http_error(request: Request, exc: HTTPException) -> JSONResponse:
        response = _error(exc.status_code, _routing_message(request, exc))
        response.headers.update(exc.headers or {})  # 405's Allow, for one
        if exc.status_code == 405 and (allowed := _allowed_methods(request)):
            response.headers["Allow"] = allowed
        return response

    @app.exception_handler(RequestValidationError)
    async def invalid(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = exc.errors()
        if any(e["type"] == "json_invalid" for e in errors):
            return _error(400, "request body is not valid JSON: "
                               + "; ".join(str(e.get("ctx", {}).get("error", e["msg"]))
                                           for e in errors)[:300])
        fields = [{"field": ".".join(str(p) for p in e["loc"]), "message": e["msg"]}
                  for e in errors]
        summary = "; ".join(f"{f['field']}: {f['message']}" for f in fields[:5])
        return _error(422, f"invalid request: {summary}", fields=fields)

    @app.exception_handler(NavsvcError)
    async def refused(request: Request, exc: NavsvcError) -> JSONResponse:
        return _error(_STATUS.get(type(exc), 422), str(exc))

    @app.exception_handler(RoadGraphError)
    async def map_error(request: Request, exc: RoadGraphError) -> JSONResponse:
        return _error(503, f"map unavailable: {exc}")


class BodySizeLimit:
    """Refuse request bodies over ``max_bytes`` with 413, whether or not they say their size."""

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        declared = dict(scope["headers"]).get(b"content-length")
        if declared is not None and declared.isdigit() and int(declared) > self.max_bytes:
            await self._refuse(scope, receive, send)
            return
        body, more = bytearray(), True
        while more:
            message = await receive()
            if message["type"] == "http.disconnect":
                return
            body += message.get("body", b"")
            more = message.get("more_body", False)
            if len(body) > self.max_bytes:
                await self._refuse(scope, receive, send)
                return
        await self.app(scope, _replay(bytes(body)), send)

    async def _refuse(self, scope: Scope, receive: Receive, send: Send) -> None:
        response = _error(413, f"request body over {self.max_bytes} bytes "
                               "(NAVSVC_MAX_BODY_BYTES)")
        await response(scope, receive, send)


def _replay(body: bytes) -> Callable[[], Awaitable[Message]]:
    sent = False

    async def receive() -> Message:
        nonlocal sent
        if not sent:
            sent = True
            return {"type": "http.request", "body": body, "more_body": False}
        await asyncio.Event().wait()  # like a client that stays connected
        return {"type": "http.disconnect"}
    return receive
