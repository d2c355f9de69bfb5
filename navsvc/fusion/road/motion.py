"""Process and measurement models of the road-vehicle filter (pure).

Seed: Mayhew 1999, chapter 4 (four sensor configurations, discrete models at the inertial
rate) and chapter 5 (an EKF whose measurements are the gyro rate and the odometer). One state
layout serves every configuration; a configuration only decides how each sensor enters.

State ``x`` (8), units in brackets::

    0 X_M            east position in the map frame [m]
    1 Y_M            north position [m]
    2 HEADING        heading, clockwise from north [rad]
    3 SPEED          forward speed [m/s]
    4 HEADING_RATE   heading rate, clockwise positive [rad/s] (= minus the gyro's z-up rate)
    5 GYRO_BIAS      gyro z-rate bias [rad/s]; with steering + odometer (no gyro), the
                     steering-angle bias [rad] instead
    6 ODO_SCALE      odometer scale factor (measured = scale x true) [-]
    7 ACCEL_BIAS     forward accelerometer bias [m/s²]

Measurement models return ``(z, h, H, R)``: the measurement, its prediction from ``x``, the
Jacobian and the noise covariance.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from navsvc.fusion import kalman
from navsvc.fusion._jit import Array, jit

X_M, Y_M, HEADING, SPEED, HEADING_RATE, GYRO_BIAS, ODO_SCALE, ACCEL_BIAS = range(8)
N_STATES = 8


class SensorConfig(enum.Enum):
    """Which dead-reckoning sensors a vehicle has (thesis chapter 4, plus GPS only)."""

    GYRO_ODOMETER = "gyro_odometer"  # thesis config 2: the one it chose
    STEERING_ODOMETER = "steering_odometer"  # config 1: bicycle model
    GYRO_ACCEL = "gyro_accel"  # config 3: speed from the forward accelerometer
    GYRO_TWO_ACCELS = "gyro_two_accels"  # config 4: plus lateral acceleration
    GPS_ONLY = "gps_only"  # constant turn rate and velocity, GPS alone
    STRAPDOWN = "strapdown"  # full 6-axis IMU: the strapdown INS (fusion/strapdown.py)

    @property
    def speed_from_accel(self) -> bool:
        return self in (SensorConfig.GYRO_ACCEL, SensorConfig.GYRO_TWO_ACCELS)


@dataclass(frozen=True)
class ProcessNoise:
    """Random-walk spectral densities of the process model."""

    accel_mps2: float = 1.5  # unmodelled longitudinal acceleration (speed random walk)
    heading_accel_rps2: float = 0.4  # unmodelled change of heading rate
    gyro_bias_drift_rps_per_sqrt_s: float = 2e-4
    odo_scale_drift_per_sqrt_s: float = 1e-5
    accel_bias_drift_mps2_per_sqrt_s: float = 1e-3
    turn_rate_tau_s: float | None = None  # GPS only: the turn rate decays with this time
    accel_integration_mps2: float = 0.3  # speed noise when it integrates the accelerometer

    @cached_property
    def densities(self) -> Array:
        """Diagonal of Q per second (speed a random walk)."""
        return np.array([0.0, 0.0, 0.0, self.accel_mps2 ** 2, self.heading_accel_rps2 ** 2,
                         self.gyro_bias_drift_rps_per_sqrt_s ** 2,
                         self.odo_scale_drift_per_sqrt_s ** 2,
                         self.accel_bias_drift_mps2_per_sqrt_s ** 2])

    @cached_property
    def densities_with_accel(self) -> Array:
        """Diagonal of Q per second when the speed integrates the accelerometer."""
        q = self.densities.copy()
        q[SPEED] = self.accel_integration_mps2 ** 2
        return q


def propagate(x: Array, dt_s: float, accel_fwd_mps2: float | None,
              noise: ProcessNoise) -> tuple[Array, Array, Array]:
    """One step of the kinematic model: new state, Jacobian ``F`` and the diagonal of the
    process noise ``Q`` (it is diagonal: independent random walks).

    With ``accel_fwd_mps2`` (configs 3 and 4) the speed integrates the bias-corrected forward
    acceleration; otherwise it is a random walk that the odometer or GPS pins down. With
    ``noise.turn_rate_tau_s`` (GPS only: no sensor measures the turn rate) the turn rate is a
    first-order Gauss-Markov process, so a turn does not go on for ever in an outage.
    """
    return _propagate(x, dt_s, *_model_args(accel_fwd_mps2, noise))


def predict(x: Array, P: Array, dt_s: float, max_step_s: float, accel_fwd_mps2: float | None,
            noise: ProcessNoise) -> tuple[Array, Array]:
    """State and covariance ``dt_s`` on, in steps of at most ``max_step_s`` (each
    :func:`propagate`, then ``F P Fᵀ + Q``), in one compiled call: the filter makes one per
    inertial sample, and one per GPS fix in a GPS-only session."""
    return _predict(x, P, dt_s, max_step_s, *_model_args(accel_fwd_mps2, noise))


def predict_with_gyro(x: Array, P: Array, dt_s: float, max_step_s: float,
                      accel_fwd_mps2: float | None, noise: ProcessNoise,
                      yaw_rate_left_rps: float, sigma_rps: float) -> tuple[Array, Array]:
    """:func:`predict`, then the :func:`gyro_rate` update (not gated), in one compiled call:
    the filter's step at every gyro sample, where two calls and the measurement's small
    arrays cost more than the arithmetic."""
    return _predict_with_gyro(x, P, dt_s, max_step_s, *_model_args(accel_fwd_mps2, noise),
                              yaw_rate_left_rps, sigma_rps ** 2)


def _model_args(accel_fwd_mps2: float | None,
                noise: ProcessNoise) -> tuple[float, Array, float]:
    """The compiled model's arguments: acceleration, Q densities, turn-rate time constant
    (NaN for "none", as the kernels take no Nones)."""
    tau = math.nan if noise.turn_rate_tau_s is None else noise.turn_rate_tau_s
    if accel_fwd_mps2 is None:
        return math.nan, noise.densities, tau
    return accel_fwd_mps2, noise.densities_with_accel, tau


@jit
def _predict(x: Array, P: Array, dt_s: float, max_step_s: float, accel_fwd_mps2: float,
             densities: Array, turn_rate_tau_s: float
             ) -> tuple[Array, Array]:  # pragma: no cover - compiled
    remaining = dt_s
    while remaining > 1e-9:
        step = min(remaining, max_step_s)
        x, F, q = _propagate(x, step, accel_fwd_mps2, densities, turn_rate_tau_s)
        P = kalman.predict(P, F, q)
        remaining -= step
    return x, P


@jit
def _predict_with_gyro(x: Array, P: Array, dt_s: float, max_step_s: float,
                       accel_fwd_mps2: float, densities: Array, turn_rate_tau_s: float,
                       yaw_rate_left_rps: float, variance: float
                       ) -> tuple[Array, Array]:  # pragma: no cover - compiled
    x, P = _predict(x, P, dt_s, max_step_s, accel_fwd_mps2, densities, turn_rate_tau_s)
    x_new, P_new, nis = kalman.correct_compiled(
        x, P, np.array([yaw_rate_left_rps]), np.array([_gyro_rate_h(x)]), _GYRO_RATE_H,
        np.array([[variance]]), np.inf)
    if nis <= np.inf:  # a NaN innovation leaves the state as it was
        x_new[HEADING] %= 2.0 * math.pi
    return x_new, P_new


@jit
def _propagate(x: Array, dt_s: float, accel_fwd_mps2: float, densities: Array,
               turn_rate_tau_s: float) -> tuple[Array, Array, Array]:  # pragma: no cover
    heading, speed, rate = x[HEADING], x[SPEED], x[HEADING_RATE]
    mid = heading + 0.5 * rate * dt_s
    s, c = math.sin(mid), math.cos(mid)
    vs, vc = speed * s * dt_s, speed * c * dt_s
    F = np.eye(N_STATES)
    F[X_M, HEADING] = vc
    F[X_M, SPEED] = s * dt_s
    F[X_M, HEADING_RATE] = 0.5 * vc * dt_s
    F[Y_M, HEADING] = -vs
    F[Y_M, SPEED] = c * dt_s
    F[Y_M, HEADING_RATE] = -0.5 * vs * dt_s
    F[HEADING, HEADING_RATE] = dt_s
    x_next = x.copy()
    x_next[X_M] += vs
    x_next[Y_M] += vc
    x_next[HEADING] = (heading + rate * dt_s) % (2.0 * math.pi)
    if not math.isnan(accel_fwd_mps2):  # speed integrates the accelerometer
        x_next[SPEED] += (accel_fwd_mps2 - x[ACCEL_BIAS]) * dt_s
        F[SPEED, ACCEL_BIAS] = -dt_s
    x_next[SPEED] = max(x_next[SPEED], 0.0)
    if not math.isnan(turn_rate_tau_s):
        decay = math.exp(-dt_s / turn_rate_tau_s)
        F[HEADING_RATE, HEADING_RATE] = decay
        x_next[HEADING_RATE] = rate * decay
    return x_next, F, densities * dt_s


Measurement = tuple[Array, Array, Array, Array]


def _row(**entries: float) -> Array:
    H = np.zeros((1, N_STATES))
    for name, value in entries.items():
        H[0, _INDEX[name]] = value
    return H


_INDEX = {"x": X_M, "y": Y_M, "heading": HEADING, "speed": SPEED, "rate": HEADING_RATE,
          "gyro_bias": GYRO_BIAS, "odo_scale": ODO_SCALE, "accel_bias": ACCEL_BIAS}
_GYRO_RATE_H = _row(rate=-1.0, gyro_bias=1.0)  # constant: made once (a gyro sample is 100 Hz)
_GYRO_RATE_H.flags.writeable = False


def gyro_rate(x: Array, yaw_rate_left_rps: float, sigma_rps: float) -> Measurement:
    """The gyro's z-up rate: ``-heading_rate + bias``."""
    return (np.array([yaw_rate_left_rps]), np.array([_gyro_rate_h(x)]), _GYRO_RATE_H,
            np.array([[sigma_rps ** 2]]))


