"""From osmnx's raw road graph to the intersection graph the matcher uses (pure: no I/O).

Seed: Mayhew 1999, section 5.7: the map is a mesh of intersection nodes, each linked to every
adjacent intersection by a road. Here osmnx simplifies the raw OSM graph so that nodes are
intersections and dead ends, projects it to the UTM zone of the map's centre, and consolidates
the several OSM nodes of one complex junction (dual carriageways, roundabout entries) that lie
within ``consolidate_m`` of each other into a single node. A ring that meets no other road (a
closed way alone, osmnx would drop it) keeps one of its nodes as a node, with a self-loop edge.

The result is a :class:`RoadNetwork`: plain records (nodes, edges with full geometry in both the
local frame and WGS84, and a :class:`MapInfo` summary) that the store writes and reads.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from importlib.metadata import version
from typing import Any

import networkx as nx
import numpy as np
import shapely
from pyproj import CRS

from roadgraph.errors import NoDrivableRoadError
from roadgraph.geometry import (
    FloatArray,
    LocalFrame,
    end_bearings_rad,
    polyline_length_m,
    utm_crs_for,
)

# The smallest tolerance that removes every junction stub (<15 m between two degree>=3 nodes)
# on the sample map while merging fewest separate intersections: see bench/consolidation.py.
DEFAULT_CONSOLIDATE_M = 8.0


@dataclass(frozen=True)
class NodeRecord:
    """One intersection or dead end."""

    id: int
    osm_ids: tuple[int, ...]  # the OSM nodes consolidated into this one
    lon_deg: float
    lat_deg: float
    x_m: float
    y_m: float
    degree: int  # number of distinct adjacent nodes (roads meeting here, either direction)


@dataclass(frozen=True, eq=False)
class EdgeRecord:
    """One directed road segment between two nodes (a two-way road is two records)."""

    u: int
    v: int
    key: int
    osm_way_ids: tuple[int, ...]
    name: str | None
    highway: str
    oneway: bool
    maxspeed: str | None  # the OSM tag as written ("50", "30 mph"), when present
    lanes: int | None
    tunnel: bool
    bridge: bool
    length_m: float
    bearing_start_rad: float  # leaving u
    bearing_end_rad: float  # arriving at v
    coords: FloatArray = field(repr=False)  # (n, 2) local metres, from u to v
    lonlat: FloatArray = field(repr=False)  # (n, 2) WGS84 degrees, from u to v

    def same_as(self, other: EdgeRecord, tol_m: float = 1e-6) -> bool:
        """Field-by-field equality, with coordinates compared within a tolerance."""
        scalars = [f for f in self.__dataclass_fields__ if f not in ("coords", "lonlat")]
        return all(
            _close(getattr(self, f), getattr(other, f), tol_m) for f in scalars
        ) and np.allclose(self.coords, other.coords, atol=tol_m, rtol=0) and np.allclose(
            self.lonlat, other.lonlat, atol=1e-9, rtol=0
        )


def _close(a: Any, b: Any, tol: float) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return math.isclose(a, b, abs_tol=tol)
    return bool(a == b)


@dataclass(frozen=True)
class MapInfo:
    """What a road-graph database holds, in brief (``roadgraph info``)."""

    crs_wkt: str
    epsg: int | None
    bbox_wgs84: tuple[float, float, float, float]  # west, south, east, north
    node_count: int
    edge_count: int
    total_length_m: float
    longest_edge_m: float
    # Longest straight-line distance between two adjacent intersections: the seed's ambiguity
    # radius is the expected drift rate times this.
    max_adjacent_node_distance_m: float
    network: str
    consolidate_m: float
    source_name: str = ""
    source_sha256: str = ""
    osmnx_version: str = field(default_factory=lambda: version("osmnx"))
    created_utc: str = ""
    # The import summary. None: not recorded (databases written before these fields, or a
    # source they do not apply to, such as a .graphml graph or a download).
    road_length_m: float | None = None  # two-way roads counted once
    junction_count: int | None = None  # nodes where three or more roads meet
    dead_end_count: int | None = None  # nodes with one road
    junction_nodes_merged: int | None = None  # intersection nodes merged by consolidation
    osm_ways_kept: int | None = None  # ways of the network in the map, whole or cut
    osm_ways_cut: int | None = None  # cut at the extract's edge (node references missing)
    osm_ways_dropped_outside: int | None = None  # fewer than two of their nodes in the file
    osm_ways_dropped_one_node: int | None = None  # ways of a single node
    osm_ways_not_in_network: int | None = None  # highway ways not for cars (footway, ...)
    osm_missing_node_refs: int | None = None  # references to nodes missing from the file
    osm_negative_ids: int | None = None  # nodes and ways with JOSM's negative (new) ids
    osm_josm_deleted: int | None = None  # objects a JOSM file marks deleted, left out
    osm_invalid_locations: int | None = None  # road nodes off the globe, taken as missing


@dataclass(frozen=True)
class RoadNetwork:
    """A whole map as records: what the store writes and reads back."""

    info: MapInfo
    nodes: tuple[NodeRecord, ...]
    edges: tuple[EdgeRecord, ...]


def build_network(
    raw: nx.MultiDiGraph, *, consolidate_m: float = DEFAULT_CONSOLIDATE_M, network: str = "drive",
    source: str = "the source",
) -> RoadNetwork:
    """Simplify, project and consolidate osmnx's raw WGS84 graph into a :class:`RoadNetwork`."""
    import osmnx as ox  # imports take 1.3 s (matplotlib, geopandas): only an import needs it

    if consolidate_m < 0.0 or not math.isfinite(consolidate_m):
        raise ValueError(f"consolidate_m must be a finite number >= 0, got {consolidate_m}")
    if raw.number_of_edges() == 0:
        raise NoDrivableRoadError(f"{source}: no drivable road")
    graph = raw if raw.graph.get("simplified") else _simplify(raw)
    lon, lat = _centre_lonlat(graph)
    frame = LocalFrame(utm_crs_for(lon, lat).to_wkt())
    graph = ox.project_graph(graph, to_crs=frame.crs_wkt)
    simplified_nodes = graph.number_of_nodes()
    if consolidate_m > 0.0:
        graph = ox.consolidate_intersections(
            graph, tolerance=consolidate_m, rebuild_graph=True, dead_ends=True,
            reconnect_edges=True,
        )
        if graph.number_of_edges() == 0:
            raise NoDrivableRoadError(
                f"{source}: no road left after merging the nodes within {consolidate_m:g} m of "
                "each other: every road is shorter than that; import with --consolidate-m 0")
    net = network_from_projected(graph, frame, network=network, consolidate_m=consolidate_m,
                                 source=source)
    merged = simplified_nodes - len(net.nodes)
    return dataclasses.replace(net, info=dataclasses.replace(net.info,
                                                             junction_nodes_merged=merged))


