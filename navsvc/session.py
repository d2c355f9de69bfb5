"""One vehicle's navigation: wire records in, matched positions out; and the live sessions.

The same pipeline serves a live session (REST, WebSocket) and an offline replay
(``navsvc run``): parse each record, feed the :class:`FusionEngine`, and place each estimate on
the road graph. A record that cannot be used is reported as a :class:`Rejection` and changes
nothing.

:class:`SessionStore` holds the service's sessions: ids, owners (API keys), idle expiry, and
the trip log that makes every accepted packet durable before it is acknowledged and lets a
restarted server rebuild its open sessions by replaying them.
"""

from __future__ import annotations

import hashlib
import logging
import math
import secrets
import sqlite3
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from navsvc.errors import (
    ConfigError,
    LimitExceeded,
    PacketError,
    Rejection,
    RejectReason,
    SessionNotFound,
)
from navsvc.fusion import (
    FusionConfig,
    FusionEngine,
    GpsMode,
    Integration,
    Mechanisation,
    SensorConfig,
    StrapdownOptions,
)
from navsvc.matching.online import MatcherConfig, OnlineMatcher
from navsvc.triplog import LoggedSession, TripLog
from navsvc.types import FusedEstimate, GpsFix, MatchedPosition, MatchState
from navsvc.wire.packets import parse
from roadgraph import LocalFrame, RoadGraph
from roadgraph.geometry import wrap_angle_rad

log = logging.getLogger(__name__)


MAP_MARGIN_DEG = 0.5  # GPS fixes farther than this outside the map's bbox are refused


@dataclass(frozen=True)
class SessionConfig:
    """Everything chosen when a session starts."""

    fusion: FusionConfig = FusionConfig()
    matcher: MatcherConfig = MatcherConfig()
    strapdown: StrapdownOptions = StrapdownOptions()  # the INS, for sensors "strapdown"
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
        if config.map_feedback and not config.fusion.profile.map_feedback:
            raise ConfigError(f"map feedback is not available with "
                              f"{config.fusion.sensors.value} yet")
        self.engine = FusionEngine(config.fusion, frame=graph.frame if graph else None,
                                   ins=config.strapdown)
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
                packet = parse(record)
                if isinstance(packet, GpsFix):
                    self._check_on_map(packet)
                estimates = self.engine.add(packet)
            except PacketError as exc:
                result.rejections.append(Rejection(index, exc.reason, exc.detail))
                continue
            result.accepted += 1
            if estimates:
                result.positions += [self._place(e) for e in estimates]
            else:
                self._step_matcher()
        return result

    def _check_on_map(self, fix: GpsFix) -> None:
        """Refuse a fix far outside the map: the vehicle cannot be matched there, and one
        such fix would throw the filter thousands of kilometres off."""
        if self.graph is None:
            return
        west, south, east, north = self.graph.info.bbox_wgs84
        m = MAP_MARGIN_DEG
        if not (south - m <= fix.lat_deg <= north + m and west - m <= fix.lon_deg <= east + m):
            raise PacketError(RejectReason.OUT_OF_RANGE,
                              f"fix at lat={fix.lat_deg} lon={fix.lon_deg} is outside the map "
                              f"{self.graph.map_id!r} (bbox {west:.4f},{south:.4f},"
                              f"{east:.4f},{north:.4f} plus {m} degrees)")

    def _step_matcher(self) -> None:
        """Between outputs, step the matcher every ``match_interval_s`` so that it sees each
        short edge and intersection on the way."""
        t = self.engine.t
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
        c, e, bearing = self.config, p.estimate, p.road_bearing_rad
        if p.state != MatchState.ON_ROAD or bearing is None or p.in_ambiguity_region or \
                p.distance_to_road_m is None or \
                p.distance_to_road_m > c.feedback_max_distance_m or e.speed_mps < 1.0:
            return
        if self._last_feedback_t is not None and e.t - self._last_feedback_t < 1.0:
            return
        if abs(wrap_angle_rad(e.heading_rad - bearing)) > math.radians(20.0):
            return
        self.engine.correct_to_road(p.x_m, p.y_m, bearing, c.feedback_sigma_across_m,
                                    c.feedback_sigma_heading_rad)
        self._last_feedback_t = e.t


def config_from_options(options: dict[str, Any]) -> SessionConfig:
    """A session's configuration from the options it was created with (API and trip log).

    Keys: ``sensors``, ``fusion`` (GPS mode), ``map_feedback``, the optional vehicle
    constants ``ticks_per_m``, ``wheelbase_m``, ``gps_uere_m``, and for ``strapdown``
    ``ins_integration``, ``ins_mechanisation``, ``imu_mounting_rpy_deg``,
    ``gps_lever_arm_m``. Raises ConfigError.
    """
    defaults = FusionConfig()
    fusion = FusionConfig(
        sensors=SensorConfig(options.get("sensors", "gyro_odometer")),
        gps_mode=GpsMode(options.get("fusion", "ekf")),
        ticks_per_m=float(options.get("ticks_per_m", defaults.ticks_per_m)),
        wheelbase_m=float(options.get("wheelbase_m", defaults.wheelbase_m)),
        gps_uere_m=float(options.get("gps_uere_m", defaults.gps_uere_m)))
    base = StrapdownOptions()
    strapdown = StrapdownOptions(
        integration=Integration(options.get("ins_integration", base.integration.value)),
        mechanisation=Mechanisation(options.get("ins_mechanisation",
                                                base.mechanisation.value)),
        mounting_rpy_deg=_triple(options.get("imu_mounting_rpy_deg", base.mounting_rpy_deg)),
        lever_arm_m=_triple(options.get("gps_lever_arm_m", base.lever_arm_m)))
    return SessionConfig(fusion=fusion, strapdown=strapdown,
                         map_feedback=bool(options.get("map_feedback", False)))


