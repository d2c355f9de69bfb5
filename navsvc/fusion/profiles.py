"""Sensor configurations as data (pure): one frozen :class:`Profile` per configuration.

Seed: Mayhew 1999, chapter 4 (four dead-reckoning configurations; the thesis chose gyro +
odometer), plus GPS alone and a full 6-axis IMU (Giroux, Gourdeau, Landry 2005). A profile says
which filter runs, which packet kinds the vehicle sends, which measurement models the filter
fuses, and the few model choices that differ; the engine, the filters and the session read
this table instead of branching on the configuration.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from navsvc.fusion.ins.measurements import (
    AcrossRoad,
    BodyVelocity,
    GnssPosition,
    GnssVelocity,
    Rest,
)
from navsvc.fusion.road.measurements import (
    CourseAndSpeed,
    GpsPosition,
    GpsVelocity,
    GyroRate,
    LateralAccel,
    OdometerSpeed,
    RoadConstraint,
    SteeringRate,
    ZeroMotion,
)


class SensorConfig(enum.Enum):
    """Which sensors a vehicle has (thesis chapter 4, plus GPS only and a strapdown IMU)."""

    GYRO_ODOMETER = "gyro_odometer"  # thesis config 2: the one it chose
    STEERING_ODOMETER = "steering_odometer"  # config 1: bicycle model
    GYRO_ACCEL = "gyro_accel"  # config 3: speed from the forward accelerometer
    GYRO_TWO_ACCELS = "gyro_two_accels"  # config 4: plus lateral acceleration
    GPS_ONLY = "gps_only"  # constant turn rate and velocity, GPS alone
    STRAPDOWN = "strapdown"  # full 6-axis IMU: the strapdown INS (navsvc.fusion.ins)


class GpsMode(enum.Enum):
    """How the road filter fuses GPS: Kalman update (gated), thesis 5.4 rules, 5.5 fuzzy."""

    EKF = "ekf"
    RULES = "rules"
    FUZZY = "fuzzy"


class FilterKind(enum.Enum):
    ROAD = "road"  # the 8-state road-vehicle EKF: navsvc.fusion.road.filter.RoadFilter
    INS = "ins"  # the strapdown INS: navsvc.fusion.ins.strapdown.StrapdownFilter


@dataclass(frozen=True)
class Profile:
    """One sensor configuration: what runs, what comes in, what is fused."""

    sensors: SensorConfig
    filter: FilterKind
    packets: frozenset[str]  # wire kinds the vehicle sends (GPS always)
    measurements: frozenset[type]  # the measurement models the filter fuses
    gps_modes: frozenset[GpsMode] = frozenset(GpsMode)
    ekf_only_reason: str = ""  # the refusal when gps_modes is only ekf
    speed_from_accel: bool = False  # speed integrates the forward accelerometer (configs 3, 4)
    turn_rate_tau_s: float | None = None  # Gauss-Markov turn rate unless the config sets one
    gps_alone: bool = False  # no dead reckoning: GPS course ungated, a slow fix is a stop

    @property
    def gyro(self) -> bool:
        """The gyro rate enters with each IMU sample's prediction."""
        return GyroRate in self.measurements


_GPS = frozenset({GpsPosition, GpsVelocity, CourseAndSpeed, RoadConstraint})
_EKF = frozenset({GpsMode.EKF})

PROFILES: dict[SensorConfig, Profile] = {p.sensors: p for p in (
    Profile(SensorConfig.GYRO_ODOMETER, FilterKind.ROAD, frozenset({"imu", "odometer", "gps"}),
            _GPS | {GyroRate, OdometerSpeed, ZeroMotion}),
    Profile(SensorConfig.STEERING_ODOMETER, FilterKind.ROAD,
            frozenset({"steering", "odometer", "gps"}),
            _GPS | {SteeringRate, OdometerSpeed, ZeroMotion}),
    Profile(SensorConfig.GYRO_ACCEL, FilterKind.ROAD, frozenset({"imu", "gps"}),
            _GPS | {GyroRate}, speed_from_accel=True),
    Profile(SensorConfig.GYRO_TWO_ACCELS, FilterKind.ROAD, frozenset({"imu", "gps"}),
            _GPS | {GyroRate, LateralAccel}, speed_from_accel=True),
    Profile(SensorConfig.GPS_ONLY, FilterKind.ROAD, frozenset({"gps"}),
            _GPS | {ZeroMotion}, gps_modes=_EKF,
            ekf_only_reason="gps_only needs gps_mode ekf: the rules and fuzzy modes blend GPS "
                            "into dead reckoning, and gps_only has none",
            turn_rate_tau_s=3.0, gps_alone=True),
    Profile(SensorConfig.STRAPDOWN, FilterKind.INS, frozenset({"imu", "odometer", "gps"}),
            frozenset({GnssPosition, GnssVelocity, BodyVelocity, Rest, AcrossRoad}),
            gps_modes=_EKF,
            ekf_only_reason="strapdown fuses GPS in its error-state EKF: fusion must be ekf"),
)}
