"""Measurement models of the road-vehicle filter (pure), one small object per sensor reading.

Seed: Mayhew 1999, chapter 4 (gyro rate, odometer, steering angle, lateral acceleration) and
chapter 5 (GPS); map feedback (the road constraint) after the thesis's map-matching chapter.
Each ``model(x)`` gives ``(z, h, H, R)`` (:data:`~navsvc.fusion.kalman.Linearised`) at the
8-state ``x`` of :mod:`navsvc.fusion.road.motion`; a test checks every ``H`` against central
differences of ``h``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from navsvc.fusion._jit import Array, jit
from navsvc.fusion.kalman import Linearised
from navsvc.fusion.road.motion import (
    ACCEL_BIAS,
    GPS_BIAS,
    GPS_BIAS_E,
    GPS_BIAS_N,
    GPS_LATENCY,
    GYRO_BIAS,
    GYRO_SCALE,
    HEADING,
    HEADING_RATE,
    N_STATES,
    ODO_SCALE,
    SPEED,
    X_M,
    Y_M,
    ProcessNoise,
    model_args,
    predict_compiled,
    symmetrised,
)


def _row(**entries: float) -> Array:
    H = np.zeros((1, N_STATES))
    for name, value in entries.items():
        H[0, _INDEX[name]] = value
    return H


_INDEX = {"x": X_M, "y": Y_M, "heading": HEADING, "speed": SPEED, "rate": HEADING_RATE,
          "gyro_bias": GYRO_BIAS, "odo_scale": ODO_SCALE, "accel_bias": ACCEL_BIAS,
          "gyro_scale": GYRO_SCALE, "gps_bias_e": GPS_BIAS_E, "gps_bias_n": GPS_BIAS_N,
          "gps_latency": GPS_LATENCY}


@jit
def gyro_input(x: Array, yaw_rate_left_rps: float) -> tuple[float, Array]:  # pragma: no cover
    """The heading rate a gyro sample gives at the state's bias and scale error,
    ``-(rate - bias) / (1 + scale error)``, and its Jacobian (a row over the state)."""
    gain = 1.0 + x[GYRO_SCALE]
    unbiased = yaw_rate_left_rps - x[GYRO_BIAS]
    J = np.zeros(N_STATES)
    J[GYRO_BIAS] = 1.0 / gain
    J[GYRO_SCALE] = unbiased / gain ** 2
    return -unbiased / gain, J


@dataclass(frozen=True)
class GyroRate:
    """The gyro's z-up rate, ``-(1 + scale error) x heading_rate + bias``.

    The road filter takes it as the input that turns the heading
    (:func:`predict_with_gyro`), not as a measurement: as a measurement of a heading-rate
    state its Jacobian changes with the turn rate, which an EKF takes for information on
    the scale error that the gyro alone cannot give (the estimate then ran to its limit and
    the heading lost 13 degrees in a hairpin). The model stays for comparisons with filters
    that do fuse it as a measurement (``bench/fusion_bench.py``)."""

    rate_left_rps: float
    sigma_rps: float

    def model(self, x: Array) -> Linearised:
        gain = 1.0 + x[GYRO_SCALE]
        return (np.array([self.rate_left_rps]),
                np.array([-gain * x[HEADING_RATE] + x[GYRO_BIAS]]),
                _row(rate=-gain, gyro_bias=1.0, gyro_scale=-x[HEADING_RATE]),
                np.array([[self.sigma_rps ** 2]]))


def predict_with_gyro(x: Array, P: Array, dt_s: float, max_step_s: float,
                      accel_fwd_mps2: float | None, noise: ProcessNoise,
                      yaw_rate_left_rps: float, sigma_rps: float) -> tuple[Array, Array]:
    """:func:`~navsvc.fusion.road.motion.predict`, then the heading rate from the gyro
    sample (:func:`gyro_input`), in one compiled call: the filter's step at every gyro
    sample. The rate becomes a function of the bias and scale-error states plus the gyro's
    noise, ``P <- A P Aᵀ + noise`` with ``A`` the identity whose rate row is the Jacobian;
    the next steps carry that into heading and position, and GPS then corrects the bias and
    the scale error through those correlations."""
    return _predict_with_gyro(x, P, dt_s, max_step_s, *model_args(accel_fwd_mps2, noise),
                              yaw_rate_left_rps, sigma_rps ** 2)


@jit
def _predict_with_gyro(x: Array, P: Array, dt_s: float, max_step_s: float,
                       accel_fwd_mps2: float, densities: Array, turn_rate_tau_s: float,
                       yaw_rate_left_rps: float, variance: float
                       ) -> tuple[Array, Array]:  # pragma: no cover - compiled
    x, P = predict_compiled(x, P, dt_s, max_step_s, accel_fwd_mps2, densities,
                            turn_rate_tau_s)
    rate, J = gyro_input(x, yaw_rate_left_rps)
    if not math.isfinite(rate):  # a NaN sample leaves the state as it was
        return x, P
    P_new = _row_replaced(P, HEADING_RATE, J)  # A P Aᵀ
    P_new[HEADING_RATE, HEADING_RATE] += variance / (1.0 + x[GYRO_SCALE]) ** 2
    x_new = x.copy()
    x_new[HEADING_RATE] = rate
    return x_new, symmetrised(P_new)


@jit
def _row_replaced(P: Array, r: int, J: Array) -> Array:  # pragma: no cover - compiled
    """``matmul(matmul(A, P), A.T)`` for ``A`` the identity with row ``r`` replaced by
    ``J``, bit for bit (the same products in the same order, ``0.0 + 1.0 x p`` where the
    identity passes an entry through), without forming ``A``: only row and column ``r``
    change."""
    n = P.shape[0]
    C = np.empty((n, n))  # A P
    for i in range(n):
        if i != r:
            for j in range(n):
                C[i, j] = 0.0 + 1.0 * P[i, j]
    for j in range(n):
        acc = 0.0
        for k in range(n):
            if J[k] != 0.0:
                acc += J[k] * P[k, j]
        C[r, j] = acc
    D = np.empty((n, n))  # (A P) Aᵀ
    for i in range(n):
        for j in range(n):
            if j != r:
                D[i, j] = 0.0 + C[i, j] * 1.0
        acc = 0.0
        for k in range(n):
            if J[k] != 0.0:
                acc += C[i, k] * J[k]
        D[i, r] = acc
    return D


@dataclass(frozen=True)
class OdometerSpeed:
    """The odometer's speed: ``scale x speed``."""

    speed_mps: float
    sigma_mps: float

    def model(self, x: Array) -> Linearised:
        h = x[ODO_SCALE] * x[SPEED]
        return (np.array([self.speed_mps]), np.array([h]),
                          _row(speed=x[ODO_SCALE], odo_scale=x[SPEED]),
                          np.array([[self.sigma_mps ** 2]]))


