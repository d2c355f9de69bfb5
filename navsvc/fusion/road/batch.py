"""The road filter's batched path (pure): a run of dead-reckoning samples in one compiled call.

Seed: Mayhew 1999, chapter 5, as :mod:`navsvc.fusion.road.filter` runs it; this module only
moves the loop over samples into compiled code. A :class:`SampleRun` holds consecutive
inertial, odometer and steering samples of one message as columns; :func:`run_samples` steps
the filter through them with the same compiled kernels the per-packet path calls
(:func:`~navsvc.fusion.road.measurements._predict_with_gyro`,
:func:`~navsvc.fusion.road.motion.predict_compiled`, :func:`~navsvc.fusion.kalman.correct_compiled`,
:func:`~navsvc.fusion.kalman.joseph`): predict with the gyro input, then the profile's
per-sample updates (lateral acceleration, odometer speed, steering, and the standstill
zero-velocity update). It stops after the first sample that emits an estimate
(``output_interval_s``) or at which the session's matcher is due, so that the caller can
build the :class:`~navsvc.types.FusedEstimate` and step the matcher exactly where the
per-packet path does, then call again for the rest.

Which path takes what (:meth:`navsvc.fusion.engine.FusionEngine.add_run`): this one takes
an initialised road filter's samples in time order; the per-packet ``RoadFilter.apply``
(the reference) takes GPS fixes and velocities, every packet before initialisation, every
packet of the strapdown INS, and late packets (the reorder window replays them, runs of the
history again through this path).

Equality with the per-packet path: the same operations in the same order, so bit for bit
(the standstill and steering updates too: both paths call
:func:`~navsvc.fusion.kalman.correct_leaving_compiled`, with the states to leave from
:mod:`.measurements`); ``tests/fusion/test_batch.py`` still allows 1e-9, from when the
per-packet standstill update went through LAPACK.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from navsvc.fusion import kalman
from navsvc.fusion._jit import Array, jit
from navsvc.fusion.road.measurements import (
    STANDSTILL_LEAVES,
    STEERING_LEAVES,
    LateralAccel,
    OdometerSpeed,
    SteeringRate,
    ZeroMotion,
    _predict_with_gyro,
)
from navsvc.fusion.road.motion import (
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
    predict_compiled,
)
from navsvc.types import ImuSample, OdometerSample, Packet, SteeringSample

if TYPE_CHECKING:
    from navsvc.fusion.config import FusionConfig
    from navsvc.fusion.profiles import Profile
    from navsvc.fusion.road.filter import RoadState

IMU, ODOMETER, STEERING = 0, 1, 2  # SampleRun kind codes
# SampleRun.rows columns: time [s], kind, then the fields in SI units and radians (NaN: the
# field is absent)
T, KIND, YAW_RPS, ACCEL_FWD, ACCEL_LEFT, ODO_DISTANCE, ODO_TICKS, ODO_SPEED, STEER_RAD = \
    range(9)
N_COLUMNS = 9

# RunScalars: the filter's scalar state that a run reads and writes (NaN: None)
(S_T, S_ACCEL_FWD, S_STILL, S_LAST_DISTANCE, S_WINDOW_T, S_WINDOW_D, S_ODO_SPEED,
 S_LAST_OUTPUT, S_LAST_MATCH, S_BIAS_SIGMA) = range(10)  # S_BIAS_SIGMA: read only
N_SCALARS = 10

# RunParams: the profile's and the configuration's constants
(P_GYRO, P_ACCEL_SPEED, P_LATERAL, P_ODOMETER, P_STEERING, P_GYRO_VAR, P_ACCEL_VAR,
 P_ODO_VAR, P_STEER_SIGMA, P_WHEELBASE, P_TICKS_PER_M, P_ODO_WINDOW, P_STILL_AFTER,
 P_OUTPUT_INTERVAL, P_ODO_LOW, P_ODO_HIGH, P_GYRO_SCALE_LIMIT, P_MAX_LATENCY, P_MAX_STEP,
 P_TAU, P_MATCH_INTERVAL, P_ZUPT_SPEED_VAR, P_ZUPT_RATE_VAR, P_STILL_MAX_RATE,
 P_BIAS_MAX_SIGMAS) = range(25)
N_PARAMS = 25

DONE, OUTPUT, MATCH = 0, 1, 2  # why run_samples returned
_STANDSTILL_KEEP = kalman.kept_mask(STANDSTILL_LEAVES, N_STATES)  # constants of the kernels
_STEERING_KEEP = kalman.kept_mask(STEERING_LEAVES, N_STATES)
_NAN = math.nan


class SampleRun:
    """Consecutive dead-reckoning samples as one array of rows (``N_COLUMNS``: time, kind
    (IMU, ODOMETER, STEERING) and the fields), one array so that a compiled call takes
    it as one argument."""

    __slots__ = ("rows",)

    def __init__(self, rows: Array) -> None:
        self.rows = rows

    def __len__(self) -> int:
        return len(self.rows)

    @property
    def t(self) -> Array:
        return self.rows[:, T]

    @property
    def first_t(self) -> float:
        return float(self.rows[0, T])

    def part(self, start: int, stop: int) -> SampleRun:
        """Samples ``start`` to ``stop`` (a view, no copy)."""
        return SampleRun(self.rows[start:stop])

    def split_at(self, t: float) -> tuple[SampleRun, SampleRun]:
        """The samples up to and including time ``t``, and the ones after."""
        k = int(np.searchsorted(self.rows[:, T], t, side="right"))
        return self.part(0, k), self.part(k, len(self))

    def packet(self, i: int) -> Packet:
        """Sample ``i`` as the packet it stands for."""
        return sample_packet(self.rows[i])

    def packets(self) -> list[Packet]:
        """The samples as packets (for the per-packet path)."""
        return [sample_packet(row) for row in self.rows]

    @classmethod
    def of(cls, packets: list[Packet]) -> SampleRun:
        """A run of packets (IMU, odometer and steering samples only)."""
        rows = np.full((len(packets), N_COLUMNS), _NAN)
        for i, p in enumerate(packets):
            rows[i, T] = p.t
            if isinstance(p, ImuSample):
                rows[i, KIND] = IMU
                rows[i, YAW_RPS] = _nan(p.yaw_rate_rps)
                rows[i, ACCEL_FWD] = _nan(p.accel_fwd_mps2)
                rows[i, ACCEL_LEFT] = _nan(p.accel_left_mps2)
            elif isinstance(p, OdometerSample):
                rows[i, KIND] = ODOMETER
                rows[i, ODO_DISTANCE] = _nan(p.distance_m)
                rows[i, ODO_TICKS] = _nan(None if p.ticks is None else float(p.ticks))
                rows[i, ODO_SPEED] = _nan(p.speed_mps)
            elif isinstance(p, SteeringSample):
                rows[i, KIND] = STEERING
                rows[i, STEER_RAD] = p.angle_rad
            else:
                raise TypeError(f"not a dead-reckoning sample: {type(p).__name__}")
        return cls(rows)


def _nan(value: float | None) -> float:
    return _NAN if value is None else value


def _none(value: float) -> float | None:
    return None if math.isnan(value) else float(value)


def sample_packet(row: Array) -> Packet:
    """One row of a run as the packet it stands for."""
    t, kind = float(row[T]), int(row[KIND])
    if kind == IMU:
        return ImuSample(t=t, yaw_rate_rps=_none(row[YAW_RPS]),
                         accel_fwd_mps2=_none(row[ACCEL_FWD]),
                         accel_left_mps2=_none(row[ACCEL_LEFT]))
    if kind == ODOMETER:
        ticks = _none(row[ODO_TICKS])
        return OdometerSample(t=t, distance_m=_none(row[ODO_DISTANCE]),
                              ticks=None if ticks is None else int(ticks),
                              speed_mps=_none(row[ODO_SPEED]))
    return SteeringSample(t=t, angle_rad=float(row[STEER_RAD]))


@jit
def run_samples(x: Array, P: Array, scalars: Array, params: Array, rows: Array, start: int,
                stop_for_events: bool) -> tuple[Array, Array, int, int]:  # pragma: no cover
    """Step the filter ``(x, P, scalars)`` through samples ``start..`` of a run's rows; with
    ``stop_for_events``, return after the first that emits an estimate (OUTPUT) or at
    which the matcher is due (MATCH). Returns ``(x, P, next index, why)``; ``scalars`` is
    updated in place. ``params``: :func:`run_params`."""
    densities = params[N_PARAMS:N_PARAMS + N_STATES]
    densities_accel = params[N_PARAMS + N_STATES:N_PARAMS + 2 * N_STATES]
    n = len(rows)
    i = start
    while i < n:
        t = rows[i, T]
        x, P = _sample(x, P, scalars, params, densities, densities_accel, t,
                       int(rows[i, KIND]), rows[i])
        i += 1
        last_out = scalars[S_LAST_OUTPUT]
        if math.isnan(last_out) or t - last_out >= params[P_OUTPUT_INTERVAL]:
            scalars[S_LAST_OUTPUT] = t
            if stop_for_events:
                return x, P, i, OUTPUT
            continue
        if stop_for_events and not math.isnan(params[P_MATCH_INTERVAL]):
            last_match = scalars[S_LAST_MATCH]
            if math.isnan(last_match) or not \
                    scalars[S_T] - last_match < params[P_MATCH_INTERVAL]:
                return x, P, i, MATCH
    return x, P, i, DONE


@jit
def _sample(x: Array, P: Array, s: Array, p: Array, densities: Array, densities_accel: Array,
            t: float, kind: int, v: Array) -> tuple[Array, Array]:  # pragma: no cover
    """``RoadFilter.apply`` of one initialised sample: ``_propagate_to``, then
    ``_fuse_dead_reckoning``."""
    accel = s[S_ACCEL_FWD] if p[P_ACCEL_SPEED] != 0.0 else _NAN
    dens = densities if math.isnan(accel) else densities_accel
    gyro = v[YAW_RPS] if kind == IMU and p[P_GYRO] != 0.0 else _NAN
    if not math.isnan(gyro):
        x, P = _predict_with_gyro(x, P, max(t - s[S_T], 0.0), p[P_MAX_STEP], accel, dens,
                                  p[P_TAU], gyro, p[P_GYRO_VAR])
    elif t - s[S_T] > 1e-9:
        x, P = predict_compiled(x, P, t - s[S_T], p[P_MAX_STEP], accel, dens, p[P_TAU])
    s[S_T] = max(s[S_T], t)
    if kind == IMU:
        if not math.isnan(v[ACCEL_FWD]):
            s[S_ACCEL_FWD] = v[ACCEL_FWD]
        if not math.isnan(v[ACCEL_LEFT]) and p[P_LATERAL] != 0.0:
            H = np.zeros((1, N_STATES))
            H[0, SPEED] = -x[HEADING_RATE]
            H[0, HEADING_RATE] = -x[SPEED]
            x, P = _update(x, P, p, s, np.array([v[ACCEL_LEFT]]),
                           np.array([-x[SPEED] * x[HEADING_RATE]]), H,
                           np.array([[p[P_ACCEL_VAR]]]))
    elif kind == ODOMETER:
        if p[P_ODOMETER] != 0.0:
            x, P = _odometer(x, P, s, p, t, v)
    elif p[P_STEERING] != 0.0:
        x, P = _steering(x, P, p, v[STEER_RAD])
    return x, P


@jit
def _update(x: Array, P: Array, p: Array, s: Array, z: Array, h: Array, H: Array,
            R: Array) -> tuple[Array, Array]:  # pragma: no cover
    """``RoadFilter._update_linearised`` without a gate: the update, then the clamps."""
    x, P, nis = kalman.correct_compiled(x, P, z, h, H, R, math.inf)
    if not nis <= math.inf:
        return x, P
    x[HEADING] %= 2.0 * math.pi
    x[ODO_SCALE] = min(max(x[ODO_SCALE], p[P_ODO_LOW]), p[P_ODO_HIGH])
    limit = p[P_GYRO_SCALE_LIMIT]
    x[GYRO_SCALE] = min(max(x[GYRO_SCALE], -limit), limit)
    x[GPS_LATENCY] = min(max(x[GPS_LATENCY], 0.0), p[P_MAX_LATENCY])
    limit = p[P_BIAS_MAX_SIGMAS] * s[S_BIAS_SIGMA]
    for pos, b in ((X_M, GPS_BIAS_E), (Y_M, GPS_BIAS_N)):
        bounded = min(max(x[b], -limit), limit)
        x[pos] += x[b] - bounded
        x[b] = bounded
    return x, P


@jit
def _odometer(x: Array, P: Array, s: Array, p: Array, t: float,
              v: Array) -> tuple[Array, Array]:  # pragma: no cover
    """``RoadFilter._fuse_odometer``: standstill detection and update, else the speed of
    ``odometer.speed_mps`` over its window."""
    distance = v[ODO_DISTANCE]
    if math.isnan(distance) and not math.isnan(v[ODO_TICKS]):
        distance = v[ODO_TICKS] / p[P_TICKS_PER_M]
    speed = v[ODO_SPEED]
    if not math.isnan(speed):
        still = speed == 0.0
    else:
        previous = s[S_LAST_DISTANCE]
        s[S_LAST_DISTANCE] = distance
        still = not math.isnan(distance) and distance == previous
    if still and abs(x[HEADING_RATE]) <= p[P_STILL_MAX_RATE]:
        s[S_STILL] += 1.0
        if s[S_STILL] >= p[P_STILL_AFTER]:
            return _standstill(x, P, p)
    else:
        s[S_STILL] = 0.0
    if math.isnan(speed):
        if math.isnan(distance):
            return x, P
        w_t, w_d = s[S_WINDOW_T], s[S_WINDOW_D]
        if math.isnan(w_t) or t < w_t or distance < w_d:
            s[S_WINDOW_T], s[S_WINDOW_D] = t, distance
            return x, P
        if t - w_t < p[P_ODO_WINDOW]:
            return x, P
        s[S_WINDOW_T], s[S_WINDOW_D] = t, distance
        speed = (distance - w_d) / (t - w_t)
    s[S_ODO_SPEED] = speed
    H = np.zeros((1, N_STATES))
    H[0, SPEED] = x[ODO_SCALE]
    H[0, ODO_SCALE] = x[SPEED]
    return _update(x, P, p, s, np.array([speed]), np.array([x[ODO_SCALE] * x[SPEED]]), H,
                   np.array([[p[P_ODO_VAR]]]))


@jit
def _standstill(x: Array, P: Array, p: Array) -> tuple[Array, Array]:  # pragma: no cover
    """``kalman.correct_leaving`` of ``ZeroMotion()``, leaving ``STANDSTILL_LEAVES``."""
    H = np.zeros((2, N_STATES))
    H[0, SPEED] = 1.0
    H[1, HEADING_RATE] = 1.0
    R = np.zeros((2, 2))
    R[0, 0], R[1, 1] = p[P_ZUPT_SPEED_VAR], p[P_ZUPT_RATE_VAR]
    y = np.empty(2)
    y[0], y[1] = 0.0 - x[SPEED], 0.0 - x[HEADING_RATE]  # z - h, as correct_leaving
    x, P, _ = kalman.correct_leaving_compiled(x, P, y, H, R, _STANDSTILL_KEEP, math.inf)
    return x, P


@jit
def _steering(x: Array, P: Array, p: Array, angle_left_rad: float
              ) -> tuple[Array, Array]:  # pragma: no cover
    """``SteeringRate.model`` (bicycle model), then ``kalman.correct_leaving`` of it,
    leaving ``STEERING_LEAVES``."""
    wheelbase = p[P_WHEELBASE]
    angle = angle_left_rad - x[GYRO_BIAS]
    tan_d, sec2 = math.tan(angle), 1.0 / math.cos(angle) ** 2
    h = x[HEADING_RATE] + x[SPEED] * tan_d / wheelbase
    sigma = abs(x[SPEED]) * p[P_STEER_SIGMA] * sec2 / wheelbase + 0.01
    H = np.zeros((1, N_STATES))
    H[0, HEADING_RATE] = 1.0
    H[0, SPEED] = tan_d / wheelbase
    H[0, GYRO_BIAS] = -x[SPEED] * sec2 / wheelbase
    y = np.empty(1)
    y[0] = 0.0 - h
    x, P, _ = kalman.correct_leaving_compiled(x, P, y, H, np.array([[sigma ** 2]]),
                                              _STEERING_KEEP, math.inf)
    return x, P


def run_params(config: FusionConfig, profile: Profile, process: ProcessNoise,
               match_interval_s: float | None) -> Array:
    """The constants :func:`run_samples` reads, from the filter's configuration (the
    variances computed as the per-packet measurement models compute them), then the two
    diagonals of Q per second (``ProcessNoise.densities``, ``densities_with_accel``)."""
    used = profile.measurements
    p = np.zeros(N_PARAMS + 2 * N_STATES)
    p[P_GYRO] = float(profile.gyro)
    p[P_ACCEL_SPEED] = float(profile.speed_from_accel)
    p[P_LATERAL] = float(LateralAccel in used)
    p[P_ODOMETER] = float(OdometerSpeed in used)
    p[P_STEERING] = float(SteeringRate in used)
    p[P_GYRO_VAR] = config.gyro_sigma_rps ** 2
    p[P_ACCEL_VAR] = config.accel_sigma_mps2 ** 2
    p[P_ODO_VAR] = config.odometer_sigma_mps ** 2
    p[P_STEER_SIGMA] = config.steering_sigma_rad
    p[P_WHEELBASE] = config.wheelbase_m
    p[P_TICKS_PER_M] = config.ticks_per_m
    p[P_ODO_WINDOW] = config.odometer_window_s
    p[P_STILL_AFTER] = config.stationary_after_samples
    p[P_OUTPUT_INTERVAL] = config.output_interval_s
    p[P_ODO_LOW], p[P_ODO_HIGH] = config.odo_scale_limits
    p[P_GYRO_SCALE_LIMIT] = config.gyro_scale_error_limit
    p[P_MAX_LATENCY] = config.max_gps_latency_s
    p[P_MAX_STEP] = config.max_step_s
    p[P_TAU] = _nan(process.turn_rate_tau_s)
    zero = ZeroMotion()
    p[P_ZUPT_SPEED_VAR], p[P_ZUPT_RATE_VAR] = zero.sigma_mps ** 2, zero.sigma_rps ** 2
    p[P_STILL_MAX_RATE] = config.still_max_turn_rate_rps
    p[P_BIAS_MAX_SIGMAS] = config.gps_bias_max_sigmas
    p[P_MATCH_INTERVAL] = _nan(match_interval_s)
    p[N_PARAMS:N_PARAMS + N_STATES] = process.densities
    p[N_PARAMS + N_STATES:] = process.densities_with_accel
    return p


def pack_scalars(s: RoadState, last_match_t: float | None) -> Array:
    """The run's scalar state from the filter's (None as NaN)."""
    window, nan = s.last_odo, _NAN
    return np.array((
        s.t, nan if s.accel_fwd_mps2 is None else s.accel_fwd_mps2, s.still_samples,
        nan if s.last_odo_distance_m is None else s.last_odo_distance_m,
        nan if window is None else window[0], nan if window is None else window[1],
        nan if s.odo_speed_mps is None else s.odo_speed_mps,
        nan if s.last_output_t is None else s.last_output_t,
        nan if last_match_t is None else last_match_t, s.gps_bias_bound_sigma_m),
        dtype=np.float64)


def unpack_scalars(s: RoadState, scalars: Array) -> None:
    """Write the run's scalar state back into the filter's (NaN as None; NaN is the one
    value not equal to itself)."""
    t, accel, still, distance, window_t, window_d, speed, output, _, _ = scalars.tolist()
    s.t = t
    s.accel_fwd_mps2 = accel if accel == accel else None
    s.still_samples = int(still)
    s.last_odo_distance_m = distance if distance == distance else None
    s.last_odo = (window_t, window_d) if window_t == window_t else None
    s.odo_speed_mps = speed if speed == speed else None
    s.last_output_t = output if output == output else None
