"""Operations: health check and Prometheus metrics (no API key needed)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Response

from navsvc import __version__
from navsvc.api.deps import StateDep
from navsvc.metrics import CONTENT_TYPE

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
def metrics(state: StateDep) -> Response:
    """Packets accepted and rejected by reason, sessions, batch and match latency."""
    state.metrics.sessions.set(len(state.store))
    return Response(state.metrics.text(), media_type=CONTENT_TYPE)