_RING_ANCHOR = "roadgraph_ring_anchor"


def _simplify(raw: nx.MultiDiGraph) -> nx.MultiDiGraph:
    """osmnx's simplification, keeping rings that meet no other road (osmnx drops them)."""
    import osmnx as ox

    raw = raw.copy()
    for component in nx.weakly_connected_components(raw):
        if not any(_is_endpoint(raw, n) for n in component):
            raw.nodes[min(component)][_RING_ANCHOR] = True
    graph: nx.MultiDiGraph = ox.simplify_graph(raw, node_attrs_include=[_RING_ANCHOR])
    for _, data in graph.nodes(data=True):
        data.pop(_RING_ANCHOR, None)
    return graph


def _is_endpoint(graph: nx.MultiDiGraph, node: int) -> bool:
    """osmnx's strict endpoint rules 1-3 (``osmnx.simplification._is_endpoint``)."""
    neighbours = set(graph.predecessors(node)) | set(graph.successors(node))
    if node in neighbours or graph.out_degree(node) == 0 or graph.in_degree(node) == 0:
        return True
    return not (len(neighbours) == 2 and graph.degree(node) in (2, 4))


def network_from_projected(
    graph: nx.MultiDiGraph, frame: LocalFrame, *, network: str = "drive",
    consolidate_m: float = 0.0, source: str = "the source",
) -> RoadNetwork:
    """Records from a MultiDiGraph already in the frame's metres.

    Nodes need ``x``, ``y``; edges may carry ``geometry`` (shapely LineString, interior
    vertices), ``osmid``, ``name``, ``highway``, ``oneway``, ``maxspeed``, ``lanes``.
    """
    nodes = _node_records(graph, frame)
    edges = _edge_records(graph, frame)
    info = summarize(nodes, edges, frame, network=network, consolidate_m=consolidate_m,
                     source=source)
    return RoadNetwork(info=info, nodes=nodes, edges=edges)


def _centre_lonlat(graph: nx.MultiDiGraph) -> tuple[float, float]:
    xs = [d["x"] for _, d in graph.nodes(data=True)]
    ys = [d["y"] for _, d in graph.nodes(data=True)]
    return (min(xs) + max(xs)) / 2.0, (min(ys) + max(ys)) / 2.0


def _node_records(graph: nx.MultiDiGraph, frame: LocalFrame) -> tuple[NodeRecord, ...]:
    undirected = nx.Graph(graph.to_undirected(as_view=True))
    records = []
    for node_id, data in graph.nodes(data=True):
        osm = data.get("osmid_original", data.get("osmid", node_id))
        lon, lat = frame.to_wgs84(data["x"], data["y"])
        neighbours = set(undirected.neighbors(node_id)) - {node_id}
        records.append(NodeRecord(
            id=int(node_id), osm_ids=tuple(int(i) for i in _as_list(osm)),
            lon_deg=lon, lat_deg=lat, x_m=float(data["x"]), y_m=float(data["y"]),
            degree=len(neighbours),
        ))
    return tuple(sorted(records, key=lambda n: n.id))


