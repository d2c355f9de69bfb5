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

from roadgraph.build import EdgeRecord, MapInfo, NodeRecord, RoadNetwork, network_from_projected
from roadgraph.errors import RoadGraphError
from roadgraph.geometry import LocalFrame, project_onto_polyline, turn_angle_rad
from roadgraph.spatial import NearPolylines, SegmentGrid
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
        self._successors = self._successor_lists()

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

    def _successor_lists(self) -> dict[int, list[tuple[int, float]]]:
        shortest: dict[tuple[int, int], float] = {}
        for e in self._edges:
            shortest[(e.u, e.v)] = min(e.length_m, shortest.get((e.u, e.v), math.inf))
        out: dict[int, list[tuple[int, float]]] = {n: [] for n in self._nodes}
        for (u, v), length in shortest.items():
            out[u].append((v, length))
        return out

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
    def edges_near(self, x_m: float, y_m: float, radius_m: float) -> list[EdgeProjection]:
        """The point projected onto each edge within ``radius_m`` of it, nearest first."""
        return self._projections(self._grid.near(x_m, y_m, radius_m))

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

        A plain heap search over precomputed successor lists: the matchers run one per
        candidate, and networkx's general version cost three times as much.
        """
        done: dict[int, float] = {}
        heap = [(0.0, source)]
        successors = self._successors
        while heap:
            d, u = heapq.heappop(heap)
            if u in done:
                continue
            done[u] = d
            for v, length in successors[u]:
                dv = d + length
                if dv <= cutoff_m and v not in done:
                    heapq.heappush(heap, (dv, v))
        return done

    def _shortest_parallel(self, u: int, v: int) -> EdgeKey:
        key = min(self.graph[u][v], key=lambda k: self.graph[u][v][k]["length"])
        return EdgeKey(u, v, key)
