"""One vehicle's navigation: wire records in, matched positions out.

The same pipeline serves a live session (REST, WebSocket) and an offline replay
(``navsvc run``): parse each record, feed the :class:`FusionEngine`, and place each estimate on
the road graph. A record that cannot be used is reported as a :class:`Rejection` and changes
nothing.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from navsvc.errors import PacketError, Rejection
from navsvc.fusion.engine import FusionConfig, FusionEngine
from navsvc.fusion.motion import road_constraint
from navsvc.matching.online import MatcherConfig, OnlineMatcher
from navsvc.types import FusedEstimate, MatchedPosition, MatchState
from navsvc.wire.packets import parse
from roadgraph import EdgeKey, LocalFrame, RoadGraph
from roadgraph.geometry import wrap_angle_rad


@dataclass(frozen=True)
class SessionConfig:
    """Everything chosen when a session starts."""

    fusion: FusionConfig = FusionConfig()
    matcher: MatcherConfig = MatcherConfig()
    map_feedback: bool = False  # matched road → pseudo-measurement into the filter
    match_interval_s: float = 0.1  # the matcher also steps between outputs (short edges)
    feedback_sigma_across_m: float = 2.0
    feedback_sigma_heading_rad: float = math.radians(5.0)
    feedback_max_distance_m: float = 10.0


@dataclass
class BatchResult:
    """What one batch of records produced."""

    positions: list[MatchedPosition] = field(default_factory=list)
    rejections: list[Rejection] = field(default_factory=list)
    accepted: int = 0


class VehicleSession:
    """Fusion and map matching for one vehicle."""

    def __init__(self, config: SessionConfig = SessionConfig(),
                 graph: RoadGraph | None = None) -> None:
        self.config = config
        self.graph = graph
        self.engine = FusionEngine(config.fusion, frame=graph.frame if graph else None)
        self.matcher = OnlineMatcher(graph, config.matcher) if graph is not None else None
        self.last_position: MatchedPosition | None = None
        self._last_match_t: float | None = None
        self._last_feedback_t: float | None = None

    @property
    def frame(self) -> LocalFrame | None:
        """The metric frame of positions (the map's; else anchored at the first GPS fix)."""
        return self.engine.frame

    def add_records(self, records: Iterable[Any], first_index: int = 0) -> BatchResult:
        """Parse and apply records in order; refuse the bad ones one by one."""
        result = BatchResult()
        for index, record in enumerate(records, start=first_index):
            if isinstance(record, dict) and record.get("kind") == "truth":
                continue  # simulator ground truth travels in the same files
            try:
                estimates = self.engine.add(parse(record))
            except PacketError as exc:
                result.rejections.append(Rejection(index, exc.reason, exc.detail))
                continue
            result.accepted += 1
            if estimates:
                result.positions += [self._place(e) for e in estimates]
            else:
                self._step_matcher()
        return result

    def position(self) -> MatchedPosition | None:
        """The latest position (on request, between GPS epochs)."""
        estimate = self.engine.estimate()
        return None if estimate is None else self._place(estimate)

    def _step_matcher(self) -> None:
        """Between outputs, step the matcher every ``match_interval_s`` so that it sees each
        short edge and intersection on the way."""
        t = self.engine.state.t
        if self.matcher is None or t is None or (
                self._last_match_t is not None
                and t - self._last_match_t < self.config.match_interval_s):
            return
        estimate = self.engine.estimate()
        if estimate is not None:
            self._place(estimate)

    def _place(self, estimate: FusedEstimate) -> MatchedPosition:
        if self.matcher is None:
            state = MatchState.OFF_ROAD if estimate.initialized else MatchState.INITIALIZING
            position = MatchedPosition(estimate=estimate, state=state, x_m=estimate.x_m,
                                       y_m=estimate.y_m)
        else:
            position = self.matcher.update(estimate)
            self._last_match_t = estimate.t
            if self.config.map_feedback:
                self._feed_back(position)
        self.last_position = position
        return position

    def _feed_back(self, p: MatchedPosition) -> None:
        """A confident match (on a road, outside any ambiguity region, close and heading
        along it) pulls the filter onto the road, at most once a second."""
        c, e = self.config, p.estimate
        if p.state != MatchState.ON_ROAD or p.edge is None or self.matcher is None or \
                self.matcher.state.region is not None or p.distance_to_road_m is None or \
                p.distance_to_road_m > c.feedback_max_distance_m or e.speed_mps < 1.0:
            return
        if self._last_feedback_t is not None and e.t - self._last_feedback_t < 1.0:
            return
        assert self.graph is not None
        bearing = self.graph.project(EdgeKey(p.edge.u, p.edge.v, p.edge.key), e.x_m,
                                     e.y_m).bearing_rad
        if abs(wrap_angle_rad(e.heading_rad - bearing)) > math.radians(20.0):
            return
        self.engine.correct(*road_constraint(self.engine.state.x, p.x_m, p.y_m, bearing,
                                             c.feedback_sigma_across_m,
                                             c.feedback_sigma_heading_rad))
        self._last_feedback_t = e.t
