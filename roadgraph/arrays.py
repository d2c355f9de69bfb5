"""The compact arrays a road graph is queried through (pure).

A map of two million edges held as Python records (one :class:`EdgeRecord` and two small
NumPy arrays an edge) would take several gigabytes and minutes to load; as flat arrays it
takes about 600 MB (300 bytes an edge) and opens in one to two seconds
(``bench/roadgraph_bench.py --scaling``). :class:`GraphArrays` holds what the queries of
:class:`roadgraph.RoadGraph` need, and nothing a user reads only now and then (names, tags,
WGS84 geometry: those stay in the database's rows):

- nodes sorted by id: ``node_id``, ``node_xy`` (local metres), ``node_lonlat``,
  ``node_degree``, and the OSM nodes merged into each (``node_osm`` in rows ``node_osm_start``);
- edges sorted by ``(u, v, key)``: ``edge_u``, ``edge_v`` (node indices), ``edge_key``,
  ``edge_length_m``, ``edge_bearing_rad`` (leaving u, arriving at v), and their vertices
  (``coords`` in rows ``coord_start``);
- compressed rows for the topology: edges leaving a node (``out_start``: the edges are sorted
  by u), arriving at a node (``in_edges`` in rows ``in_start``), and each node's successors by
  the shortest parallel edge (``succ_target``, ``succ_length_m`` in rows ``out_start``-like
  ``succ_start``), which the route search runs over;
- the spatial grid over the edges' segments (:mod:`roadgraph.spatial`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields

import numpy as np

from roadgraph.build import EdgeRecord, NodeRecord
from roadgraph.geometry import FloatArray
from roadgraph.spatial import GridArrays, IndexArray, IntArray, build_grid


@dataclass(frozen=True, eq=False)
class GraphArrays:
    """A road graph as flat arrays (see the module docstring for each one)."""

    node_id: IntArray
    node_xy: FloatArray
    node_lonlat: FloatArray
    node_degree: IntArray
    node_osm_start: IntArray
    node_osm: IntArray
    edge_u: IntArray
    edge_v: IntArray
    edge_key: IntArray
    edge_length_m: FloatArray
    edge_bearing_rad: FloatArray
    coord_start: IntArray
    coords: FloatArray
    out_start: IntArray
    in_start: IntArray
    in_edges: IntArray
    succ_start: IntArray
    succ_target: IntArray
    succ_length_m: FloatArray
    grid_cell_m: float
    grid_keys: IntArray
    grid_start: IntArray
    grid_segments: IndexArray

    @property
    def grid(self) -> GridArrays:
        return GridArrays(self.grid_cell_m, self.grid_keys, self.grid_start, self.grid_segments)

    def as_dict(self) -> dict[str, np.ndarray | float]:
        """The arrays by name (what the store writes)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in self.as_dict().values() if isinstance(a, np.ndarray))


def array_names() -> list[str]:
    """The names of the arrays, in order (the store reads these back)."""
    return [f.name for f in fields(GraphArrays) if f.name != "grid_cell_m"]


def build_arrays(
    node_id: IntArray, node_xy: FloatArray, node_lonlat: FloatArray, node_degree: IntArray,
    node_osm_start: IntArray, node_osm: IntArray, edge_u_id: IntArray, edge_v_id: IntArray,
    edge_key: IntArray, edge_length_m: FloatArray, edge_bearing_rad: FloatArray,
    coord_start: IntArray, coords: FloatArray,
) -> GraphArrays:
    """The arrays of a graph, from its nodes (sorted by id) and edges (sorted by
    ``(u, v, key)``, u and v as node ids); adds the compressed rows and the grid."""
    n = len(node_id)
    u = np.searchsorted(node_id, edge_u_id).astype(np.int64)
    v = np.searchsorted(node_id, edge_v_id).astype(np.int64)
    if len(u) and (np.any(node_id[np.minimum(u, n - 1)] != edge_u_id)
                   or np.any(node_id[np.minimum(v, n - 1)] != edge_v_id)):
        raise ValueError("an edge names a node that is not in the graph")
    if len(u) > 1 and np.any(np.diff(u * (n + 1) + v) < 0):
        raise ValueError("edges must be sorted by (u, v, key)")
    out_start = np.searchsorted(u, np.arange(n + 1)).astype(np.int64)
    in_edges = np.argsort(v, kind="stable").astype(np.int64)
    in_start = np.searchsorted(v[in_edges], np.arange(n + 1)).astype(np.int64)
    succ_start, succ_target, succ_length = _successor_rows(u, v, edge_length_m, n)
    grid = build_grid(coords, coord_start)
    return GraphArrays(
        node_id=node_id, node_xy=node_xy, node_lonlat=node_lonlat, node_degree=node_degree,
        node_osm_start=node_osm_start, node_osm=node_osm, edge_u=u, edge_v=v,
        edge_key=edge_key.astype(np.int64), edge_length_m=edge_length_m,
        edge_bearing_rad=edge_bearing_rad, coord_start=coord_start, coords=coords,
        out_start=out_start, in_start=in_start, in_edges=in_edges, succ_start=succ_start,
        succ_target=succ_target, succ_length_m=succ_length, grid_cell_m=grid.cell_m,
        grid_keys=grid.keys, grid_start=grid.start, grid_segments=grid.segments,
    )


