"""The served map: metadata, and its edges as GeoJSON for a bounding box."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, HTTPException, Query

from navsvc.api.deps import AppState, OwnerDep, StateDep
from navsvc.api.models import ErrorBody
from roadgraph.cli import info_dict, parse_bbox
from roadgraph.geojson import feature_collection
from roadgraph.store import read_edges_in_bbox

router = APIRouter(prefix="/maps", tags=["maps"], responses={404: {"model": ErrorBody}})

MAX_BBOX_EDGES = 50_000


def _map(state: AppState, map_id: str) -> dict[str, Any]:
    if map_id != state.graph.map_id:
        raise HTTPException(404, f"no map {map_id!r}; this server has {state.graph.map_id!r}")
    return info_dict(state.graph.info, state.settings.map_path)


@router.get("")
def list_maps(state: StateDep, _owner: OwnerDep) -> dict[str, list[dict[str, Any]]]:
    """The maps this server matches on (one per server)."""
    return {"maps": [_map(state, state.graph.map_id)]}


@router.get("/{map_id}")
def get_map(map_id: str, state: StateDep, _owner: OwnerDep) -> dict[str, Any]:
    """Node and edge counts, bounding box, CRS, longest edge, max adjacent-node distance."""
    return _map(state, map_id)


@router.get("/{map_id}/edges", responses={422: {"model": ErrorBody}})
def get_edges(map_id: str, state: StateDep, _owner: OwnerDep,
              bbox: str = Query(description="W,S,E,N in WGS84 degrees",
                                examples=["7.42,43.73,7.43,43.74"])) -> dict[str, Any]:
    """Edges meeting a bounding box, as a GeoJSON FeatureCollection (R*Tree query)."""
    _map(state, map_id)
    try:
        box = parse_bbox(bbox)
    except ValueError as exc:
        raise HTTPException(422, str(exc)) from exc
    edges = read_edges_in_bbox(state.settings.map_path, box)
    if len(edges) > MAX_BBOX_EDGES:
        raise HTTPException(413, f"{len(edges)} edges in that box; at most {MAX_BBOX_EDGES}: "
                                 "ask for a smaller one")
    return feature_collection(edges)