@jit
def _gyro_rate_h(x: Array) -> float:  # pragma: no cover - compiled
    """The gyro rate the state predicts (:func:`gyro_rate`; compiled, for the fused step)."""
    return float(-x[HEADING_RATE] + x[GYRO_BIAS])


def odometer_speed(x: Array, speed_mps: float, sigma_mps: float) -> Measurement:
    """The odometer's speed: ``scale x speed``."""
    h = x[ODO_SCALE] * x[SPEED]
    return (np.array([speed_mps]), np.array([h]),
            _row(speed=x[ODO_SCALE], odo_scale=x[SPEED]), np.array([[sigma_mps ** 2]]))


def lateral_accel(x: Array, accel_left_mps2: float, sigma_mps2: float) -> Measurement:
    """Centripetal acceleration to the left: ``speed x (-heading_rate)`` (thesis config 4)."""
    h = -x[SPEED] * x[HEADING_RATE]
    return (np.array([accel_left_mps2]), np.array([h]),
            _row(speed=-x[HEADING_RATE], rate=-x[SPEED]), np.array([[sigma_mps2 ** 2]]))


def steering_rate(x: Array, angle_left_rad: float, wheelbase_m: float,
                  sigma_rad: float) -> Measurement:
    """Bicycle model (thesis config 1): heading rate ``-speed x tan(steer - bias) / wheelbase``.

    The steering-angle bias lives in the ``GYRO_BIAS`` slot (this configuration has no gyro);
    a bias of a few milliradians turns into degrees per second of heading error at speed.
    """
    angle = angle_left_rad - x[GYRO_BIAS]
    tan_d, sec2 = math.tan(angle), 1.0 / math.cos(angle) ** 2
    h = x[HEADING_RATE] + x[SPEED] * tan_d / wheelbase_m
    sigma = abs(x[SPEED]) * sigma_rad * sec2 / wheelbase_m + 0.01
    return (np.array([0.0]), np.array([h]),
            _row(rate=1.0, speed=tan_d / wheelbase_m,
                 gyro_bias=-x[SPEED] * sec2 / wheelbase_m),
            np.array([[sigma ** 2]]))


