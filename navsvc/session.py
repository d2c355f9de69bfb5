"""One vehicle's navigation: wire records in, matched positions out.

The same pipeline serves a live session (REST, WebSocket) and an offline replay
(``navsvc run``): parse each record, feed the :class:`FusionEngine`, and place each estimate on
the road graph. A record that cannot be used is reported as a :class:`Rejection` and changes
nothing.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from navsvc.errors import PacketError, Rejection
from navsvc.fusion.engine import FusionConfig, FusionEngine
from navsvc.types import FusedEstimate, MatchedPosition, MatchState
from navsvc.wire.packets import parse
from roadgraph import LocalFrame, RoadGraph


@dataclass(frozen=True)
class SessionConfig:
    """Everything chosen when a session starts."""

    fusion: FusionConfig = FusionConfig()


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
        self.last_position: MatchedPosition | None = None

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
            result.positions += [self._place(e) for e in estimates]
        return result

    def position(self) -> MatchedPosition | None:
        """The latest position (on request, between GPS epochs)."""
        estimate = self.engine.estimate()
        return None if estimate is None else self._place(estimate)

    def _place(self, estimate: FusedEstimate) -> MatchedPosition:
        state = MatchState.OFF_ROAD if estimate.initialized else MatchState.INITIALIZING
        position = MatchedPosition(estimate=estimate, state=state, x_m=estimate.x_m,
                                   y_m=estimate.y_m)
        self.last_position = position
        return position