def _triple(values: Any) -> tuple[float, float, float]:
    x, y, z = (float(v) for v in values)
    return x, y, z


def owner_of(api_key: str | None) -> str:
    """What the store keeps of an API key: its SHA-256 ('' for the open service)."""
    return hashlib.sha256(api_key.encode()).hexdigest() if api_key else ""


@dataclass
class LiveSession:
    """A session of the service: the vehicle's pipeline and what the store needs around it."""

    id: str
    owner: str
    vehicle_id: str
    options: dict[str, Any]
    created_unix: float
    vehicle: VehicleSession
    packets: int = 0  # accepted so far (the next trip-log sequence number)
    rejected: int = 0
    last_seen: float = 0.0  # store clock


class SessionStore:
    """The live sessions, backed by a trip log."""

    def __init__(self, graph: RoadGraph, triplog: TripLog, *, idle_timeout_s: float = 3600.0,
                 max_sessions_per_owner: int = 10_000,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.graph = graph
        self.triplog = triplog
        self.idle_timeout_s = idle_timeout_s
        self.max_sessions_per_owner = max_sessions_per_owner
        self._clock = clock
        self._sessions: dict[str, LiveSession] = {}

    def __len__(self) -> int:
        return len(self._sessions)

    def create(self, owner: str, vehicle_id: str, options: dict[str, Any]) -> LiveSession:
        """Start a session (options as in :func:`config_from_options`)."""
        config = config_from_options(options)
        owned = sum(1 for s in self._sessions.values() if s.owner == owner)
        if owned >= self.max_sessions_per_owner:
            raise LimitExceeded(f"this API key already has {owned} sessions; the limit is "
                                f"{self.max_sessions_per_owner}")
        session = LiveSession(id=secrets.token_hex(8), owner=owner, vehicle_id=vehicle_id,
                              options=options, created_unix=time.time(),
                              vehicle=VehicleSession(config, self.graph),
                              last_seen=self._clock())
        self.triplog.create_session(LoggedSession(session.id, owner, vehicle_id, options,
                                                  session.created_unix))
        self._sessions[session.id] = session
        log.info("session %s created for vehicle %r (%s)", session.id, vehicle_id, options)
        return session

    def get(self, session_id: str, owner: str) -> LiveSession:
        session = self._sessions.get(session_id)
        if session is None or session.owner != owner:
            raise SessionNotFound(f"no session {session_id!r}")
        return session

    def sessions(self, owner: str) -> list[LiveSession]:
        return [s for s in self._sessions.values() if s.owner == owner]

    def ingest(self, session: LiveSession, records: list[Any],
               records_json: str | None = None) -> BatchResult:
        """Apply a batch, then log its accepted packets; returns once they are on disk.

        ``records_json``, the batch as the JSON array it arrived in, is logged as it is when
        every packet is accepted (the common case), which saves encoding it again.

        If the log cannot be written the session is rebuilt from its log, so that memory
        never holds packets the log lacks, and the error propagates (nothing acknowledged).
        """
        result = session.vehicle.add_records(records)
        refused = {r.index for r in result.rejections}
        accepted = [r for i, r in enumerate(records) if i not in refused
                    and not (isinstance(r, dict) and r.get("kind") == "truth")]
        try:
            self.triplog.append(session.id, session.packets, accepted,
                                records_json if len(accepted) == len(records) else None)
        except sqlite3.Error:
            log.exception("session %s: trip log write failed; rebuilding from the log",
                          session.id)
            self._sessions[session.id] = self._replay(
                LoggedSession(session.id, session.owner, session.vehicle_id, session.options,
                              session.created_unix), session.rejected)
            raise
        session.packets += len(accepted)
        session.rejected += len(result.rejections)
        session.last_seen = self._clock()
        return result

    def delete(self, session_id: str, owner: str) -> None:
        self.get(session_id, owner)
        self._close(session_id)

    def expire_idle(self) -> list[str]:
        """End the sessions idle for longer than the timeout; return their ids."""
        cutoff = self._clock() - self.idle_timeout_s
        idle = [s.id for s in self._sessions.values() if s.last_seen < cutoff]
        for session_id in idle:
            log.info("session %s expired after %.0f s idle", session_id, self.idle_timeout_s)
            self._close(session_id)
        return idle

    def restore(self) -> int:
        """Rebuild every open session of the trip log (after a restart); return how many."""
        for logged in self.triplog.open_sessions():
            session = self._replay(logged)
            self._sessions[logged.id] = session
            log.info("session %s restored: %d packets replayed", logged.id, session.packets)
        return len(self._sessions)

    def _replay(self, logged: LoggedSession, rejected: int = 0) -> LiveSession:
        """A session rebuilt by running its logged packets through a fresh pipeline."""
        vehicle = VehicleSession(config_from_options(logged.options), self.graph)
        count = 0
        for record in self.triplog.packets(logged.id):
            vehicle.add_records([record])
            count += 1
        return LiveSession(id=logged.id, owner=logged.owner, vehicle_id=logged.vehicle_id,
                           options=logged.options, created_unix=logged.created_unix,
                           vehicle=vehicle, packets=count, rejected=rejected,
                           last_seen=self._clock())

    def _close(self, session_id: str) -> None:
        self.triplog.close_session(session_id)
        del self._sessions[session_id]
