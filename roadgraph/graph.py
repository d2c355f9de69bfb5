"""RoadGraph: the read side of a map, the queries the matcher needs.

Opened once from a road-graph database (:func:`RoadGraph.open`): its compact arrays
(:mod:`roadgraph.arrays`) are held in memory, an edge's full record is read from the database
when asked for. Its queries are pure and safe to share between threads. Nearest-edge queries
use a packed uniform grid over the edges' segments (:mod:`roadgraph.spatial`); distances and
projections are exact.

Seed: Mayhew 1999, section 5.7 (the intersection mesh and the perpendicular-distance search).
"""

from __future__ import annotations

import functools
import heapq
import math
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import NamedTuple, TypeVar, overload

import networkx as nx
import numba
import numpy as np

from roadgraph.arrays import GraphArrays, arrays_from_records
from roadgraph.build import EdgeRecord, MapInfo, NodeRecord, RoadNetwork, network_from_projected
from roadgraph.errors import RoadGraphError
from roadgraph.geometry import FloatArray, LocalFrame, project_onto_polyline, turn_angle_rad
from roadgraph.spatial import IntArray, NearPolylines, SegmentGrid
from roadgraph.store import EdgeRows, read_arrays, read_network, schema_version

_R = TypeVar("_R")


class EdgeKey(NamedTuple):
    """A directed edge: from node ``u`` to node ``v``, parallel index ``key``."""

    u: int
    v: int
    key: int


class EdgeProjection(NamedTuple):
    """A point projected onto an edge (a named tuple: the matchers make thousands a second)."""

    edge: EdgeKey
    offset_m: float  # along the edge from u
    distance_m: float  # from the point to the edge
    x_m: float  # the projected point
    y_m: float
    bearing_rad: float  # road direction (u → v) at the projected point
    length_m: float  # the edge's length

    @property
    def remaining_m(self) -> float:
        """Distance along the edge from the projected point to ``v``."""
        return max(self.length_m - self.offset_m, 0.0)


