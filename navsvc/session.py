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

import enum
import hashlib
import io
import json
import logging
import math
import pickle
import secrets
import sqlite3
import time
from collections import OrderedDict
from collections.abc import Callable, Generator, Iterable
from dataclasses import dataclass, field, fields, is_dataclass, replace
from functools import cache
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from navsvc.errors import (
    BatchAlreadyApplied,
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
from navsvc.fusion.road.batch import IMU, N_COLUMNS, ODOMETER, STEERING, SampleRun
from navsvc.fusion.road.filter import RoadFilter
from navsvc.matching.online import MatcherConfig, OnlineMatcher
from navsvc.triplog import Checkpoint, CommitGroup, LoggedSession, TripLog
from navsvc.types import (
    FusedEstimate,
    GpsFix,
    MatchedPosition,
    MatchState,
    Packet,
)
from navsvc.wire import bulk
from navsvc.wire.packets import parse_record
from navsvc.wire.positions import position_json
from roadgraph import EdgeKey, LocalFrame, RoadGraph
from roadgraph.geometry import wrap_angle_rad

log = logging.getLogger(__name__)


MAP_MARGIN_DEG = 0.5  # GPS fixes farther than this outside the map's bbox are refused
MAX_TIME_JUMP_S = 3600.0  # a packet this far ahead of the vehicle's latest is refused


@dataclass(frozen=True)
class SessionConfig:
    """Everything chosen when a session starts."""

    fusion: FusionConfig = FusionConfig()
    matcher: MatcherConfig = MatcherConfig()
    strapdown: StrapdownOptions = StrapdownOptions()  # the INS, for sensors "strapdown"
    map_feedback: bool = True  # matched road → pseudo-measurement into the filter
    match_interval_s: float = 0.1  # the matcher also steps between outputs (short edges)
    feedback_sigma_across_m: float = 2.0
    feedback_sigma_heading_rad: float = math.radians(5.0)
    feedback_max_distance_m: float = 10.0  # always fed back this close to the road; farther
    feedback_gate_sigmas: float = 3.0  # only within this many sigmas of the estimate's own
    # across-road uncertainty (an outage's drift is pulled back, a wrong road's pull is not)
    feedback_max_heading_sigma_rad: float = math.radians(60.0)  # none for a heading less
    # sure than this: it is unknown, and "along the road" then says nothing


@dataclass
class BatchResult:
    """What one batch of records produced."""

    positions: list[MatchedPosition] = field(default_factory=list)
    rejections: list[Rejection] = field(default_factory=list)
    accepted: int = 0
    indices: list[int] = field(default_factory=list)  # of each of the accepted in the batch
    faulted: bool = False  # the pipeline raised on a packet: its state may be torn
    encoded: str | None = None  # the accepted records as one JSON array, when that is the
    # message's own text (every packet accepted as it came): what the trip log stores
    decoded: list[dict[str, Any]] | None = None  # the accepted, as validated (None: from
    # ``encoded`` when asked)

    @property
    def records(self) -> list[dict[str, Any]]:
        """The accepted records, as validated (and logged)."""
        if self.decoded is None:
            self.decoded = json.loads(self.encoded) if self.encoded else []
        return self.decoded


_SKIP = object()  # a record add_records skips (simulator truth)
_DEAD_RECKONING: dict[type, int] = {bulk.Imu: IMU, bulk.Odometer: ODOMETER,
                                    bulk.Steering: STEERING}
_DEG = math.pi / 180.0  # math.radians(x) is x times this
_NAN = math.nan


class _Run:
    """Dead-reckoning samples waiting to go through the filter as one run (rows, flat: NaN
    where a field is absent, which is what ``np.array`` makes of None, at half the cost)."""

    __slots__ = ("indices", "values")

    def __init__(self) -> None:
        self.indices: list[int] = []
        self.values: list[float] = []

    def add(self, index: int, packet: bulk.Imu | bulk.Odometer | bulk.Steering,
            kind: int) -> None:
        """A sample, with the conversions of ``packets.*.core`` (degrees to radians; the
        6-axis fields stand in for the planar ones)."""
        self.indices.append(index)
        if kind == IMU:
            p: Any = packet
            yaw, fwd, left = p.yaw_rate_dps, p.accel_fwd_mps2, p.accel_left_mps2
            if yaw is None and p.gyro_dps is not None:
                yaw = p.gyro_dps[2]
            if p.accel_mps2 is not None:
                fwd = p.accel_mps2[0] if fwd is None else fwd
                left = p.accel_mps2[1] if left is None else left
            self.values += (p.t, IMU, _NAN if yaw is None else yaw * _DEG,
                            _NAN if fwd is None else fwd, _NAN if left is None else left,
                            _NAN, _NAN, _NAN, _NAN)
        elif kind == ODOMETER:
            o: Any = packet
            self.values += (o.t, ODOMETER, _NAN, _NAN, _NAN,
                            _NAN if o.distance_m is None else o.distance_m,
                            _NAN if o.ticks is None else o.ticks,
                            _NAN if o.speed_mps is None else o.speed_mps, _NAN)
        else:
            a: Any = packet
            self.values += (a.t, STEERING, _NAN, _NAN, _NAN, _NAN, _NAN, _NAN,
                            a.angle_deg * _DEG)

    def take(self) -> tuple[list[int], SampleRun]:
        """The samples' indices and run; empties this one."""
        indices, values = self.indices, self.values
        self.indices, self.values = [], []
        return indices, SampleRun(np.array(values, dtype=np.float64).reshape(-1, N_COLUMNS))


class VehicleSession:
    """Fusion and map matching for one vehicle."""

    def __init__(self, config: SessionConfig = SessionConfig(),
                 graph: RoadGraph | None = None) -> None:
        self.config = config
        self.graph = graph
        self.engine = FusionEngine(config.fusion, frame=graph.frame if graph else None,
                                   ins=config.strapdown,
                                   road_distance=graph.distance_to_road_m if graph else None)
        self.matcher = OnlineMatcher(graph, config.matcher) if graph is not None else None
        self.last_position: MatchedPosition | None = None
        self._last_match_t: float | None = None
        self._last_feedback_t: float | None = None

    @property
    def frame(self) -> LocalFrame | None:
        """The metric frame of positions (the map's; else anchored at the first GPS fix)."""
        return self.engine.frame

    def add_records(self, records: Iterable[Any] | bulk.Batch, first_index: int = 0,
                    skip_truth: bool = True) -> BatchResult:
        """Parse and apply records in order; refuse the bad ones one by one. Simulator ground
        truth (``kind: "truth"``) travels in the same files and is skipped unless
        ``skip_truth`` is False (the service refuses it as an unknown kind).

        ``records``: JSON values, or a :class:`navsvc.wire.bulk.Batch` (a message decoded and
        validated in one call). A list is validated in one call when every record passes
        (:func:`navsvc.wire.bulk.validate_all`), else record by record, with the reasons of
        :mod:`navsvc.wire.packets`. Runs of dead-reckoning samples then go through the
        filter's batched path (:meth:`FusionEngine.add_run`), everything else a packet at a
        time; the matcher steps where it would packet by packet, so the outputs are the same.

        A packet the pipeline fails on (a fault of ours that validation let through) is
        refused as ``unusable`` and the result marked ``faulted``: the caller rebuilds the
        pipeline, since the failure may have left it half updated."""
        if isinstance(records, bulk.Batch):
            return self._add_items(list(records.packets), None, records, first_index)
        source = records if isinstance(records, list) else list(records)
        valid = bulk.validate_all(source)
        items: list[Any] = [self._validate(record, skip_truth) for record in source] \
            if valid is None else list(valid)
        return self._add_items(items, source, None, first_index)

    def add_records_per_packet(self, records: Iterable[Any], first_index: int = 0,
                               skip_truth: bool = True) -> BatchResult:
        """:meth:`add_records` the reference way: each record parsed by
        :mod:`navsvc.wire.packets` and applied alone (``FusionEngine.add``). The batched
        path's outputs are checked against it (``tests/test_batched_session.py``)."""
        result = BatchResult(decoded=[])
        for index, record in enumerate(records, start=first_index):
            if skip_truth and isinstance(record, dict) and record.get("kind") == "truth":
                continue
            try:
                packet, canonical = parse_record(record)
            except PacketError as exc:
                result.rejections.append(Rejection(index, exc.reason, exc.detail))
                continue
            if self._apply_packet(index, packet, result):
                result.accepted += 1
                result.records.append(canonical)
                result.indices.append(index)
        return result

    @staticmethod
    def _validate(record: Any, skip_truth: bool) -> Any:
        """One record: a bulk packet, ``(packet, canonical record)`` from the careful
        parser (other kinds, unknown fields), a :class:`PacketError`, or ``_SKIP``."""
        if skip_truth and isinstance(record, dict) and record.get("kind") == "truth":
            return _SKIP
        packet = bulk.validate_one(record)
        if packet is not None:
            return packet
        try:
            return parse_record(record)
        except PacketError as exc:
            return exc

    def _add_items(self, items: list[Any], records: list[Any] | None,
                   message: bulk.Batch | None, first_index: int) -> BatchResult:
        """Apply validated items (see :meth:`_validate`) of ``records`` (or of ``message``,
        whose text is what the trip log gets when all of it is accepted)."""
        result = BatchResult()
        canonical: dict[int, dict[str, Any]] = {}  # of the records the careful parser took
        run = _Run()
        road = isinstance(self.engine.filter, RoadFilter)
        latest = self.engine.t
        accepted: list[int] = []
        for index, item in enumerate(items, start=first_index):
            kind = _DEAD_RECKONING.get(type(item)) if road else None
            if kind is not None and latest is not None and \
                    latest <= item.t <= latest + MAX_TIME_JUMP_S:
                run.add(index, item, kind)
                latest = item.t
                continue
            if run.indices:
                self._apply_run(run, result, accepted)
            if item is _SKIP:
                continue
            if isinstance(item, PacketError):
                result.rejections.append(Rejection(index, item.reason, item.detail))
                continue
            if isinstance(item, tuple):
                packet, canonical[index] = item
            else:
                packet = bulk.core(item)
            if self._apply_packet(index, packet, result):
                accepted.append(index)
            latest = self.engine.t
        if run.indices:
            self._apply_run(run, result, accepted)
        result.accepted, result.indices = len(accepted), accepted
        if message is not None and len(accepted) == len(items):
            result.encoded = message.text  # as it came: decoded only when asked
        else:
            source = records if records is not None else \
                message.records() if message is not None else []
            result.decoded = [canonical[i] if i in canonical else dict(source[i - first_index])
                              for i in accepted]
        return result

    def _apply_packet(self, index: int, packet: Packet, result: BatchResult) -> bool:
        """One packet through the engine, the per-packet way; False when refused."""
        try:
            self._check_time(packet.t)
            if isinstance(packet, GpsFix):
                self._check_on_map(packet)
            estimates = self.engine.add(packet)
            positions = [self._place(e) for e in estimates]
            if not estimates:
                self._step_matcher()
        except Exception as exc:  # noqa: BLE001 (one packet must not fail the batch)
            self._refuse(result, index, exc)
            return False
        result.positions += positions
        return True

    def _apply_run(self, pending: _Run, result: BatchResult, accepted: list[int]) -> None:
        """Pending samples through the engine as one run, stopping where an estimate is to
        be placed or the matcher is due, as the per-packet path places and steps it."""
        indices, run = pending.take()
        interval = None if self.matcher is None else self.config.match_interval_s
        k = 0
        while k < len(run):
            try:
                end, estimates = self.engine.add_run(run, k, self._last_match_t, interval)
            except Exception as exc:  # noqa: BLE001 (that sample alone is refused)
                self._refuse(result, indices[k], exc)
                k += 1
                continue
            accepted += indices[k:end - 1]
            try:
                positions = [self._place(e) for e in estimates]
                if not estimates:
                    self._step_matcher()
            except Exception as exc:  # noqa: BLE001
                self._refuse(result, indices[end - 1], exc)
            else:
                result.positions += positions
                accepted.append(indices[end - 1])
            k = end

    @staticmethod
    def _refuse(result: BatchResult, index: int, exc: Exception) -> None:
        """A packet the pipeline raised on: its own reason, or ``unusable`` (a fault)."""
        if isinstance(exc, PacketError):
            result.rejections.append(Rejection(index, exc.reason, exc.detail))
            return
        log.error("packet %d could not be applied", index, exc_info=exc)
        result.rejections.append(Rejection(index, RejectReason.UNUSABLE,
                                           f"{type(exc).__name__}: {exc}"))
        result.faulted = True

    def _check_time(self, t: float) -> None:
        """Refuse a jump far into the future: every later packet would be ``time_backwards``
        (a clock in milliseconds, or a stray timestamp, would brick the session)."""
        latest = self.engine.t
        if latest is not None and t > latest + MAX_TIME_JUMP_S:
            raise PacketError(RejectReason.OUT_OF_RANGE,
                              f"t={t!r} is {t - latest:.0f} s after the vehicle's latest packet "
                              f"(t={latest!r}); the limit is {MAX_TIME_JUMP_S:.0f} s (start a "
                              "new session after a longer pause)")

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
            if not estimate.initialized:
                estimate = self.matcher.on_road(estimate)
            position = self.matcher.update(estimate)
            self._last_match_t = estimate.t
            if self.config.map_feedback:
                self._feed_back(position)
        self.last_position = position
        return position

    def _feed_back(self, p: MatchedPosition) -> None:
        """Pull the filter onto a confident match (:func:`feedback_wanted`), at most once a
        second."""
        if p.road_bearing_rad is None or not feedback_wanted(p, self.config):
            return
        e, c = p.estimate, self.config
        if self._last_feedback_t is not None and e.t - self._last_feedback_t < 1.0:
            return
        assert self.matcher is not None and p.edge is not None
        share = self.matcher.road_share(e, EdgeKey(p.edge.u, p.edge.v, p.edge.key))
        self.engine.correct_to_road(p.x_m, p.y_m, p.road_bearing_rad,
                                    c.feedback_sigma_across_m, c.feedback_sigma_heading_rad,
                                    feedback_probability(share))
        self._last_feedback_t = e.t


def feedback_wanted(p: MatchedPosition, c: SessionConfig) -> bool:
    """Whether a match is confident enough to feed back: on a road, outside any ambiguity
    region, moving along it (within 20 degrees) and close to it: within
    ``feedback_max_distance_m``, or farther within ``feedback_gate_sigmas`` of the estimate's
    own uncertainty across the road, so that an outage's drift is pulled back while a wrong
    road far outside the estimate's uncertainty is not followed. Not while the heading is
    unknown (``feedback_max_heading_sigma_rad``: a restart, or a long outage): any road
    lies within 20 degrees of a random heading, and its bearing became the heading with the
    feedback's sigma (steering, Andorra 102 of the tune split: 813 m off, heading sigma 117
    degrees, then 5). Tune split: steering and gyro_accel (ekf, 120 drives each) one drive
    better each (8.8 -> 6.6 and 2.2 -> 1.6x raw), the rest unchanged; gyro_odometer (600)
    unchanged; the rules and fuzzy modes (4 x 80) 4 drives better, 1 worse. A bound of 20
    degrees had steering Monaco 1 lose the feedback that held it (0.39 -> 18x raw)."""
    e, bearing, distance_m = p.estimate, p.road_bearing_rad, p.distance_to_road_m
    if p.state != MatchState.ON_ROAD or bearing is None or p.in_ambiguity_region or \
            distance_m is None or e.speed_mps < 1.0 or \
            e.heading_sigma_rad > c.feedback_max_heading_sigma_rad:
        return False
    gate_m = c.feedback_gate_sigmas * math.hypot(e.position_sigma_m, c.feedback_sigma_across_m)
    return distance_m <= max(c.feedback_max_distance_m, gate_m) and \
        abs(wrap_angle_rad(e.heading_rad - bearing)) <= math.radians(20.0)


def feedback_probability(road_share: float) -> float:
    """How likely the feedback takes a matched road to be the one driven, from its share
    of the likelihood of the roads beside the estimate (:meth:`OnlineMatcher.road_share`):
    sure while it holds at least half (in a dense map the road driven usually has others
    beside it), else twice its share: the estimate has drifted nearer another road than the
    one matched. The filter then takes that share of the constraint's pull and of the
    variance it would remove (:func:`navsvc.fusion.kalman.no_surer_than`), as
    probabilistic data association does. Held to its road at full weight, an estimate after
    an outage sat on a road 20 m from the one driven for a minute while the fixes, 3 m off,
    were taken as a bias (Stockholm 585 of the tune split: 0.85 -> 0.19x raw GPS).

    The rival road used to widen the constraint's sigmas by ``1 / sqrt(2 share)`` instead.
    For an estimate that had lost its place that was still a sure road: one update took a
    sigma of 170 m to 13 m and a heading sigma of 43 degrees to 6, 777 m from the truth
    (steering, Stockholm 120). Tune split against it: default (600 drives) 6 better, 2
    worse (gh-issue-13 39 1.67 -> 0.84x raw GPS); gyro_accel (120) 6 better, 4 worse,
    largest matched error with GPS 620 -> 525 m; steering, gyro_two_accels (120 each)
    unchanged but for Stockholm 120, a lost cause either way (11.7 -> 12.7x). Once pulled
    part of the way, the same road's share grows at the next match: a rivalled road is
    still followed, over several seconds instead of one. Not feeding back at all below a
    quarter of the likelihood (measured with the old widening: default 2 better, none
    worse) added a threshold for no more.

    The rules and fuzzy modes used to feed every road back as sure (their fixes pull too
    little to choose between rival roads, so the map alone held the estimate). With the
    probability (tune split, 120 drives each, mean log fused/raw GPS): gyro_accel rules
    -1.4 % (11 better, 5 worse), fuzzy -1.8 % (10, 7); gyro_odometer rules -0.3 % (3, 0),
    fuzzy +0.1 % (0, 1); steering rules -0.3 % (4, 4), fuzzy -0.1 % (1, 2): one rule for
    every mode."""
    return min(2.0 * road_share, 1.0)


class SessionOptions(BaseModel):
    """What a client chooses when a session starts: the one list of what a session may
    override (the API's body is this plus the vehicle id; the trip log keeps it as its
    JSON; ``navsvc run``, ``tune`` and the benches build it from their flags). Everything
    else is the defaults of :class:`SessionConfig`, or a tuned ``profile``."""

    model_config = ConfigDict(extra="forbid")

    sensors: SensorConfig = Field(SensorConfig.GYRO_ODOMETER, description="sensor configuration")
    fusion: GpsMode = Field(GpsMode.EKF, description="how GPS is fused: ekf, rules or fuzzy")
    map_feedback: bool | None = Field(
        None, description="feed confident matches back into the filter as a road constraint "
        "(bounds drift in GPS outages); default: on")
    ticks_per_m: float | None = Field(None, gt=0, le=10_000,
                                      description="odometer ticks per metre")
    wheelbase_m: float | None = Field(None, gt=0.5, le=20, description="for steering sensors")
    gps_uere_m: float | None = Field(None, gt=0, le=100,
                                     description="GPS error per unit of HDOP, metres")
    ins_integration: Integration | None = Field(
        None, description="strapdown: feedback (default), feedforward or direct "
                          "(the paper's three EKF integrations)")
    ins_mechanisation: Mechanisation | None = Field(
        None, description="strapdown: first_order (default) or rk4")
    imu_mounting_rpy_deg: tuple[float, float, float] | None = Field(
        None, description="strapdown: roll, pitch, yaw of the IMU axes in the vehicle, "
                          "degrees")
    gps_lever_arm_m: tuple[float, float, float] | None = Field(
        None, description="strapdown: GPS antenna from the IMU, forward/right/down, metres")
    profile: dict[str, Any] | None = Field(
        None, description="tuned parameters (`navsvc tune`): the profile document, or its "
        "'parameters' object of dotted names to values")

    def config(self) -> SessionConfig:
        """The session's configuration: these options over the defaults, then the profile.
        Raises ConfigError."""
        fusion, ins = FusionConfig(), StrapdownOptions()
        fusion = FusionConfig(
            sensors=self.sensors, gps_mode=self.fusion,
            ticks_per_m=_or(self.ticks_per_m, fusion.ticks_per_m),
            wheelbase_m=_or(self.wheelbase_m, fusion.wheelbase_m),
            gps_uere_m=_or(self.gps_uere_m, fusion.gps_uere_m))
        strapdown = StrapdownOptions(
            integration=_or(self.ins_integration, ins.integration),
            mechanisation=_or(self.ins_mechanisation, ins.mechanisation),
            mounting_rpy_deg=_or(self.imu_mounting_rpy_deg, ins.mounting_rpy_deg),
            lever_arm_m=_or(self.gps_lever_arm_m, ins.lever_arm_m))
        config = SessionConfig(fusion=fusion, strapdown=strapdown,
                               map_feedback=_or(self.map_feedback, True))
        return apply_profile(config, self.profile)

    def as_dict(self) -> dict[str, Any]:
        """The options as JSON values, unset ones left out (what the trip log keeps)."""
        return self.model_dump(mode="json", exclude_none=True)


def config_from_options(options: dict[str, Any]) -> SessionConfig:
    """A session's configuration from its options as JSON values (:class:`SessionOptions`:
    the trip log's record, a CLI's flags). Raises ConfigError naming what is wrong."""
    try:
        return SessionOptions.model_validate(options).config()
    except ValidationError as exc:
        raise ConfigError("; ".join(
            f"{'.'.join(str(part) for part in e['loc']) or 'options'}: {e['msg']}"
            for e in exc.errors())) from None


T = TypeVar("T")


def _or(value: T | None, default: T) -> T:
    return default if value is None else value


def apply_profile(config: SessionConfig, profile: Any) -> SessionConfig:
    """``config`` with a tuned profile's parameters set (``navsvc tune``; None: unchanged).

    ``profile`` is a profile document (its ``parameters``) or the mapping itself: dotted
    paths into :class:`SessionConfig` to numbers or booleans, e.g.
    ``{"fusion.gps_uere_m": 4.2, "fusion.process.accel_mps2": 0.8,
    "matcher.road_sigma_m": 5.0}``. A path ending ``.scale`` under a fuzzy set
    (``fusion.fuzzy.distance_m.scale``) multiplies every finite corner of its trapezoids.
    Raises ConfigError naming the parameter.
    """
    if profile is None:
        return config
    if not isinstance(profile, dict):
        raise ConfigError("profile: expected an object of parameters")
    parameters = profile.get("parameters", profile)
    if not isinstance(parameters, dict):
        raise ConfigError("profile: 'parameters' must be an object")
    for name, value in parameters.items():
        config = _set_path(config, str(name).split("."), value, str(name))
    return config


def _set_path(obj: Any, path: list[str], value: Any, name: str) -> Any:
    """``obj`` (a frozen dataclass) with the field at ``path`` replaced by ``value``."""
    head, rest = path[0], path[1:]
    if isinstance(obj, dict) and rest == [] and head == "scale":
        factor = _number(value, float, name)
        return {k: tuple(c * factor if math.isfinite(c) else c for c in corners)
                for k, corners in obj.items()}
    known = {f.name for f in fields(obj)} if is_dataclass(obj) else set()
    if head not in known:
        raise ConfigError(f"profile parameter {name!r}: {type(obj).__name__} has no field "
                          f"{head!r}")
    current = getattr(obj, head)
    if rest:
        new = _set_path(current, rest, value, name)
    elif isinstance(current, bool | int | float) and not isinstance(current, enum.Enum):
        new = _number(value, type(current), name)
    else:
        raise ConfigError(f"profile parameter {name!r}: only numbers and booleans may be set")
    try:
        return replace(obj, **{head: new})
    except ConfigError as exc:
        raise ConfigError(f"profile parameter {name!r}: {exc}") from None


def _number(value: Any, kind: type, name: str) -> Any:
    if kind is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"profile parameter {name!r}: expected true or false")
        return value
    if isinstance(value, bool) or not isinstance(value, int | float) or \
            not math.isfinite(value) or (kind is int and value != int(value)):
        raise ConfigError(f"profile parameter {name!r}: expected a finite "
                          f"{'integer' if kind is int else 'number'}, got {value!r}")
    return kind(value)


