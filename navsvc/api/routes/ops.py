"""Operations: health check and Prometheus metrics (no API key needed)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Query, Response

from navsvc import __version__
from navsvc.api.deps import StateDep
from navsvc.api.fleet import Scope, ask_workers, other_workers
from navsvc.metrics import CONTENT_TYPE, merge_expositions

router = APIRouter(tags=["operations"])


@router.get("", include_in_schema=False)
@router.get("/", summary="Index", responses={200: {"content": {"application/json": {
    "example": {"service": "navsvc", "version": "0.1.0", "map": "monaco",
                "links": {"map_view": "/", "docs": "/docs"}}}}}})
def index(state: StateDep) -> dict[str, Any]:
    """What this server is, and where to go: the live map, the API docs, the schema."""
    return {"service": "navsvc", "version": __version__, "map": state.graph.map_id,
            "links": {"map_view": "/", "docs": "/docs", "redoc": "/redoc",
                      "openapi": "/openapi.json", "sessions": "/v1/sessions",
                      "maps": "/v1/maps", "health": "/v1/healthz",
                      "wire_contract": "docs/interfaces.md in the repository"}}


@router.get("/healthz")
def healthz(state: StateDep) -> dict[str, Any]:
    """Liveness and readiness: the map is loaded and the trip log is open."""
    return {"status": "ok", "map": state.graph.map_id, "sessions": len(state.store)}


@router.get("/metrics", response_class=Response,
            responses={200: {"content": {"text/plain": {}},
                             "description": "Prometheus text exposition format"}})
async def metrics(state: StateDep, scope: Scope = Query(  # noqa: B008
        "fleet", description="fleet: every worker's metrics, each series labelled with its "
        "worker (behind the balancer); worker: this worker's alone")) -> Response:
    """Per worker: packets accepted and rejected by reason, sessions open, ingest latency
    (navsvc_batch_seconds), trip-log append latency and size, checkpoint lag, event-loop lag;
    match latency. Behind the balancer, every worker's (navsvc_worker_up says which answered)."""
    state.metrics.sessions.set(len(state.store))
    own = state.metrics.text()
    workers = other_workers(state.settings, scope)
    if state.settings.worker_id is None or scope == "worker":
        return Response(own, media_type=CONTENT_TYPE)
    answers = await ask_workers(workers, "/v1/metrics", {})
    scrapes = {str(state.settings.worker_id): own.decode()}
    scrapes.update({str(a.worker_id): a.body.decode() for a in answers if a.body is not None})
    up = {str(k): str(k) in scrapes for k in range(len(state.settings.peers))}
    up[str(state.settings.worker_id)] = True
    return Response(merge_expositions(dict(sorted(scrapes.items())), up),
                    media_type=CONTENT_TYPE)