class RoadGraph:
    """An intersection graph on compact arrays, with spatial and routing queries.

    Opened from a database, it holds only :class:`GraphArrays` (positions, topology, the
    spatial grid); an edge's full record (names, tags, WGS84 geometry) is read from the
    database when asked for, and the last 65,536 are kept. Built from records (tests,
    :meth:`from_networkx`), it keeps those records.
    """

    def __init__(self, network: RoadNetwork | None = None, map_id: str = "", *,
                 arrays: GraphArrays | None = None, info: MapInfo | None = None,
                 db: Path | None = None) -> None:
        self.map_id = map_id
        if network is not None:
            self.info: MapInfo = network.info
            self._records: tuple[EdgeRecord, ...] | None = tuple(
                sorted(network.edges, key=lambda e: (e.u, e.v, e.key)))
            self._a = arrays_from_records(network.nodes, self._records)
        elif arrays is not None and info is not None and db is not None:
            self.info, self._a, self._records = info, arrays, None
        else:
            raise TypeError("RoadGraph needs a network, or arrays, info and a database")
        self._db = db
        self._rows = EdgeRows(db) if db is not None else None
        self.frame = LocalFrame(self.info.crs_wkt)
        a = self._a
        self._grid = SegmentGrid(a.coords, a.coord_start, a.grid)
        self._edge_at = functools.lru_cache(maxsize=1 << 16)(self._load_edge)

    @classmethod
    def open(cls, path: Path | str) -> RoadGraph:
        """Open a road-graph database written by ``roadgraph import`` (its arrays only)."""
        path = Path(path)
        if schema_version(path) < 2:  # written before the arrays: from its rows, in memory
            return cls(read_network(path), map_id=path.stem)
        info, arrays = read_arrays(path)
        return cls(map_id=path.stem, arrays=arrays, info=info, db=path)

    @classmethod
    def from_networkx(cls, graph: nx.MultiDiGraph, frame: LocalFrame) -> RoadGraph:
        """A RoadGraph from a hand-built graph in the frame's metres (tests, synthetic maps)."""
        return cls(network_from_projected(graph, frame), map_id=graph.graph.get("name", ""))

    def to_networkx(self) -> nx.MultiDiGraph:
        """The whole graph as a networkx MultiDiGraph (nodes with ``x``, ``y``, ``lon``,
        ``lat``; edges with ``length``): for users' own analyses. Built on each call, and
        large for a big map (about 1 kB an edge)."""
        a = self._a
        graph = nx.MultiDiGraph(crs=self.info.crs_wkt)
        ids = a.node_id.tolist()
        graph.add_nodes_from(
            (n, {"x": x, "y": y, "lon": lon, "lat": lat})
            for n, (x, y), (lon, lat) in zip(ids, a.node_xy.tolist(), a.node_lonlat.tolist()))
        graph.add_edges_from(
            (ids[u], ids[v], k, {"length": length}) for u, v, k, length in zip(
                a.edge_u.tolist(), a.edge_v.tolist(), a.edge_key.tolist(),
                a.edge_length_m.tolist()))
        return graph

    @functools.cached_property
    def graph(self) -> nx.MultiDiGraph:
        """:meth:`to_networkx`, built once on first use (kept for the callers that read it)."""
        return self.to_networkx()

    @property
    def arrays(self) -> GraphArrays:
        return self._a

    # --- records -------------------------------------------------------------------------
    @property
    def nodes(self) -> _Records[NodeRecord]:
        """Every node, by id (a sequence made on demand, not held)."""
        return _Records(len(self._a.node_id), self._node_at)

    @property
    def edges(self) -> _Records[EdgeRecord]:
        """Every edge, by ``(u, v, key)`` (a sequence made on demand, not held)."""
        return _Records(len(self._a.edge_u), self._edge_at)

    def node(self, node_id: int) -> NodeRecord:
        return self._node_at(self._node_index(node_id))

    def edge(self, edge: EdgeKey) -> EdgeRecord:
        return self._edge_at(self._edge_index(edge))

    def has_edge(self, edge: EdgeKey) -> bool:
        return _find_edge(*self._edge_args(edge)) >= 0

    def _node_index(self, node_id: int) -> int:
        i = _find_node(node_id, self._a.node_id)
        if i < 0:
            raise KeyError(node_id)
        return i

    def _edge_args(self, edge: EdgeKey) -> tuple[int, int, int, IntArray, IntArray, IntArray,
                                                 IntArray]:
        a = self._a
        return edge[0], edge[1], edge[2], a.node_id, a.out_start, a.edge_v, a.edge_key

    def _edge_index(self, edge: EdgeKey) -> int:
        i = _find_edge(*self._edge_args(edge))
        if i < 0:
            raise KeyError(edge)
        return i

    def _node_at(self, i: int) -> NodeRecord:
        a = self._a
        x, y = a.node_xy[i].tolist()
        lon, lat = a.node_lonlat[i].tolist()
        osm = a.node_osm[a.node_osm_start[i]:a.node_osm_start[i + 1]]
        return NodeRecord(id=int(a.node_id[i]), osm_ids=tuple(osm.tolist()), lon_deg=lon,
                          lat_deg=lat, x_m=x, y_m=y, degree=int(a.node_degree[i]))

    def _load_edge(self, i: int) -> EdgeRecord:
        if self._records is not None:
            return self._records[i]
        assert self._rows is not None
        return self._rows.edge(i)

    def _key_at(self, i: int) -> EdgeKey:
        a = self._a
        return EdgeKey(int(a.node_id[a.edge_u[i]]), int(a.node_id[a.edge_v[i]]),
                       int(a.edge_key[i]))

    # --- spatial -------------------------------------------------------------------------
    def edges_near(self, x_m: float, y_m: float, radius_m: float,
                   limit: int | None = None) -> list[EdgeProjection]:
        """The point projected onto each edge within ``radius_m`` of it, nearest first; the
        ``limit`` nearest when given."""
        return self._projections(self._grid.near(x_m, y_m, radius_m,
                                                 -1 if limit is None else limit))

    def nearest_edge(self, x_m: float, y_m: float) -> EdgeProjection:
        """The point projected onto the nearest edge, however far (start-up when nothing is
        within a radius)."""
        found = self._projections(self._grid.nearest(x_m, y_m))
        if not found:
            raise RoadGraphError(f"no edge near ({x_m}, {y_m}): the graph is empty or the point "
                                 "is outside what the map's projection can hold")
        return found[0]

    def distance_to_road_m(self, x_m: float, y_m: float, heading_rad: float,
                           radius_m: float, max_bearing_diff_rad: float) -> float:
        """Distance from the point to the nearest road running along ``heading_rad`` (either
        way, within ``max_bearing_diff_rad``); ``radius_m`` when none is that near. How well
        a position and heading fit the map (the fusion's test of two GPS tracks)."""
        near = self._grid.near(x_m, y_m, radius_m)
        for distance, _offset, _x, _y, bearing in near.closest:  # nearest first
            diff = abs(math.remainder(bearing - heading_rad, math.pi))
            if diff <= max_bearing_diff_rad:
                return min(distance, radius_m)
        return radius_m

    def _projections(self, near: NearPolylines) -> list[EdgeProjection]:
        length = self._a.edge_length_m
        return [EdgeProjection(self._key_at(i), offset, distance, x, y, bearing,
                               float(length[i]))
                for i, (distance, offset, x, y, bearing) in zip(near.polylines, near.closest)]

    def coords(self, edge: EdgeKey) -> FloatArray:
        """An edge's vertices in local metres, from u to v (a view: do not write to it)."""
        i = self._edge_index(edge)
        start = self._a.coord_start
        return self._a.coords[start[i]:start[i + 1]]

    def project(self, edge: EdgeKey, x_m: float, y_m: float) -> EdgeProjection:
        """Project a point onto an edge."""
        i = self._edge_index(edge)
        start = self._a.coord_start
        p = project_onto_polyline(self._a.coords[start[i]:start[i + 1]], x_m, y_m)
        return EdgeProjection(edge=edge, offset_m=p.offset_m, distance_m=p.distance_m,
                              x_m=p.x_m, y_m=p.y_m, bearing_rad=p.bearing_rad,
                              length_m=float(self._a.edge_length_m[i]))

    # --- topology ------------------------------------------------------------------------
    def out_edges(self, node_id: int) -> list[EdgeRecord]:
        """Edges leaving a node (each with its ``bearing_start_rad``)."""
        i = self._node_index(node_id)
        start = self._a.out_start
        return [self._edge_at(k) for k in range(int(start[i]), int(start[i + 1]))]

    def in_edges(self, node_id: int) -> list[EdgeRecord]:
        """Edges arriving at a node (each with its ``bearing_end_rad``)."""
        i = self._node_index(node_id)
        start = self._a.in_start
        return [self._edge_at(k) for k in self._a.in_edges[start[i]:start[i + 1]].tolist()]

    def turn_angle_rad(self, edge_in: EdgeKey, edge_out: EdgeKey) -> float:
        """Turn from one edge into the next at their shared node: positive right, negative left."""
        if edge_in[1] != edge_out[0]:
            raise RoadGraphError(f"edges {edge_in} and {edge_out} do not meet")
        bearing = self._a.edge_bearing_rad
        return turn_angle_rad(float(bearing[self._edge_index(edge_in), 1]),
                              float(bearing[self._edge_index(edge_out), 0]))

    def shortest_path(self, source: int, target: int) -> list[EdgeKey]:
        """The shortest route by length from one node to another, as edges; [] when equal.

        Raises :class:`networkx.NetworkXNoPath` when the target cannot be reached.
        """
        a = self._a
        s, t = self._node_index(source), self._node_index(target)
        nodes = _shortest_path(s, t, a.succ_start, a.succ_target, a.succ_length_m)
        if nodes.size == 0:
            raise nx.NetworkXNoPath(f"Node {target} not reachable from {source}")
        return [self._shortest_parallel(u, v) for u, v in zip(nodes[:-1].tolist(),
                                                              nodes[1:].tolist())]

    def distances_from(self, source: int, cutoff_m: float) -> dict[int, float]:
        """Driving distance from ``source`` to every node within ``cutoff_m`` (Dijkstra).

        Compiled over compressed successor rows: the offline matcher runs one per candidate
        source node, and networkx's general version cost three times a plain Python heap
        search, which in turn cost five times this.
        """
        a = self._a
        nodes, distances = _distances_from(self._node_index(source), cutoff_m, a.succ_start,
                                           a.succ_target, a.succ_length_m)
        return dict(zip(a.node_id[nodes].tolist(), distances.tolist()))

    def _shortest_parallel(self, u: int, v: int) -> EdgeKey:
        """The shortest of the edges from node index u to node index v (the first of equals)."""
        a = self._a
        lo, hi = int(a.out_start[u]), int(a.out_start[u + 1])
        ks = [k for k in range(lo, hi) if a.edge_v[k] == v]
        best = min(ks, key=lambda k: (a.edge_length_m[k], k))
        return self._key_at(best)


