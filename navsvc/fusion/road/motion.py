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
    8 GYRO_SCALE     gyro scale factor error (measured = (1 + this) x true rate) [-]
    9 GPS_BIAS_E     the slowly changing part of the GPS error, east [m] (first-order
   10 GPS_BIAS_N     ... north; Gauss-Markov: the filter propagates it at each fix)
   11 GPS_LATENCY    how long before its time stamp a fix was measured [s]

The measurement models over this state are in :mod:`navsvc.fusion.road.measurements`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from navsvc.fusion import kalman
from navsvc.fusion._jit import Array, jit

(X_M, Y_M, HEADING, SPEED, HEADING_RATE, GYRO_BIAS, ODO_SCALE, ACCEL_BIAS, GYRO_SCALE,
 GPS_BIAS_E, GPS_BIAS_N, GPS_LATENCY) = range(12)
N_STATES = 12
GPS_BIAS = (GPS_BIAS_E, GPS_BIAS_N)


@dataclass(frozen=True)
class ProcessNoise:
    """Random-walk spectral densities of the process model."""

    accel_mps2: float = 1.5  # unmodelled longitudinal acceleration (speed random walk)
    heading_accel_rps2: float = 0.4  # unmodelled change of heading rate
    gyro_bias_drift_rps_per_sqrt_s: float = 2e-4
    odo_scale_drift_per_sqrt_s: float = 1e-5
    accel_bias_drift_mps2_per_sqrt_s: float = 1e-3
    gyro_scale_drift_per_sqrt_s: float = 1e-5
    turn_rate_tau_s: float | None = None  # GPS only: the turn rate decays with this time
    accel_integration_mps2: float = 0.3  # speed noise when it integrates the accelerometer

    @cached_property
    def densities(self) -> Array:
        """Diagonal of Q per second (speed a random walk)."""
        return np.array([0.0, 0.0, 0.0, self.accel_mps2 ** 2, self.heading_accel_rps2 ** 2,
                         self.gyro_bias_drift_rps_per_sqrt_s ** 2,
                         self.odo_scale_drift_per_sqrt_s ** 2,
                         self.accel_bias_drift_mps2_per_sqrt_s ** 2,
                         self.gyro_scale_drift_per_sqrt_s ** 2, 0.0, 0.0, 0.0])

    @cached_property
    def densities_with_accel(self) -> Array:
        """Diagonal of Q per second when the speed integrates the accelerometer."""
        q = self.densities.copy()
        q[SPEED] = self.accel_integration_mps2 ** 2
        return q


def propagate_gps_bias(x: Array, P: Array, dt_s: float, tau_s: float,
                       sigma_m: float, held_within_m: float | None = None) -> None:
    """The GPS bias states ``dt_s`` on, in place: first-order Gauss-Markov with time
    constant ``tau_s`` and steady sigma ``sigma_m``. The inertial-rate predictions leave them
    alone (their transition is a scalar times the identity, which commutes with the rest),
    so this one step at a fix is exact. ``held_within_m``: the value is held (no decay toward
    zero), but its variance grows as the process's would, up to this sigma (an offset held
    with its spread that still wanders within it)."""
    decay = math.exp(-max(dt_s, 0.0) / tau_s)
    grown = sigma_m ** 2 * (1.0 - decay ** 2)
    if held_within_m is not None:
        for i in GPS_BIAS:
            P[i, i] = max(P[i, i], min(P[i, i] + grown, held_within_m ** 2))
        return
    idx = list(GPS_BIAS)
    x[idx] *= decay
    P[idx, :] *= decay
    P[:, idx] *= decay
    for i in GPS_BIAS:
        P[i, i] += grown


def propagate(x: Array, dt_s: float, accel_fwd_mps2: float | None,
              noise: ProcessNoise) -> tuple[Array, Array, Array]:
    """One step of the kinematic model: new state, Jacobian ``F`` and the diagonal of the
    process noise ``Q`` (it is diagonal: independent random walks).

    With ``accel_fwd_mps2`` (configs 3 and 4) the speed integrates the bias-corrected forward
    acceleration; otherwise it is a random walk that the odometer or GPS pins down. With
    ``noise.turn_rate_tau_s`` (GPS only: no sensor measures the turn rate) the turn rate is a
    first-order Gauss-Markov process, so a turn does not go on for ever in an outage.
    """
    return _propagate(x, dt_s, *model_args(accel_fwd_mps2, noise))


def predict(x: Array, P: Array, dt_s: float, max_step_s: float, accel_fwd_mps2: float | None,
            noise: ProcessNoise) -> tuple[Array, Array]:
    """State and covariance ``dt_s`` on, in steps of at most ``max_step_s`` (each
    :func:`propagate`, then ``F P Fᵀ + Q``), in one compiled call: the filter makes one per
    inertial sample, and one per GPS fix in a GPS-only session."""
    return predict_compiled(x, P, dt_s, max_step_s, *model_args(accel_fwd_mps2, noise))


def model_args(accel_fwd_mps2: float | None,
                noise: ProcessNoise) -> tuple[float, Array, float]:
    """The compiled model's arguments: acceleration, Q densities, turn-rate time constant
    (NaN for "none", as the kernels take no Nones)."""
    tau = math.nan if noise.turn_rate_tau_s is None else noise.turn_rate_tau_s
    if accel_fwd_mps2 is None:
        return math.nan, noise.densities, tau
    return accel_fwd_mps2, noise.densities_with_accel, tau


@jit
def predict_compiled(x: Array, P: Array, dt_s: float, max_step_s: float, accel_fwd_mps2: float,
             densities: Array, turn_rate_tau_s: float
             ) -> tuple[Array, Array]:  # pragma: no cover - compiled
    remaining = dt_s
    while remaining > 1e-9:
        step = min(remaining, max_step_s)
        x, F, q = _propagate(x, step, accel_fwd_mps2, densities, turn_rate_tau_s)
        P = _predict_covariance(P, F, q)
        remaining -= step
    return x, P


@jit
def _predict_covariance(P: Array, F: Array, q_diag: Array) -> Array:  # pragma: no cover
    """``kalman.predict(P, F, q_diag)``, bit for bit, with the second product over the
    nonzeros of ``F`` (20 of 144) instead of all of them."""
    P_next = matmul_transposed(kalman.matmul(F, P), F)
    for i in range(len(q_diag)):
        P_next[i, i] += q_diag[i]
    return symmetrised(P_next)


@jit
def symmetrised(A: Array) -> Array:  # pragma: no cover - compiled
    """``0.5 * (A + A.T)``, bit for bit, in place (the sum is the same either way round)."""
    n = A.shape[0]
    for i in range(n):
        for j in range(i, n):
            v = 0.5 * (A[i, j] + A[j, i])
            A[i, j] = v
            A[j, i] = v
    return A


@jit
def matmul_transposed(A: Array, B: Array) -> Array:  # pragma: no cover - compiled
    """``kalman.matmul(A, B.T)``, bit for bit, skipping the zeros of ``B`` (a sparse
    Jacobian) where ``matmul`` skips those of ``A``: each element adds the same nonzero
    products in the same order (ascending k), and a zero product added to a sum that starts
    at +0 changes nothing. ``tests/fusion/test_batch.py`` checks it against ``matmul``."""
    n, m = A.shape[0], B.shape[0]
    C = np.zeros((n, m))
    for j in range(m):
        for k in range(B.shape[1]):
            b = B[j, k]
            if b != 0.0:
                for i in range(n):
                    C[i, j] += A[i, k] * b
    return C


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