def owner_of(api_key: str | None) -> str:
    """What the store keeps of an API key: its SHA-256 ('' for the open service)."""
    return hashlib.sha256(key_bytes(api_key)).hexdigest() if api_key else ""


def key_bytes(api_key: str | None) -> bytes:
    """An API key as bytes, whatever characters it holds (a lone surrogate included)."""
    return (api_key or "").encode("utf-8", "surrogatepass")


def batch_reply(result: BatchResult, frame: LocalFrame) -> dict[str, Any]:
    """The JSON of a :class:`navsvc.api.models.BatchReply`; a plain dict, since the WebSocket
    sends it as it is, and building and dumping the model for each message cost more than the
    rest of its reply."""
    return {"accepted": result.accepted, "rejected": [r.to_json() for r in result.rejections],
            "positions": [position_json(p, frame) for p in result.positions]}


# --- checkpoints ------------------------------------------------------------------------
# A checkpoint after every 200 packets (a restart then replays at most that many, ~5 ms of
# work; with 500, 1,000 sessions at 100 Hz took 5.6 s to restore after a crash), but not more
# often than every second (a vehicle sending 1,000 packets a second would otherwise pickle
# its pipeline five times a second). A checkpoint costs ~0.5 ms: 2.5 us a packet.
CHECKPOINT_EVERY_PACKETS = 200
CHECKPOINT_MIN_INTERVAL_S = 1.0
CHECKPOINT_BUDGET_S = 0.001  # deferred checkpoints taken before one group commit, at most
# this long (a reply of that group waits for them)


