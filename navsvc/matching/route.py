"""A whole trace matched to a route, as the JSON of ``navsvc match`` and ``POST /v1/match``."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from shapely import LineString
from shapely.ops import substring

from navsvc.errors import TraceError
from navsvc.matching.hmm import HmmConfig, HmmMatcher, MatchResult, RouteSegment, TracePoint
from navsvc.wire.traces import TraceFix, clean
from roadgraph import RoadGraph


def _collapse(values: list[Any]) -> list[Any]:
    return [v for i, v in enumerate(values) if i == 0 or v != values[i - 1]]


def _segment_json(graph: RoadGraph, seg: RouteSegment) -> dict[str, Any]:
    records = [graph.edge(e) for e in seg.edges]
    parts: list[np.ndarray] = []
    for i, r in enumerate(records):
        start = seg.start_offset_m if i == 0 else 0.0
        end = seg.end_offset_m if i == len(records) - 1 else r.length_m
        line = LineString(r.coords)
        piece = substring(line, start, max(end, start))
        coords = np.asarray(piece.coords) if not piece.is_empty else r.coords[:1]
        parts.append(coords if not parts else coords[1:])
    xy = np.vstack(parts)
    lonlat = graph.frame.coords_to_wgs84(xy)
    return {
        "edges": [{"u": r.u, "v": r.v, "key": r.key, "osm_way_ids": list(r.osm_way_ids),
                   "name": r.name, "length_m": round(r.length_m, 2)} for r in records],
        "osm_way_ids": _collapse([w for r in records for w in r.osm_way_ids]),
        "streets": _collapse([r.name or "" for r in records]),
        "length_m": round(seg.length_m, 2),
        "geometry": {"type": "LineString",
                     "coordinates": [[round(lo, 7), round(la, 7)] for lo, la in lonlat]},
    }


def trace_length_m(graph: RoadGraph, fixes: list[TraceFix]) -> float:
    xy = [graph.frame.to_local(f.lon_deg, f.lat_deg) for f in fixes]
    return float(sum(math.dist(a, b) for a, b in zip(xy[:-1], xy[1:])))


DEFAULT_CONFIG = HmmConfig()


def match_trace(graph: RoadGraph, fixes: list[TraceFix],
                config: HmmConfig = DEFAULT_CONFIG) -> dict[str, Any]:
    """Match a trace (sorted by time and deduplicated first) and describe the route."""
    fixes = clean(fixes)
    points = [TracePoint(f.t, *graph.frame.to_local(f.lon_deg, f.lat_deg)) for f in fixes]
    result: MatchResult = HmmMatcher(graph, config).match(points)
    if not result.segments:
        radius = config.search_radius_sigmas * config.sigma_m
        raise TraceError(f"no point of the trace is within {radius:g} m of a road of the map "
                         f"{graph.map_id!r} (is it the right map?)")
    per_point = []
    for f, m in zip(fixes, result.points):
        matched = None
        if m.projection is not None:
            lon, lat = graph.frame.to_wgs84(m.projection.x_m, m.projection.y_m)
            e = m.projection.edge
            matched = {"lat": round(lat, 7), "lon": round(lon, 7),
                       "edge": {"u": e.u, "v": e.v, "key": e.key},
                       "distance_m": round(m.projection.distance_m, 2),
                       "segment": m.segment}
        per_point.append({"index": m.index, "t": f.t, "lat": f.lat_deg, "lon": f.lon_deg,
                          "matched": matched})
    segments = [_segment_json(graph, s) for s in result.segments]
    return {"map": graph.map_id, "points_in": len(fixes),
            "trace_length_m": round(trace_length_m(graph, fixes), 2),
            "length_m": round(sum(s["length_m"] for s in segments), 2),
            "segments": segments, "points": per_point}