class _Records(Sequence[_R]):
    """A read-only sequence whose items are made when read."""

    def __init__(self, size: int, item: Callable[[int], _R]) -> None:
        self._size, self._item = size, item

    def __len__(self) -> int:
        return self._size

    @overload
    def __getitem__(self, i: int) -> _R: ...

    @overload
    def __getitem__(self, i: slice) -> list[_R]: ...

    def __getitem__(self, i: int | slice) -> _R | list[_R]:
        if isinstance(i, slice):
            return [self._item(k) for k in range(*i.indices(self._size))]
        if i < 0:
            i += self._size
        if not 0 <= i < self._size:
            raise IndexError(i)
        return self._item(i)

    def __iter__(self) -> Iterator[_R]:
        return (self._item(k) for k in range(self._size))


@numba.njit(cache=True, nogil=True)
def _find_node(node_id: int, ids: IntArray) -> int:  # pragma: no cover - compiled
    i = int(np.searchsorted(ids, node_id))
    return i if i < ids.size and ids[i] == node_id else -1


@numba.njit(cache=True, nogil=True)
def _find_edge(u: int, v: int, key: int, ids: IntArray, out_start: IntArray, edge_v: IntArray,
               edge_key: IntArray) -> int:  # pragma: no cover - compiled
    """The index of edge (u, v, key) by node ids, or -1."""
    i = _find_node(u, ids)
    j = _find_node(v, ids)
    if i < 0 or j < 0:
        return -1
    for k in range(out_start[i], out_start[i + 1]):
        if edge_v[k] == j and edge_key[k] == key:
            return k
    return -1


