"""Offline matching of a whole trace: hidden Markov model and Viterbi (Newson & Krumm 2009).

States are candidate positions on directed edges near each point (from the spatial index).
Emission: Gaussian in the distance from the point to the road (``sigma_m``). Transition:
exponential in ``|route distance - straight distance|`` between consecutive points
(``beta_m``), the route distance by shortest path on the graph (bounded search). Points closer
than ``2 sigma`` to the last kept one are skipped (as GraphHopper does); where no candidate
of one point can reach any of the next, the trace is split into a new segment.

The route between matched points is rebuilt by shortest path; a skipped point is matched to
the nearest position on the route between its kept neighbours. Pure: no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

from navsvc.errors import TraceError
from roadgraph import EdgeKey, EdgeProjection, RoadGraph


@dataclass(frozen=True)
class HmmConfig:
    sigma_m: float = 10.0  # GPS error (GraphHopper's default measurement_error_sigma)
    beta_m: float = 2.0 * 10.0  # transition scale (GraphHopper: beta 2 in its own units)
    search_radius_sigmas: float = 3.0
    max_candidates: int = 8
    max_route_factor: float = 5.0  # route search stops at this x straight distance + 500 m
    max_points: int = 20_000  # per request


# A trace point: (x_m, y_m) in the map's frame. A trace is its points in time order; times
# themselves do not enter the model.
Point = Sequence[float]


class PointMatch(NamedTuple):
    """Where one trace point was matched (None: no road near it, or outside every segment)."""

    trace_index: int  # the point's position in the (cleaned) trace
    projection: EdgeProjection | None
    segment: int | None


@dataclass
class RouteSegment:
    """A contiguous matched route."""

    edges: list[EdgeKey] = field(default_factory=list)
    start_offset_m: float = 0.0  # on the first edge
    end_offset_m: float = 0.0  # on the last edge
    length_m: float = 0.0


@dataclass
class MatchResult:
    segments: list[RouteSegment]
    points: list[PointMatch]


def _keep(points: Sequence[Point], min_gap_m: float) -> list[int]:
    """Indices of the points to match: the first, the last, and those ``min_gap_m`` from the
    previous kept one."""
    kept = [0]
    for i in range(1, len(points) - 1):
        if math.dist(points[i], points[kept[-1]]) > min_gap_m:
            kept.append(i)
    if len(points) > 1:
        kept.append(len(points) - 1)
    return kept


class HmmMatcher:
    """Matches traces on one graph (holds the graph and a cache of route searches)."""

    def __init__(self, graph: RoadGraph, config: HmmConfig = HmmConfig()) -> None:
        self.graph = graph
        self.config = config

    def candidates(self, p: Point) -> list[EdgeProjection]:
        c = self.config
        return self.graph.edges_near(p[0], p[1], c.search_radius_sigmas * c.sigma_m,
                                     c.max_candidates)

    def _reach(self, source: int, limit_m: float,
               cache: dict[int, tuple[float, dict[int, float]]]) -> dict[int, float]:
        """Driving distance from node ``source`` to every node within ``limit_m``.

        ``cache`` holds one search per source node for the whole trace, with the cutoff it was
        run to; a later step that needs a longer reach searches again. Searches go twice as
        far as asked, as the limit follows the gap between points and grows often (654
        searches instead of 1,694 for the ten drives of bench/matching_speed.py). Distances
        beyond ``limit_m`` are the caller's to ignore.
        """
        found = cache.get(source)
        if found is None or found[0] < limit_m:
            cutoff = 2.0 * limit_m
            found = cache[source] = (cutoff, self.graph.distances_from(source, cutoff))
        return found[1]

    def match(self, points: Sequence[Point]) -> MatchResult:
        c = self.config
        if not points:
            raise TraceError("the trace has no points")
        if len(points) > c.max_points:
            raise TraceError(f"the trace has {len(points)} points; the limit is {c.max_points}")
        kept = _keep(points, 2.0 * c.sigma_m)
        matches: dict[int, tuple[EdgeProjection, int]] = {}
        segments: list[RouteSegment] = []
        layer: list[tuple[EdgeProjection, float, int]] = []  # candidate, log prob, back index
        history: list[tuple[int, list[tuple[EdgeProjection, float, int]]]] = []
        cache: dict[int, tuple[float, dict[int, float]]] = {}
        for i in kept:
            cands = self.candidates(points[i])
            if not cands:
                continue  # nothing near: the point is left unmatched
            emission = [-0.5 * (p.distance_m / c.sigma_m) ** 2 for p in cands]
            if not layer:
                layer = [(p, e, -1) for p, e in zip(cands, emission)]
                history = [(i, layer)]
                continue
            new_layer = self._transition(layer, points[history[-1][0]], points[i], cands,
                                         emission, cache)
            if all(s == -math.inf for _, s, _ in new_layer):  # a gap it cannot bridge: split
                self._close_segment(points, history, segments, matches)
                layer = [(p, e, -1) for p, e in zip(cands, emission)]
                history = [(i, layer)]
                continue
            layer = new_layer
            history.append((i, layer))
        if history:
            self._close_segment(points, history, segments, matches)
        return MatchResult(segments, [PointMatch(i, *matches.get(i, (None, None)))
                                      for i in range(len(points))])

    def _transition(self, layer: list[tuple[EdgeProjection, float, int]], prev: Point,
                    point: Point, cands: list[EdgeProjection], emission: list[float],
                    cache: dict[int, tuple[float, dict[int, float]]]
                    ) -> list[tuple[EdgeProjection, float, int]]:
        """One Viterbi step: each candidate's best predecessor and score.

        The route distance from ``q`` to ``p`` is along ``q``'s edge when ``p`` lies ahead on
        it, else the rest of ``q``'s edge, the shortest path to ``p``'s edge and ``p``'s
        offset; inf beyond the search limit."""
        c = self.config
        straight = math.dist(prev, point)
        limit = c.max_route_factor * straight + 500.0
        best = [-math.inf] * len(cands)
        back = [-1] * len(cands)
        for k, (q, score, _) in enumerate(layer):
            if score == -math.inf:
                continue
            reach = self._reach(q.edge.v, limit, cache)
            remaining = q.remaining_m
            for j, p in enumerate(cands):
                if p.edge == q.edge and p.offset_m >= q.offset_m - 1e-6:
                    route = p.offset_m - q.offset_m
                else:
                    between = reach.get(p.edge.u)
                    if between is None or between > limit:
                        continue
                    route = remaining + between + p.offset_m
                s = score - abs(route - straight) / c.beta_m
                if s > best[j]:
                    best[j], back[j] = s, k
        return [(p, b + e if k >= 0 else -math.inf, k)
                for p, b, e, k in zip(cands, best, emission, back)]

    @staticmethod
    def _backtrack(history: list[tuple[int, list[tuple[EdgeProjection, float, int]]]]
                   ) -> list[tuple[int, EdgeProjection]]:
        last = history[-1][1]
        k = max(range(len(last)), key=lambda j: last[j][1])
        chain = []
        for i, layer in reversed(history):
            proj, _, back = layer[k]
            chain.append((i, proj))
            k = back
        return chain[::-1]

    def _close_segment(self, points: Sequence[Point],
                       history: list[tuple[int, list[tuple[EdgeProjection, float, int]]]],
                       segments: list[RouteSegment],
                       matches: dict[int, tuple[EdgeProjection, int]]) -> None:
        """Decode the segment ending here, rebuild its route and match its points."""
        chain = self._backtrack(history)
        seg, spans = self._route(chain)
        segments.append(seg)
        number = len(segments) - 1
        for k, (i, proj) in enumerate(chain):
            matches[i] = (proj, number)
            if k + 1 == len(chain):
                break
            between = seg.edges[spans[k][0]:spans[k][1] + 1]
            for j in range(i + 1, chain[k + 1][0]):  # skipped points: onto the route driven
                x, y = points[j]
                matches[j] = (min((self.graph.project(e, x, y) for e in between),
                                  key=lambda q: q.distance_m), number)

    def _route(self, chain: list[tuple[int, EdgeProjection]]
               ) -> tuple[RouteSegment, list[tuple[int, int]]]:
        """The edges driven through the matched positions, in order, and for each step
        between two of them the first and last index into those edges."""
        first = chain[0][1]
        seg = RouteSegment(edges=[first.edge], start_offset_m=first.offset_m,
                           end_offset_m=first.offset_m)
        spans = []
        for (_, a), (_, b) in zip(chain[:-1], chain[1:]):
            start = len(seg.edges) - 1
            if a.edge == b.edge and b.offset_m >= a.offset_m - 1e-6:
                seg.length_m += b.offset_m - a.offset_m
                spans.append((start, start))
                continue
            seg.length_m += a.remaining_m + b.offset_m
            if a.edge.v != b.edge.u:
                path = self.graph.shortest_path(a.edge.v, b.edge.u)
                seg.edges += path
                seg.length_m += sum(self.graph.edge(e).length_m for e in path)
            seg.edges.append(b.edge)
            spans.append((start, len(seg.edges) - 1))
        seg.end_offset_m = chain[-1][1].offset_m
        return seg, spans