PICKLED_SOURCES = ("navsvc/fusion", "navsvc/matching", "navsvc/session.py", "navsvc/types.py",
                   "navsvc/errors.py", "roadgraph")  # the code of what a checkpoint holds


@cache
def code_id() -> str:
    """A hash of the source of the classes a checkpoint holds: a checkpoint is only loaded by
    the code that wrote it (pickled objects of changed classes would load, and be wrong)."""
    root = Path(__file__).resolve().parent.parent
    digest = hashlib.sha256()
    for name in PICKLED_SOURCES:
        path = root / name
        for source in sorted(path.rglob("*.py")) if path.is_dir() else [path]:
            digest.update(source.relative_to(root).as_posix().encode())
            digest.update(source.read_bytes())
    return digest.hexdigest()


class _Pickler(pickle.Pickler):
    """Pickles a vehicle's pipeline without the road graph (shared, read-only, reopened)."""

    def __init__(self, file: io.BytesIO, graph: RoadGraph) -> None:
        super().__init__(file, protocol=pickle.HIGHEST_PROTOCOL)
        self._shared = {id(graph): "graph", id(graph.frame): "frame"}

    def persistent_id(self, obj: Any) -> str | None:
        return self._shared.get(id(obj))


class _Unpickler(pickle.Unpickler):
    def __init__(self, file: io.BytesIO, graph: RoadGraph) -> None:
        super().__init__(file)
        self._shared = {"graph": graph, "frame": graph.frame}

    def persistent_load(self, pid: Any) -> Any:
        return self._shared[pid]