@dataclass(frozen=True)
class LateralAccel:
    """Centripetal acceleration to the left: ``speed x (-heading_rate)`` (thesis config 4)."""

    accel_left_mps2: float
    sigma_mps2: float

    def model(self, x: Array) -> Linearised:
        h = -x[SPEED] * x[HEADING_RATE]
        return (np.array([self.accel_left_mps2]), np.array([h]),
                          _row(speed=-x[HEADING_RATE], rate=-x[SPEED]),
                          np.array([[self.sigma_mps2 ** 2]]))


@dataclass(frozen=True)
class SteeringRate:
    """Bicycle model (thesis config 1): heading rate ``-speed x tan(steer - bias) / wheelbase``.

    The steering-angle bias lives in the ``GYRO_BIAS`` slot (this configuration has no gyro);
    a bias of a few milliradians turns into degrees per second of heading error at speed. The
    noise grows with speed (it is treated as constant in ``H``).
    """

    angle_left_rad: float
    wheelbase_m: float
    sigma_rad: float

    def model(self, x: Array) -> Linearised:
        angle = self.angle_left_rad - x[GYRO_BIAS]
        tan_d, sec2 = math.tan(angle), 1.0 / math.cos(angle) ** 2
        h = x[HEADING_RATE] + x[SPEED] * tan_d / self.wheelbase_m
        sigma = abs(x[SPEED]) * self.sigma_rad * sec2 / self.wheelbase_m + 0.01
        return (np.array([0.0]), np.array([h]),
                          _row(rate=1.0, speed=tan_d / self.wheelbase_m,
                               gyro_bias=-x[SPEED] * sec2 / self.wheelbase_m),
                          np.array([[sigma ** 2]]))


@dataclass(frozen=True)
class GpsPosition:
    """A GPS fix in the map frame (east, north), of where the car was when the fix was
    measured, the latency state before its time stamp (a client stamps a fix when it gets
    it, a tenth of a second or more after the measurement): the position then, that long of
    driving back along the heading, plus the slowly changing GPS error (the bias states);
    ``sigma_m`` is the rest, the part that is new at each fix."""

    east_m: float
    north_m: float
    sigma_m: float

    def model(self, x: Array) -> Linearised:
        variance, lag = self.sigma_m ** 2, x[GPS_LATENCY]
        s, c, v = math.sin(x[HEADING]), math.cos(x[HEADING]), x[SPEED]
        H = np.zeros((2, N_STATES))
        H[0, X_M] = H[1, Y_M] = H[0, GPS_BIAS_E] = H[1, GPS_BIAS_N] = 1.0
        H[0, SPEED], H[0, HEADING], H[0, GPS_LATENCY] = -lag * s, -lag * v * c, -v * s
        H[1, SPEED], H[1, HEADING], H[1, GPS_LATENCY] = -lag * c, lag * v * s, -v * c
        return (np.array([self.east_m, self.north_m]),
                np.array([x[X_M] - lag * v * s + x[GPS_BIAS_E],
                          x[Y_M] - lag * v * c + x[GPS_BIAS_N]]), H,
                np.array([[variance, 0.0], [0.0, variance]]))


