"""A whole trace matched to a route (the HMM of ``navsvc.matching.hmm``), as the JSON of
``navsvc match`` and ``POST /v1/match``."""

from __future__ import annotations

from typing import Any

import numpy as np
from shapely import LineString
from shapely.ops import substring

from navsvc.errors import TraceError
from navsvc.matching.hmm import HmmConfig, HmmMatcher, MatchResult, RouteSegment
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
        if start <= 0.0 and end >= r.length_m:  # the whole edge (all but the two ends)
            coords = r.coords
        else:
            piece = substring(LineString(r.coords), start, max(end, start))
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
        "geometry": {"type": "LineString", "coordinates": np.round(lonlat, 7).tolist()},
    }


def _local(graph: RoadGraph, fixes: list[TraceFix]) -> np.ndarray:
    """The fixes in the map's metres, as an ``(n, 2)`` array (one projection call)."""
    lonlat = np.array([(f.lon_deg, f.lat_deg) for f in fixes], dtype=np.float64).reshape(-1, 2)
    return graph.frame.coords_to_local(lonlat)


DEFAULT_CONFIG = HmmConfig()


def match_trace(graph: RoadGraph, fixes: list[TraceFix],
                config: HmmConfig = DEFAULT_CONFIG) -> dict[str, Any]:
    """Match a trace (sorted by time and deduplicated first) and describe the route."""
    fixes = clean(fixes)
    xy = _local(graph, fixes)
    result: MatchResult = HmmMatcher(graph, config).match(xy.tolist())
    if not result.segments:
        radius = config.search_radius_sigmas * config.sigma_m
        raise TraceError(f"no point of the trace is within {radius:g} m of a road of the map "
                         f"{graph.map_id!r} (is it the right map?)")
    on_road = [m.projection for m in result.points if m.projection is not None]
    matched_lonlat = iter(np.round(graph.frame.coords_to_wgs84(
        np.array([(p.x_m, p.y_m) for p in on_road], dtype=np.float64).reshape(-1, 2)),
        7).tolist())
    per_point = []
    for f, m in zip(fixes, result.points):
        matched = None
        if m.projection is not None:
            lon, lat = next(matched_lonlat)
            e = m.projection.edge
            matched = {"lat": lat, "lon": lon,
                       "edge": {"u": e.u, "v": e.v, "key": e.key},
                       "distance_m": round(m.projection.distance_m, 2),
                       "segment": m.segment}
        per_point.append({"index": m.trace_index, "t": f.t, "lat": f.lat_deg, "lon": f.lon_deg,
                          "matched": matched})
    segments = [_segment_json(graph, s) for s in result.segments]
    length = np.hypot(*np.diff(xy, axis=0).T).sum() if len(xy) > 1 else 0.0
    return {"map": graph.map_id, "points_in": len(fixes),
            "trace_length_m": round(float(length), 2),
            "length_m": round(sum(s["length_m"] for s in segments), 2),
            "segments": segments, "points": per_point}
