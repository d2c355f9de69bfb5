"""Matched positions → the JSON object of interfaces.md (degrees and WGS84 on the wire)."""

from __future__ import annotations

import math
from typing import Any

from navsvc.types import EdgeRef, MatchedPosition
from roadgraph import LocalFrame


def _num(value: float, digits: int) -> float | None:
    """Rounded for the wire; null when not finite (JSON has no NaN or Infinity, and a
    browser's JSON.parse refuses them)."""
    return round(value, digits) if math.isfinite(value) else None


def _edge_json(edge: EdgeRef, with_offset: bool = True) -> dict[str, Any]:
    out: dict[str, Any] = {"u": edge.u, "v": edge.v, "key": edge.key,
                           "osm_way_ids": list(edge.osm_way_ids), "name": edge.name}
    if with_offset:
        out["offset_m"] = _num(edge.offset_m, 2)
        out["length_m"] = _num(edge.length_m, 2)
    return out


def position_json(p: MatchedPosition, frame: LocalFrame) -> dict[str, Any]:
    """One matched position as sent to clients and written by ``navsvc run`` (every number
    finite, or null)."""
    e = p.estimate
    lon, lat = frame.to_wgs84(p.x_m, p.y_m)
    fused_lon, fused_lat = frame.to_wgs84(e.x_m, e.y_m)
    gps: dict[str, Any] | None = None
    if e.gps is not None:
        gps = {"used": e.gps.used, "weight": _num(e.gps.weight, 3), "reason": e.gps.reason}
        if e.gps.nis is not None:
            gps["nis"] = _num(e.gps.nis, 3)
    return {
        "t": _num(e.t, 4), "lat": _num(lat, 7), "lon": _num(lon, 7),
        "fused_lat": _num(fused_lat, 7), "fused_lon": _num(fused_lon, 7),
        "heading_deg": _num(math.degrees(e.heading_rad) % 360.0, 2),
        "speed_mps": _num(e.speed_mps, 3), "position_sigma_m": _num(e.position_sigma_m, 2),
        "state": p.state.value,
        "edge": None if p.edge is None else _edge_json(p.edge),
        "distance_to_road_m": None if p.distance_to_road_m is None
        else _num(p.distance_to_road_m, 2),
        "candidates": [{"edge": _edge_json(edge, with_offset=False),
                        "probability": _num(prob, 4)} for edge, prob in p.candidates],
        "next_node": p.next_node,
        "distance_to_next_node_m": None if p.distance_to_next_node_m is None
        else _num(p.distance_to_next_node_m, 2),
        "gps": gps,
    }