def _successor_rows(u: IntArray, v: IntArray, length: FloatArray, n: int
                    ) -> tuple[IntArray, IntArray, FloatArray]:
    """Each node's successors by the shortest parallel edge, in compressed rows: node
    ``i``'s are ``target[start[i]:start[i + 1]]`` at ``length[...]`` (node indices)."""
    pair = u * (n + 1) + v  # edges are sorted by (u, v): equal pairs are adjacent
    first = np.ones(len(pair), dtype=bool)
    first[1:] = pair[1:] != pair[:-1]
    group = np.cumsum(first) - 1
    shortest = np.full(int(first.sum()), np.inf)
    np.minimum.at(shortest, group, length)
    su, sv = u[first], v[first]
    start = np.searchsorted(su, np.arange(n + 1)).astype(np.int64)
    return start, sv.astype(np.int64), shortest


def arrays_from_records(nodes: Sequence[NodeRecord], edges: Sequence[EdgeRecord]
                        ) -> GraphArrays:
    """The arrays of node and edge records (tests, small maps, the osmnx builder)."""
    nodes = sorted(nodes, key=lambda r: r.id)
    edges = sorted(edges, key=lambda e: (e.u, e.v, e.key))
    coords = np.vstack([e.coords for e in edges]) if edges else np.empty((0, 2))
    return build_arrays(
        node_id=np.array([r.id for r in nodes], dtype=np.int64),
        node_xy=np.array([(r.x_m, r.y_m) for r in nodes], dtype=np.float64).reshape(-1, 2),
        node_lonlat=np.array([(r.lon_deg, r.lat_deg) for r in nodes],
                             dtype=np.float64).reshape(-1, 2),
        node_degree=np.array([r.degree for r in nodes], dtype=np.int64),
        node_osm_start=np.cumsum([0, *(len(r.osm_ids) for r in nodes)]).astype(np.int64),
        node_osm=np.array([i for r in nodes for i in r.osm_ids], dtype=np.int64),
        edge_u_id=np.array([e.u for e in edges], dtype=np.int64),
        edge_v_id=np.array([e.v for e in edges], dtype=np.int64),
        edge_key=np.array([e.key for e in edges], dtype=np.int64),
        edge_length_m=np.array([e.length_m for e in edges], dtype=np.float64),
        edge_bearing_rad=np.array([(e.bearing_start_rad, e.bearing_end_rad) for e in edges],
                                  dtype=np.float64).reshape(-1, 2),
        coord_start=np.cumsum([0, *(len(e.coords) for e in edges)]).astype(np.int64),
        coords=np.ascontiguousarray(coords, dtype=np.float64),
    )


@dataclass(frozen=True, eq=False)
class EdgeAttributes:
    """What the database's edge rows hold beyond :class:`GraphArrays`, edge by edge in the
    arrays' order: OSM ways, tags, and the vertices in WGS84 (rows ``coord_start``)."""

    osm_way_ids: list[tuple[int, ...]]
    name: list[str | None]
    highway: list[str]
    oneway: list[bool]
    maxspeed: list[str | None]
    lanes: list[int | None]
    tunnel: list[bool]
    bridge: list[bool]
    lonlat: FloatArray


def attributes_from_records(edges: Sequence[EdgeRecord]) -> EdgeAttributes:
    """The attributes of edge records, sorted by ``(u, v, key)`` as the arrays are."""
    edges = sorted(edges, key=lambda e: (e.u, e.v, e.key))
    return EdgeAttributes(
        osm_way_ids=[e.osm_way_ids for e in edges], name=[e.name for e in edges],
        highway=[e.highway for e in edges], oneway=[e.oneway for e in edges],
        maxspeed=[e.maxspeed for e in edges], lanes=[e.lanes for e in edges],
        tunnel=[e.tunnel for e in edges], bridge=[e.bridge for e in edges],
        lonlat=np.vstack([e.lonlat for e in edges]) if edges else np.empty((0, 2)),
    )