def dump_vehicle(vehicle: VehicleSession, graph: RoadGraph) -> bytes:
    """A vehicle's pipeline (engine and matcher state) as bytes, for the trip log.

    pickle: the trip log is the server's own file, never a client's input."""
    buffer = io.BytesIO()
    _Pickler(buffer, graph).dump((code_id(), vehicle))
    return buffer.getvalue()


def load_vehicle(data: bytes, graph: RoadGraph) -> VehicleSession | None:
    """The pipeline :func:`dump_vehicle` saved, or None when other code wrote it."""
    written_by, vehicle = _Unpickler(io.BytesIO(data), graph).load()
    return vehicle if written_by == code_id() and isinstance(vehicle, VehicleSession) else None


def _finish(steps: Generator[None, None, LiveSession]) -> LiveSession:
    """Run a stepwise rebuild to its end."""
    while True:
        try:
            next(steps)
        except StopIteration as done:
            session: LiveSession = done.value
            return session


REPLIES_KEPT = 64  # replies to numbered batches kept per session, to answer resends
MAX_CLIENT_SEQ = 2**53  # a client's batch number, at most (JSON numbers are exact up to it)
REPLAY_STEP_BATCHES = 50  # a background rebuild replays this many batches between requests


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
    last_batch_rowid: int = 0  # the trip-log row of the last batch applied
    checkpoint_packets: int = 0  # packets + rejected at the last checkpoint
    checkpoint_clock: float = 0.0  # store clock at the last checkpoint
    replies: OrderedDict[int, dict[str, Any]] = field(default_factory=OrderedDict)

    @property
    def last_client_seq(self) -> int | None:
        return next(reversed(self.replies)) if self.replies else None

    def logged(self) -> LoggedSession:
        return LoggedSession(self.id, self.owner, self.vehicle_id, self.options,
                             self.created_unix)