def _edge_records(graph: nx.MultiDiGraph, frame: LocalFrame) -> tuple[EdgeRecord, ...]:
    records = []
    for u, v, key, data in graph.edges(keys=True, data=True):
        coords = _edge_coords(graph, u, v, data)
        start, end = end_bearings_rad(coords)
        names = _as_list(data.get("name"))
        records.append(EdgeRecord(
            u=int(u), v=int(v), key=int(key),
            osm_way_ids=tuple(dict.fromkeys(int(i) for i in _as_list(data.get("osmid")))),
            name="; ".join(dict.fromkeys(str(n) for n in names)) or None,
            highway=str((_as_list(data.get("highway")) or ["road"])[0]),
            oneway=bool(data.get("oneway", False)),
            maxspeed=_first_str(data.get("maxspeed")),
            lanes=_max_int(data.get("lanes")),
            tunnel=_tag_yes(data.get("tunnel")), bridge=_tag_yes(data.get("bridge")),
            length_m=polyline_length_m(coords),
            bearing_start_rad=start, bearing_end_rad=end,
            coords=coords, lonlat=frame.coords_to_wgs84(coords),
        ))
    return tuple(sorted(records, key=lambda e: (e.u, e.v, e.key)))


def _edge_coords(graph: nx.MultiDiGraph, u: int, v: int, data: dict[str, Any]) -> FloatArray:
    """The edge's polyline from u to v, ending exactly on both nodes' positions."""
    pu = (graph.nodes[u]["x"], graph.nodes[u]["y"])
    pv = (graph.nodes[v]["x"], graph.nodes[v]["y"])
    geom = data.get("geometry")
    inner = np.asarray(shapely.get_coordinates(geom), dtype=np.float64) if geom is not None \
        else np.empty((0, 2))
    coords = np.vstack([pu, inner, pv]) if len(inner) else np.array([pu, pv], dtype=np.float64)
    keep = np.concatenate([[True], np.any(np.abs(np.diff(coords, axis=0)) > 1e-6, axis=1)])
    coords = coords[keep]
    if len(coords) == 1:  # a self-loop reduced to one point
        coords = np.vstack([coords, coords])
    return coords


def summarize(
    nodes: tuple[NodeRecord, ...], edges: tuple[EdgeRecord, ...], frame: LocalFrame, *,
    network: str, consolidate_m: float, source: str = "the source",
) -> MapInfo:
    """The :class:`MapInfo` of a set of nodes and edges."""
    if not edges:
        raise NoDrivableRoadError(f"{source}: no drivable road")
    lonlat = np.vstack([e.lonlat for e in edges])
    by_id = {n.id: n for n in nodes}
    adjacent = [
        math.hypot(by_id[e.u].x_m - by_id[e.v].x_m, by_id[e.u].y_m - by_id[e.v].y_m)
        for e in edges
    ]
    epsg = _epsg_of(frame)
    return MapInfo(
        crs_wkt=frame.crs_wkt, epsg=epsg,
        bbox_wgs84=(float(lonlat[:, 0].min()), float(lonlat[:, 1].min()),
                    float(lonlat[:, 0].max()), float(lonlat[:, 1].max())),
        node_count=len(nodes), edge_count=len(edges),
        total_length_m=float(sum(e.length_m for e in edges)),
        longest_edge_m=float(max(e.length_m for e in edges)),
        max_adjacent_node_distance_m=float(max(adjacent)),
        network=network, consolidate_m=consolidate_m,
        road_length_m=float(sum(e.length_m * (1.0 if e.oneway else 0.5) for e in edges)),
        junction_count=sum(1 for n in nodes if n.degree >= 3),
        dead_end_count=sum(1 for n in nodes if n.degree == 1),
    )


def _epsg_of(frame: LocalFrame) -> int | None:
    epsg: int | None = CRS.from_wkt(frame.crs_wkt).to_epsg()
    return epsg


def _as_list(value: Any) -> list[Any]:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return []
    if isinstance(value, (list, tuple, set)):
        return list(value)
    return [value]


def _first_str(value: Any) -> str | None:
    items = _as_list(value)
    return str(items[0]) if items else None


def _max_int(value: Any) -> int | None:
    numbers = [int(float(s)) for s in _iter_numbers(_as_list(value))]
    return max(numbers) if numbers else None


def _iter_numbers(items: Iterable[Any]) -> Iterable[str]:
    for item in items:
        for part in str(item).replace(";", " ").split():
            try:
                float(part)
            except ValueError:
                continue
            yield part


def _tag_yes(value: Any) -> bool:
    return any(str(v) not in ("no", "false", "0", "") for v in _as_list(value))
