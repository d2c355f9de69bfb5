"""Road-graph records as GeoJSON (pure): for `roadgraph export` and the maps API."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from roadgraph.build import EdgeRecord, NodeRecord


def edge_feature(edge: EdgeRecord) -> dict[str, Any]:
    """One edge as a GeoJSON LineString feature in WGS84."""
    return {
        "type": "Feature",
        "geometry": {"type": "LineString", "coordinates": edge.lonlat.round(7).tolist()},
        "properties": {
            "u": edge.u, "v": edge.v, "key": edge.key, "osm_way_ids": list(edge.osm_way_ids),
            "name": edge.name, "highway": edge.highway, "oneway": edge.oneway,
            "maxspeed": edge.maxspeed, "lanes": edge.lanes, "tunnel": edge.tunnel,
            "bridge": edge.bridge, "length_m": round(edge.length_m, 3),
        },
    }


def node_feature(node: NodeRecord) -> dict[str, Any]:
    """One intersection as a GeoJSON Point feature in WGS84."""
    return {
        "type": "Feature",
        "geometry": {"type": "Point",
                     "coordinates": [round(node.lon_deg, 7), round(node.lat_deg, 7)]},
        "properties": {"id": node.id, "osm_ids": list(node.osm_ids), "degree": node.degree},
    }


def feature_collection(
    edges: Iterable[EdgeRecord], nodes: Iterable[NodeRecord] = ()
) -> dict[str, Any]:
    """A FeatureCollection of edges, then nodes."""
    features = [edge_feature(e) for e in edges] + [node_feature(n) for n in nodes]
    return {"type": "FeatureCollection", "features": features}