@dataclass(frozen=True)
class Ingested:
    """A batch's reply, and what it did (None: a resend answered from memory)."""

    reply: dict[str, Any]
    result: BatchResult | None
    group: CommitGroup | None = None  # with ``defer_commit``: the reply waits for its commit


class SessionStore:
    """The live sessions, backed by a trip log.

    After a restart the open sessions of the log are known at once but rebuilt as they are
    needed (:meth:`reopen`): a session a request names is rebuilt then, the rest one at a
    time by :meth:`restore_next`, a step of a few batches at a time (the API calls it between
    requests), so the server answers from its first second whatever the number of sessions
    and however long a log without a checkpoint is."""

    def __init__(self, graph: RoadGraph, triplog: TripLog, *, idle_timeout_s: float = 3600.0,
                 max_sessions_per_owner: int = 10_000,
                 clock: Callable[[], float] = time.monotonic, id_prefix: str = "") -> None:
        self.graph = graph
        self.id_prefix = id_prefix  # a worker's: the balancer routes on it (navsvc.cluster)
        self.triplog = triplog
        self.idle_timeout_s = idle_timeout_s
        self.max_sessions_per_owner = max_sessions_per_owner
        self._clock = clock
        self._sessions: dict[str, LiveSession] = {}
        self._pending: dict[str, LoggedSession] = {}  # open in the log, not rebuilt yet
        # the one being rebuilt in the background, a step at a time
        self._rebuilding: dict[str, tuple[LoggedSession, Generator[None, None, LiveSession]]] \
            = {}
        self._group: CommitGroup | None = None  # the trip log's open group, as last seen
        self._uncommitted: dict[str, LiveSession] = {}  # sessions with batches in it
        self._due: dict[str, LiveSession] = {}  # deferred checkpoints, oldest first

    def __len__(self) -> int:
        return len(self._sessions) + len(self._pending) + len(self._rebuilding)

    def _not_rebuilt(self) -> list[LoggedSession]:
        return [*self._pending.values(), *(logged for logged, _ in self._rebuilding.values())]

    def create(self, owner: str, vehicle_id: str, options: dict[str, Any]) -> LiveSession:
        """Start a session (options as in :func:`config_from_options`)."""
        config = config_from_options(options)
        owned = sum(s.owner == owner for s in self._sessions.values()) + \
            sum(p.owner == owner for p in self._not_rebuilt())
        if owned >= self.max_sessions_per_owner:
            raise LimitExceeded(f"this API key already has {owned} sessions; the limit is "
                                f"{self.max_sessions_per_owner}")
        now = self._clock()
        session = LiveSession(id=self.id_prefix + secrets.token_hex(8), owner=owner,
                              vehicle_id=vehicle_id,
                              options=options, created_unix=time.time(),
                              vehicle=VehicleSession(config, self.graph), last_seen=now,
                              checkpoint_clock=now)
        self.triplog.create_session(session.logged())
        self._sessions[session.id] = session
        log.info("session %s created for vehicle %r (%s)", session.id, vehicle_id, options)
        return session

    def get(self, session_id: str, owner: str) -> LiveSession:
        self._rebuild_now(session_id, owner)
        session = self._sessions.get(session_id)
        if session is None or session.owner != owner:
            raise SessionNotFound(f"no session {session_id!r}")
        return session

    def sessions(self, owner: str) -> list[LiveSession]:
        for logged in [p for p in self._not_rebuilt() if p.owner == owner]:
            self._rebuild_now(logged.id, owner)
        return [s for s in self._sessions.values() if s.owner == owner]

    def _rebuild_now(self, session_id: str, owner: str) -> None:
        """Finish rebuilding a session of the owner's that is not rebuilt yet, if it is one."""
        rebuilding = self._rebuilding.get(session_id)
        if rebuilding is not None and rebuilding[0].owner == owner:
            del self._rebuilding[session_id]
            self._install(_finish(rebuilding[1]))
        pending = self._pending.get(session_id)
        if pending is not None and pending.owner == owner:
            self._install(self._load(self._pending.pop(session_id)))

    def ingest(self, session: LiveSession, records: list[Any] | bulk.Batch,
               client_seq: int | None = None, defer_commit: bool = False) -> Ingested:
        """Apply a batch and log it as one unit; returns once it is on disk.

        ``defer_commit``: the batch joins the trip log's open :class:`CommitGroup` instead,
        returned as ``Ingested.group``; the reply must wait for that group's commit
        (:meth:`TripLog.commit`). If the group is lost (the commit fails), every session with
        a batch in it is rebuilt from the log, as below, and the group's waiters learn the
        error: none of its batches was acknowledged.

        ``client_seq``, the client's number for the batch (increasing per session), makes a
        resend safe: a batch numbered at or below the last one is not applied again but
        answered with its original reply (``"duplicate": true``), or refused with
        :class:`BatchAlreadyApplied` when that reply is no longer kept.

        If the log cannot be written the session is rebuilt from its log, so that memory
        never holds packets the log lacks, and the error propagates (nothing acknowledged).
        """
        last = session.last_client_seq
        if client_seq is not None and last is not None and client_seq <= last:
            kept = session.replies.get(client_seq)
            if kept is None:
                raise BatchAlreadyApplied(
                    f"batch {client_seq} is not after the session's last numbered batch "
                    f"({last}): either it was applied already and its reply is no longer kept "
                    f"(the last {REPLIES_KEPT} are), or the numbers went backwards")
            # answered once the batch it repeats is committed, if it is not yet
            return Ingested({**kept, "duplicate": True}, None,
                            self._group if session.id in self._uncommitted else None)
        result = self._apply(session, records)
        reply = batch_reply(result, self.graph.frame)
        try:
            session.last_batch_rowid = self.triplog.append(
                session.id, session.packets, result.records if result.encoded is None else
                result.accepted, len(result.rejections), client_seq,
                reply if client_seq is not None else None, result.encoded,
                not defer_commit)  # commit
        except sqlite3.Error:
            log.exception("session %s: trip log write failed; rebuilding from the log",
                          session.id)
            self._sessions[session.id] = self._load(session.logged())
            raise
        session.packets += result.accepted
        session.rejected += len(result.rejections)
        session.last_seen = self._clock()
        if client_seq is not None:
            session.replies[client_seq] = reply
            if len(session.replies) > REPLIES_KEPT:
                session.replies.popitem(last=False)
        group = self.triplog.group if defer_commit else None
        if group is not None:
            self._watch(group, session)
        if self._checkpoint_is_due(session):
            if defer_commit:  # taken by checkpoint_due, a few before each group's commit
                self._due[session.id] = session
            else:
                self.checkpoint(session)
        return Ingested(reply, result, group)

    def _watch(self, group: CommitGroup, session: LiveSession) -> None:
        """Note that ``session`` has a batch in ``group``, to rebuild it should the group be
        lost."""
        if group is not self._group:
            self._group, self._uncommitted = group, {}
            sessions = self._uncommitted
            group.when_done(lambda error: self._group_done(sessions, error))
        self._uncommitted[session.id] = session

    def _group_done(self, sessions: dict[str, LiveSession], error: BaseException | None
                    ) -> None:
        """A commit group's end. When it was rolled back, rebuild its sessions from the log,
        so that memory never holds packets the log lacks."""
        for session_id, session in sessions.items() if error is not None else ():
            if session_id in self._sessions:
                log.error("session %s: trip log commit failed; rebuilding from the log",
                          session_id)
                self._sessions[session_id] = self._load(session.logged())
        if sessions is self._uncommitted:
            self._group, self._uncommitted = None, {}

    def _apply(self, session: LiveSession, records: list[Any] | bulk.Batch) -> BatchResult:
        """The batch applied to the session's pipeline; after a fault, the pipeline is rebuilt
        from the log and the batch's usable packets applied again."""
        result = session.vehicle.add_records(records, skip_truth=False)
        while result.faulted:
            log.warning("session %s: rebuilding the pipeline after a fault", session.id)
            session.vehicle = self._load(session.logged()).vehicle
            again = session.vehicle.add_records(result.records)
            refused = [Rejection(result.indices[r.index], r.reason, r.detail)
                       for r in again.rejections]
            result = BatchResult(
                positions=again.positions, accepted=again.accepted, faulted=again.faulted,
                rejections=sorted(result.rejections + refused, key=lambda r: r.index),
                decoded=again.records, indices=[result.indices[i] for i in again.indices])
        return result

    def _checkpoint_is_due(self, session: LiveSession) -> bool:
        return session.packets + session.rejected - session.checkpoint_packets >= \
            CHECKPOINT_EVERY_PACKETS and \
            self._clock() - session.checkpoint_clock >= CHECKPOINT_MIN_INTERVAL_S

    def checkpoint_due(self, budget_s: float = CHECKPOINT_BUDGET_S) -> int:
        """Checkpoint the sessions that came due in deferred-commit ingests, oldest first,
        until ``budget_s`` is spent (one at least); return how many. Called just before each
        group's commit, so that the checkpoints join it.

        Why deferred: sessions that started together come due together (200 sessions at
        101 packets/s all passed 200 packets in the same 0.1 s, every 2 s), and 200
        checkpoints of ~0.3 ms in one turn of the event loop held every reply of that turn:
        p99 latency 81 ms at 200 real-rate sessions (bench/service_load.py). A session
        replaced meanwhile (rebuilt after a lost group) or closed is skipped."""
        start, done = self._clock(), 0
        while self._due:
            session_id = next(iter(self._due))
            session = self._due.pop(session_id)
            if self._sessions.get(session_id) is not session:
                continue
            self.checkpoint(session)
            done += 1
            if self._clock() - start >= budget_s:
                break
        return done

    def checkpoint(self, session: LiveSession) -> None:
        """Save the session's pipeline, so that a restart replays only what follows. A failure
        costs only time at the next restart: the log has every batch."""
        try:
            self.triplog.save_checkpoint(session.id, Checkpoint(
                session.last_batch_rowid, session.packets, session.rejected,
                dump_vehicle(session.vehicle, self.graph)))
        except (sqlite3.Error, pickle.PicklingError) as exc:
            log.warning("session %s: checkpoint not saved: %s", session.id, exc)
            return
        session.checkpoint_packets = session.packets + session.rejected
        session.checkpoint_clock = self._clock()

    def checkpoint_all(self) -> None:
        """Checkpoint every session with packets since its last (at shutdown)."""
        self._due.clear()
        for session in self._sessions.values():
            if session.packets + session.rejected != session.checkpoint_packets:
                self.checkpoint(session)

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

    def reopen(self) -> int:
        """Take the open sessions of the trip log (after a restart), to be rebuilt as they
        are needed; return how many."""
        self._pending = {s.id: s for s in self.triplog.open_sessions()
                         if s.id not in self._sessions}
        return len(self._pending)

    def restore_next(self) -> bool:
        """One step of rebuilding the sessions taken by :meth:`reopen` (a few batches of
        one); False when none is left."""
        if self._rebuilding:
            session_id, (logged, steps) = next(iter(self._rebuilding.items()))
            try:
                next(steps)
            except StopIteration as done:
                del self._rebuilding[session_id]
                self._install(done.value)
            return True
        if not self._pending:
            return False
        logged = self._pending.pop(next(iter(self._pending)))
        self._rebuilding[logged.id] = (logged, self._loading(logged))
        return True

    def restore(self) -> int:
        """Rebuild every open session of the trip log now; return how many there are."""
        self.reopen()
        while self.restore_next():
            pass
        return len(self._sessions)

    def _install(self, session: LiveSession) -> None:
        self._sessions[session.id] = session
        log.debug("session %s restored: %d packets", session.id, session.packets)

    def _load(self, logged: LoggedSession) -> LiveSession:
        """A session rebuilt from the trip log, all at once."""
        return _finish(self._loading(logged))

    def _loading(self, logged: LoggedSession) -> Generator[None, None, LiveSession]:
        """A session rebuilt from the trip log: its last checkpoint, then the batches logged
        after it (all of them when there is no usable checkpoint), pausing (yielding) after
        every ``REPLAY_STEP_BATCHES``; returns the session."""
        checkpoint = self.triplog.checkpoint(logged.id)
        vehicle = None
        if checkpoint is not None:
            try:
                vehicle = load_vehicle(checkpoint.state, self.graph)
            except Exception as exc:  # noqa: BLE001 (an unreadable checkpoint: replay all)
                log.warning("session %s: checkpoint unreadable (%s); replaying its log",
                            logged.id, exc)
        if vehicle is None or checkpoint is None:
            vehicle = VehicleSession(config_from_options(logged.options), self.graph)
            checkpoint = Checkpoint(0, 0, 0, b"")
        now = self._clock()
        session = LiveSession(id=logged.id, owner=logged.owner, vehicle_id=logged.vehicle_id,
                              options=logged.options, created_unix=logged.created_unix,
                              vehicle=vehicle, packets=checkpoint.packets,
                              rejected=checkpoint.rejected, last_seen=now,
                              last_batch_rowid=checkpoint.batch_rowid, checkpoint_clock=now)
        while batches := self.triplog.batches_after(logged.id, session.last_batch_rowid,
                                                    REPLAY_STEP_BATCHES):
            for batch in batches:
                replayed = vehicle.add_records(batch.records, skip_truth=False)
                if replayed.faulted:  # cannot happen to validated packets; say so if it does
                    log.error("session %s: logged batch %d failed to replay", logged.id,
                              batch.rowid)
                session.packets += len(batch.records)
                session.rejected += batch.rejected
                session.last_batch_rowid = batch.rowid
            yield
        session.checkpoint_packets = checkpoint.packets + checkpoint.rejected
        for logged_reply in self.triplog.last_replies(logged.id, REPLIES_KEPT):
            session.replies[logged_reply.client_seq] = logged_reply.reply
        return session

    def _close(self, session_id: str) -> None:
        self.triplog.close_session(session_id)
        del self._sessions[session_id]
        self._due.pop(session_id, None)

    def checkpoint_lag(self) -> tuple[int, float]:
        """Packets logged since their session's last checkpoint, over all live sessions (what
        a restart would replay), and the longest time in seconds since a checkpoint of a
        session that has such packets."""
        now, packets, seconds = self._clock(), 0, 0.0
        for s in self._sessions.values():
            if (behind := s.packets + s.rejected - s.checkpoint_packets) > 0:
                packets += behind
                seconds = max(seconds, now - s.checkpoint_clock)
        return packets, seconds
