"""``POST /match``: a whole trace matched to a route (the offline matcher)."""

from __future__ import annotations

import time
from typing import Any

from fastapi import APIRouter, HTTPException

from navsvc.api.deps import OwnerDep, StateDep
from navsvc.api.models import ErrorBody, MatchRequest
from navsvc.matching.hmm import HmmConfig
from navsvc.wire.route import match_trace
from navsvc.wire.traces import TraceFix, parse_trace

router = APIRouter(tags=["matching"])


@router.post("/match", responses={413: {"model": ErrorBody}, 422: {"model": ErrorBody}})
def match(body: MatchRequest, state: StateDep, _owner: OwnerDep) -> dict[str, Any]:
    """Match a trace (sorted by time, exact duplicates dropped, split at gaps the road graph
    cannot bridge) and return the route: edges, OSM way ids, streets, geometry, length, and
    each point's match. Runs in a worker thread: the road graph is read-only."""
    start = time.perf_counter()
    if body.points is not None:
        fixes = [TraceFix(p.t if p.t is not None else float(i), p.lat, p.lon)
                 for i, p in enumerate(body.points)]
    else:
        assert body.trace is not None and body.format is not None
        fixes = parse_trace(body.trace, body.format, "trace")
    limit = state.settings.max_trace_points
    if len(fixes) > limit:
        raise HTTPException(413, f"the trace has {len(fixes)} points; the limit is {limit}")
    route = match_trace(state.graph, fixes, HmmConfig(sigma_m=body.sigma_m,
                                                      beta_m=2.0 * body.sigma_m,
                                                      max_points=limit))
    state.metrics.match_seconds.observe(time.perf_counter() - start)
    return route