def gps_position(x: Array, east_m: float, north_m: float, sigma_m: float) -> Measurement:
    variance = sigma_m ** 2
    return (np.array([east_m, north_m]), np.array([x[X_M], x[Y_M]]), _GPS_POSITION_H,
            np.array([[variance, 0.0], [0.0, variance]]))


_GPS_POSITION_H = np.zeros((2, N_STATES))
_GPS_POSITION_H[0, X_M] = _GPS_POSITION_H[1, Y_M] = 1.0
_GPS_POSITION_H.flags.writeable = False


def gps_velocity(x: Array, speed_mps: float, course_rad: float,
                 sigma_mps: float) -> Measurement:
    """GPS ground velocity (east, north): ``speed x (sin heading, cos heading)``."""
    s, c = math.sin(x[HEADING]), math.cos(x[HEADING])
    H = np.zeros((2, N_STATES))
    H[0, SPEED], H[0, HEADING] = s, x[SPEED] * c
    H[1, SPEED], H[1, HEADING] = c, -x[SPEED] * s
    z = np.array([speed_mps * math.sin(course_rad), speed_mps * math.cos(course_rad)])
    return z, np.array([x[SPEED] * s, x[SPEED] * c]), H, np.eye(2) * sigma_mps ** 2


def zero_motion(x: Array, sigma_mps: float = 0.01, sigma_rps: float = 1e-3) -> Measurement:
    """Zero-velocity update while stationary: speed 0 and heading rate 0."""
    H = np.zeros((2, N_STATES))
    H[0, SPEED] = H[1, HEADING_RATE] = 1.0
    return (np.zeros(2), x[[SPEED, HEADING_RATE]].copy(), H,
            np.diag([sigma_mps ** 2, sigma_rps ** 2]))


def road_constraint(x: Array, east_m: float, north_m: float, road_bearing_rad: float,
                    sigma_across_m: float, sigma_heading_rad: float) -> Measurement:
    """Map feedback: the position lies on a road line and the heading follows it.

    The first row is the offset across the road (the along-road offset is not observed); the
    second the heading difference, wrapped, with the road's direction as measured heading.
    """
    nx_, ny_ = math.cos(road_bearing_rad), -math.sin(road_bearing_rad)  # unit normal
    across = (x[X_M] - east_m) * nx_ + (x[Y_M] - north_m) * ny_
    dh = math.remainder(x[HEADING] - road_bearing_rad, 2.0 * math.pi)
    H = np.zeros((2, N_STATES))
    H[0, X_M], H[0, Y_M], H[1, HEADING] = nx_, ny_, 1.0
    return (np.zeros(2), np.array([across, dh]), H,
            np.diag([sigma_across_m ** 2, sigma_heading_rad ** 2]))