@dataclass(frozen=True)
class GpsVelocity:
    """GPS ground velocity (east, north): ``speed x (sin, cos)`` of the heading when the
    fix was measured (``heading - heading_rate x latency``)."""

    speed_mps: float
    course_rad: float
    sigma_mps: float

    def model(self, x: Array) -> Linearised:
        lag, rate = x[GPS_LATENCY], x[HEADING_RATE]
        then = x[HEADING] - rate * lag
        s, c = math.sin(then), math.cos(then)
        H = np.zeros((2, N_STATES))
        H[0, SPEED], H[0, HEADING] = s, x[SPEED] * c
        H[1, SPEED], H[1, HEADING] = c, -x[SPEED] * s
        for row in (0, 1):
            H[row, HEADING_RATE] = -lag * H[row, HEADING]
            H[row, GPS_LATENCY] = -rate * H[row, HEADING]
        z = np.array([self.speed_mps * math.sin(self.course_rad),
                      self.speed_mps * math.cos(self.course_rad)])
        return (z, np.array([x[SPEED] * s, x[SPEED] * c]), H,
                np.eye(2) * self.sigma_mps ** 2)


@dataclass(frozen=True)
class CourseAndSpeed:
    """GPS course and speed directly (the rules and fuzzy modes' weighted sums): the heading
    difference, wrapped, and the speed."""

    course_rad: float
    speed_mps: float
    sigma_heading_rad: float
    sigma_mps: float

    def model(self, x: Array) -> Linearised:
        H = np.zeros((2, N_STATES))
        H[0, HEADING] = H[1, SPEED] = 1.0
        dh = math.remainder(x[HEADING] - self.course_rad, 2.0 * math.pi)
        return (np.array([0.0, self.speed_mps]), np.array([dh, x[SPEED]]), H,
                          np.diag([self.sigma_heading_rad ** 2, self.sigma_mps ** 2]))


@dataclass(frozen=True)
class ZeroMotion:
    """Zero-velocity update while stationary: speed 0 and heading rate 0."""

    sigma_mps: float = 0.01
    sigma_rps: float = 1e-3

    def model(self, x: Array) -> Linearised:
        H = np.zeros((2, N_STATES))
        H[0, SPEED] = H[1, HEADING_RATE] = 1.0
        return (np.zeros(2), x[[SPEED, HEADING_RATE]].copy(), H,
                          np.diag([self.sigma_mps ** 2, self.sigma_rps ** 2]))


@dataclass(frozen=True)
class RoadConstraint:
    """Map feedback: the position lies on a road line and the heading follows it.

    The first row is the offset across the road (the along-road offset is not observed); the
    second the heading difference, wrapped, with the road's direction as measured heading.
    ``probability``: how likely the road is the one driven (the filter takes the
    constraint as right only that likely: :func:`navsvc.fusion.kalman.no_surer_than`).
    """

    east_m: float
    north_m: float
    road_bearing_rad: float
    sigma_across_m: float
    sigma_heading_rad: float
    probability: float = 1.0

    def model(self, x: Array) -> Linearised:
        nx_, ny_ = math.cos(self.road_bearing_rad), -math.sin(self.road_bearing_rad)  # normal
        across = (x[X_M] - self.east_m) * nx_ + (x[Y_M] - self.north_m) * ny_
        dh = math.remainder(x[HEADING] - self.road_bearing_rad, 2.0 * math.pi)
        H = np.zeros((2, N_STATES))
        H[0, X_M], H[0, Y_M], H[1, HEADING] = nx_, ny_, 1.0
        return (np.zeros(2), np.array([across, dh]), H,
                          np.diag([self.sigma_across_m ** 2, self.sigma_heading_rad ** 2]))


# Updates that say nothing of some states although their linearisation seems to: they leave
# them (kalman.correct_leaving; the same lists in the compiled runs, navsvc.fusion.road.batch)
STANDSTILL_LEAVES = (X_M, Y_M, HEADING, ODO_SCALE, GYRO_SCALE, *GPS_BIAS, GPS_LATENCY)
# a standstill update tells the gyro bias, not these: the scales are unobservable at rest (the
# rate's Jacobian by the gyro scale is the gyro noise, which the update read as information);
# correcting heading and position through their correlation with a bias that drifts moved a
# car at rest 30 m and 6 degrees after an outage; and a car pulling away slowly through a
# corner, read as standing, moved the GPS bias states 40 m

STEERING_LEAVES = (SPEED, ODO_SCALE)  # the steering angle tells the turn rate at a speed,
# not the speed: as a measurement of it, slow corners and angle noise pulled the speed (and
# with it the odometer scale) 3 % off, and the position 6 m behind while the fixes were right