@numba.njit(cache=True, nogil=True)
def _shortest_path(source: int, target: int, start: IntArray, succ: IntArray,
                   length: FloatArray) -> IntArray:  # pragma: no cover - compiled
    """Dijkstra from node index ``source`` until ``target``: the nodes of the path, or an
    empty array when it cannot be reached."""
    if source == target:
        return np.array([source], dtype=np.int64)
    prev = {source: -1}
    done = {source: 0.0}
    done.clear()
    best = {source: 0.0}
    heap = [(0.0, source, -1)]
    while heap:
        d, u, p = heapq.heappop(heap)
        if u in done:
            continue
        done[u] = d
        prev[u] = p
        if u == target:
            break
        for k in range(start[u], start[u + 1]):
            v = succ[k]
            dv = d + length[k]
            if v not in done and dv < best.get(v, np.inf):
                best[v] = dv
                heapq.heappush(heap, (dv, v, u))
    if target not in done:
        return np.empty(0, dtype=np.int64)
    path = [target]
    while path[-1] != source:
        path.append(prev[path[-1]])
    return np.array(path[::-1], dtype=np.int64)


@numba.njit(cache=True, nogil=True)
def _distances_from(source: int, cutoff_m: float, start: IntArray, target: IntArray,
                    length: FloatArray) -> tuple[IntArray, FloatArray]:  # pragma: no cover
    """Dijkstra from node index ``source`` to ``cutoff_m``: the nodes reached, in order of
    distance, and their distances."""
    done = {source: 0.0}
    done.clear()
    heap = [(0.0, source)]
    nodes, distances = [source], [0.0]
    nodes.clear()
    distances.clear()
    while heap:
        d, u = heapq.heappop(heap)
        if u in done:
            continue
        done[u] = d
        nodes.append(u)
        distances.append(d)
        for k in range(start[u], start[u + 1]):
            v = target[k]
            dv = d + length[k]
            if dv <= cutoff_m and v not in done:
                heapq.heappush(heap, (dv, v))
    return np.array(nodes, dtype=np.int64), np.array(distances)
