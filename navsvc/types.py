"""The core values that cross modules: sensor packets, fused estimates, matched positions.

Read this file first. Everything here is SI and radians; headings are clockwise from north
(the compass convention of :mod:`roadgraph.geometry`). Geodetic coordinates appear only as
``lat_deg``/``lon_deg`` on GPS fixes; everything else is in the map's local metres.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np


class GpsFixType(enum.Enum):
    NONE = "none"
    FIX_2D = "2d"
    FIX_3D = "3d"
    DGPS = "dgps"
    RTK = "rtk"


@dataclass(frozen=True)
class GpsFix:
    """One GPS epoch. ``status_ok`` is the receiver's own verdict (Oncore status byte, NMEA)."""

    t: float
    lat_deg: float
    lon_deg: float
    alt_m: float | None = None
    speed_mps: float | None = None
    heading_rad: float | None = None  # course over ground, clockwise from north
    hdop: float | None = None
    sats: int | None = None
    fix: GpsFixType | None = None
    accuracy_m: float | None = None  # 1-sigma horizontal, when the receiver says
    status_ok: bool = True


@dataclass(frozen=True)
class ImuSample:
    """Inertial sample. ``yaw_rate_rps`` is z-up, positive turning left (as on the wire)."""

    t: float
    yaw_rate_rps: float | None = None
    accel_fwd_mps2: float | None = None
    accel_left_mps2: float | None = None
    gyro_rps: tuple[float, float, float] | None = None  # body x fwd, y left, z up
    accel_mps2: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class OdometerSample:
    """Wheel odometer: cumulative distance, cumulative ticks, or a speed."""

    t: float
    distance_m: float | None = None
    ticks: int | None = None
    speed_mps: float | None = None


@dataclass(frozen=True)
class SteeringSample:
    """Front-wheel steering angle, positive left."""

    t: float
    angle_rad: float


@dataclass(frozen=True)
class GpsVelocity:
    """Ground speed and course without a position (NMEA VTG)."""

    t: float
    speed_mps: float
    heading_rad: float | None


Packet = GpsFix | GpsVelocity | ImuSample | OdometerSample | SteeringSample


@dataclass(frozen=True)
class GpsUsage:
    """How the fusion used the last GPS fix (reported with each estimate)."""

    used: bool
    weight: float  # 1 = fully trusted (EKF update accepted), 0 = ignored
    reason: str  # e.g. "accepted", "gated: innovation too large", "receiver status bad"
    nis: float | None = None


@dataclass(frozen=True)
class FusedEstimate:
    """The fusion engine's unconstrained estimate at one instant, in local metres."""

    t: float
    x_m: float
    y_m: float
    heading_rad: float
    speed_mps: float
    yaw_rate_rps: float  # heading rate, clockwise positive (= minus the gyro's z rate)
    position_cov_m2: np.ndarray = field(repr=False)  # 2x2, (x, y)
    heading_sigma_rad: float = 0.0
    initialized: bool = True
    gps: GpsUsage | None = None
    gps_bias_var_m2: float = 0.0  # of position_cov, the GPS error that no averaging removes
    # (and the latest disagreement with a fix): not the track's own uncertainty

    @cached_property
    def position_sigma_m(self) -> float:
        """1-sigma horizontal uncertainty: sqrt of the mean of the covariance's eigenvalues."""
        c = self.position_cov_m2
        return math.sqrt(max((float(c[0, 0]) + float(c[1, 1])) / 2.0, 0.0))

    @cached_property
    def tracking_sigma_m(self) -> float:
        """The uncertainty without the GPS bias: how far the track itself may wander (the
        matcher's road spread already allows for a fix's steady offset from the road)."""
        c = self.position_cov_m2
        return math.sqrt(max((float(c[0, 0]) + float(c[1, 1])) / 2.0 - self.gps_bias_var_m2,
                             0.0))


class MatchState(enum.Enum):
    INITIALIZING = "initializing"
    ON_ROAD = "on_road"
    AMBIGUOUS = "ambiguous"
    OFF_ROAD = "off_road"
    LOST = "lost"


@dataclass(frozen=True)
class EdgeRef:
    """The road a position is matched to, as reported to clients."""

    u: int
    v: int
    key: int
    osm_way_ids: tuple[int, ...]
    name: str | None
    offset_m: float
    length_m: float


@dataclass(frozen=True)
class MatchedPosition:
    """What a client receives at each GPS epoch: the estimate and where it is on the map."""

    estimate: FusedEstimate
    state: MatchState
    x_m: float  # on the road when matched, else the estimate
    y_m: float
    edge: EdgeRef | None = None
    distance_to_road_m: float | None = None
    candidates: tuple[tuple[EdgeRef, float], ...] = ()
    next_node: int | None = None
    distance_to_next_node_m: float | None = None
    road_bearing_rad: float | None = None  # the matched road's direction at (x_m, y_m)
    in_ambiguity_region: bool = False  # near an intersection, the road not yet committed
