"""Matched positions → the JSON object of interfaces.md (degrees and WGS84 on the wire)."""

from __future__ import annotations

import math
from typing import Any

from navsvc.types import EdgeRef, MatchedPosition
from roadgraph import LocalFrame


def _edge_json(edge: EdgeRef, with_offset: bool = True) -> dict[str, Any]:
    out: dict[str, Any] = {"u": edge.u, "v": edge.v, "key": edge.key,
                           "osm_way_ids": list(edge.osm_way_ids), "name": edge.name}
    if with_offset:
        out["offset_m"] = round(edge.offset_m, 2)
        out["length_m"] = round(edge.length_m, 2)
    return out


def position_json(p: MatchedPosition, frame: LocalFrame) -> dict[str, Any]:
    """One matched position as sent to clients and written by ``navsvc run``."""
    e = p.estimate
    lon, lat = frame.to_wgs84(p.x_m, p.y_m)
    fused_lon, fused_lat = frame.to_wgs84(e.x_m, e.y_m)
    gps: dict[str, Any] | None = None
    if e.gps is not None:
        gps = {"used": e.gps.used, "weight": round(e.gps.weight, 3), "reason": e.gps.reason}
        if e.gps.nis is not None:
            gps["nis"] = round(e.gps.nis, 3)
    return {
        "t": round(e.t, 4), "lat": round(lat, 7), "lon": round(lon, 7),
        "fused_lat": round(fused_lat, 7), "fused_lon": round(fused_lon, 7),
        "heading_deg": round(math.degrees(e.heading_rad) % 360.0, 2),
        "speed_mps": round(e.speed_mps, 3), "position_sigma_m": round(e.position_sigma_m, 2),
        "state": p.state.value,
        "edge": None if p.edge is None else _edge_json(p.edge),
        "distance_to_road_m": None if p.distance_to_road_m is None
        else round(p.distance_to_road_m, 2),
        "candidates": [{"edge": _edge_json(edge, with_offset=False),
                        "probability": round(prob, 4)} for edge, prob in p.candidates],
        "next_node": p.next_node,
        "distance_to_next_node_m": None if p.distance_to_next_node_m is None
        else round(p.distance_to_next_node_m, 2),
        "gps": gps,
    }
