"""RoadGraph: the read side of a map, the queries the matcher needs.

Opened once from a road-graph database (:func:`RoadGraph.open`), then held in memory: its queries
are pure and safe to share between threads. Nearest-edge queries use a uniform grid over the
edges' segments (:mod:`roadgraph.spatial`); distances and projections are exact.

Seed: Mayhew 1999, section 5.7 (the intersection mesh and the perpendicular-distance search).
"""

from __future__ import annotations

import heapq
import math
from pathlib import Path
from typing import NamedTuple

import networkx as nx
import numba
import numpy as np

from roadgraph.build import EdgeRecord, MapInfo, NodeRecord, RoadNetwork, network_from_projected
from roadgraph.errors import RoadGraphError
from roadgraph.geometry import FloatArray, LocalFrame, project_onto_polyline, turn_angle_rad
from roadgraph.spatial import IntArray, NearPolylines, SegmentGrid
from roadgraph.store import read_network


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
    """An intersection graph in memory, with spatial and routing queries."""

    def __init__(self, network: RoadNetwork, map_id: str = "") -> None:
        self.map_id = map_id
        self.info: MapInfo = network.info
        self.frame = LocalFrame(network.info.crs_wkt)
        self._nodes = {n.id: n for n in network.nodes}
        self._edges = network.edges
        self._index = {EdgeKey(e.u, e.v, e.key): i for i, e in enumerate(self._edges)}
        self._keys = list(self._index)
        self._grid = SegmentGrid([e.coords for e in self._edges])
        self.graph = self._to_networkx()
        self._node_ids = np.array(list(self._nodes), dtype=np.int64)
        self._node_index = {n: i for i, n in enumerate(self._nodes)}
        self._successors = self._successor_arrays()

    @classmethod
    def open(cls, path: Path | str) -> RoadGraph:
        """Load a road-graph database written by ``roadgraph import``."""
        path = Path(path)
        return cls(read_network(path), map_id=path.stem)

    @classmethod
    def from_networkx(cls, graph: nx.MultiDiGraph, frame: LocalFrame) -> RoadGraph:
        """A RoadGraph from a hand-built graph in the frame's metres (tests, synthetic maps)."""
        return cls(network_from_projected(graph, frame), map_id=graph.graph.get("name", ""))

    def _to_networkx(self) -> nx.MultiDiGraph:
        graph = nx.MultiDiGraph(crs=self.info.crs_wkt)
        for n in self._nodes.values():
            graph.add_node(n.id, x=n.x_m, y=n.y_m, lon=n.lon_deg, lat=n.lat_deg)
        for e in self._edges:
            graph.add_edge(e.u, e.v, key=e.key, length=e.length_m)
        return graph

    def _successor_arrays(self) -> tuple[IntArray, IntArray, FloatArray]:
        """Each node's successors by the shortest parallel edge, in compressed rows: node
        ``i``'s are ``target[start[i]:start[i + 1]]`` at ``length[...]`` (node indices)."""
        shortest: dict[tuple[int, int], float] = {}
        for e in self._edges:
            shortest[(e.u, e.v)] = min(e.length_m, shortest.get((e.u, e.v), math.inf))
        index = self._node_index
        rows = sorted((index[u], index[v], length) for (u, v), length in shortest.items())
        counts = np.bincount([r[0] for r in rows], minlength=len(index))
        start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        target = np.array([r[1] for r in rows], dtype=np.int64)
        length = np.array([r[2] for r in rows], dtype=np.float64)
        return start, target, length

    # --- records -------------------------------------------------------------------------
    @property
    def nodes(self) -> tuple[NodeRecord, ...]:
        return tuple(self._nodes.values())

    @property
    def edges(self) -> tuple[EdgeRecord, ...]:
        return self._edges

    def node(self, node_id: int) -> NodeRecord:
        return self._nodes[node_id]

    def edge(self, edge: EdgeKey) -> EdgeRecord:
        return self._edges[self._index[edge]]

    def has_edge(self, edge: EdgeKey) -> bool:
        return edge in self._index

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

    def _projections(self, near: NearPolylines) -> list[EdgeProjection]:
        keys, edges = self._keys, self._edges
        return [EdgeProjection(keys[i], offset, distance, x, y, bearing, edges[i].length_m)
                for i, (distance, offset, x, y, bearing) in zip(near.polylines, near.closest)]

    def project(self, edge: EdgeKey, x_m: float, y_m: float) -> EdgeProjection:
        """Project a point onto an edge."""
        record = self.edge(edge)
        p = project_onto_polyline(record.coords, x_m, y_m)
        return EdgeProjection(edge=edge, offset_m=p.offset_m, distance_m=p.distance_m,
                              x_m=p.x_m, y_m=p.y_m, bearing_rad=p.bearing_rad,
                              length_m=record.length_m)

    # --- topology ------------------------------------------------------------------------
    def out_edges(self, node_id: int) -> list[EdgeRecord]:
        """Edges leaving a node (each with its ``bearing_start_rad``)."""
        return [self.edge(EdgeKey(u, v, k)) for u, v, k in self.graph.out_edges(node_id, keys=True)]

    def in_edges(self, node_id: int) -> list[EdgeRecord]:
        """Edges arriving at a node (each with its ``bearing_end_rad``)."""
        return [self.edge(EdgeKey(u, v, k)) for u, v, k in self.graph.in_edges(node_id, keys=True)]

    def turn_angle_rad(self, edge_in: EdgeKey, edge_out: EdgeKey) -> float:
        """Turn from one edge into the next at their shared node: positive right, negative left."""
        a, b = self.edge(edge_in), self.edge(edge_out)
        if a.v != b.u:
            raise RoadGraphError(f"edges {edge_in} and {edge_out} do not meet")
        return turn_angle_rad(a.bearing_end_rad, b.bearing_start_rad)

    def shortest_path(self, source: int, target: int) -> list[EdgeKey]:
        """The shortest route by length from one node to another, as edges; [] when equal.

        Raises :class:`networkx.NetworkXNoPath` when the target cannot be reached.
        """
        nodes = nx.shortest_path(self.graph, source, target, weight="length")
        return [self._shortest_parallel(u, v) for u, v in zip(nodes[:-1], nodes[1:])]

    def distances_from(self, source: int, cutoff_m: float) -> dict[int, float]:
        """Driving distance from ``source`` to every node within ``cutoff_m`` (Dijkstra).

        Compiled over compressed successor rows: the offline matcher runs one per candidate
        source node, and networkx's general version cost three times a plain Python heap
        search, which in turn cost five times this.
        """
        nodes, distances = _distances_from(self._node_index[source], cutoff_m, *self._successors)
        return dict(zip(self._node_ids[nodes].tolist(), distances.tolist()))

    def _shortest_parallel(self, u: int, v: int) -> EdgeKey:
        key = min(self.graph[u][v], key=lambda k: self.graph[u][v][k]["length"])
        return EdgeKey(u, v, key)


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
