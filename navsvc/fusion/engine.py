"""FusionEngine: the multi-rate EKF of one vehicle (pure: no I/O, no clock).

Seed: Mayhew 1999, chapter 5. The filter predicts at every inertial, odometer or steering
sample with the real time step, and corrects with each sensor's measurement model
(:mod:`navsvc.fusion.motion`). GPS arrives asynchronously (about 1 Hz) and is fused by one of
three modes: ``ekf`` (Kalman update with chi-square gating), ``rules`` (thesis 5.4) or
``fuzzy`` (thesis 5.5). While the odometer reads no motion for 20+ samples the vehicle is
stationary: zero-velocity updates hold it and calibrate the gyro bias (thesis: gyro centre).

Packets up to ``reorder_window_s`` late are applied in time order (the state is rolled back
and the later packets replayed); older ones are refused with ``time_backwards``. The state is
saved every ``SNAPSHOT_EVERY`` packets, not at each: a late packet replays a few more, and the
copies no longer cost a tenth of the time per packet.

The per-vehicle state is :class:`FusionState` (plain data); the engine owns one.
"""

from __future__ import annotations

import enum
import math
from collections import deque
from dataclasses import dataclass, field, replace

import numpy as np

from navsvc.errors import ConfigError, PacketError, RejectReason
from navsvc.fusion import kalman, motion
from navsvc.fusion.gps_fuzzy import THESIS_SETS, FuzzySets, fuzzy_weights
from navsvc.fusion.gps_rules import GpsAction, GpsDecision, RuleParams, decide_rules
from navsvc.fusion.kalman import Array
from navsvc.fusion.motion import (
    GYRO_BIAS,
    HEADING,
    HEADING_RATE,
    N_STATES,
    ODO_SCALE,
    SPEED,
    X_M,
    Y_M,
    ProcessNoise,
    SensorConfig,
)
from navsvc.types import (
    FusedEstimate,
    GpsFix,
    GpsFixType,
    GpsUsage,
    GpsVelocity,
    ImuSample,
    OdometerSample,
    Packet,
    SteeringSample,
)
from roadgraph.geometry import LocalFrame, bearing_rad


class GpsMode(enum.Enum):
    EKF = "ekf"
    RULES = "rules"
    FUZZY = "fuzzy"


# A fix type alone says little: only the corrected solutions are trusted by type (a plain 3D
# fix in a street canyon is off by tens of metres as often as not).
_FIX_SIGMA_M = {GpsFixType.RTK: 0.05, GpsFixType.DGPS: 1.0}


def gps_problem(fix: GpsFix, cfg: FusionConfig) -> str | None:
    """Why a fix is bad (thesis validity rules), or None when it is good."""
    if not fix.status_ok:
        return "receiver status bad"
    if fix.fix == GpsFixType.NONE:
        return "no fix"
    if fix.sats is not None and fix.sats < cfg.min_sats:
        return f"{fix.sats} satellites (< {cfg.min_sats})"
    if fix.hdop is not None and fix.hdop > cfg.max_hdop:
        return f"HDOP {fix.hdop:g} (> {cfg.max_hdop:g})"
    return None


def gps_sigma_m(fix: GpsFix, cfg: FusionConfig) -> float:
    """1-σ horizontal error of a fix: its own accuracy, else HDOP × UERE, else by fix type
    (RTK, DGPS), else the conservative ``gps_default_sigma_m``."""
    if fix.accuracy_m is not None and fix.accuracy_m > 0.0:
        return fix.accuracy_m
    if fix.hdop is not None and fix.hdop > 0.0:
        return fix.hdop * cfg.gps_uere_m
    if fix.fix in _FIX_SIGMA_M:
        return _FIX_SIGMA_M[fix.fix]
    return cfg.gps_default_sigma_m


@dataclass(frozen=True)
class FusionConfig:
    """Fusion parameters; every field may be overridden per session."""

    sensors: SensorConfig = SensorConfig.GYRO_ODOMETER
    gps_mode: GpsMode = GpsMode.EKF
    process: ProcessNoise = ProcessNoise()
    gyro_sigma_rps: float = 0.005  # white noise of one gyro sample
    odometer_sigma_mps: float = 0.15  # speed from one odometer interval
    accel_sigma_mps2: float = 0.3
    steering_sigma_rad: float = 0.005
    wheelbase_m: float = 2.7
    ticks_per_m: float = 27.3  # thesis: ABS pulses per metre
    gps_uere_m: float = 3.5  # sigma = HDOP x UERE when no accuracy_m is given (tuned: bench)
    gps_default_sigma_m: float = 10.0  # a fix that says nothing of its accuracy
    gps_velocity_sigma_mps: float = 0.5
    min_speed_for_gps_heading_mps: float = 2.8  # thesis m_GPSVelocityThreshold
    gps_gate_scale: float = 1.0  # chi-square gate multiplier (ekf mode)
    gps_nis_memory_fixes: float = 30.0  # ekf: the fixes the GPS error level is learnt over
    gps_huber_nis: float = 5.99  # ekf: a fix past this NIS (95 %, 2 dof) pulls as one at it
    gps_bias_share: float = 0.7  # ekf: of a fix's sigma, the part that is a slowly changing
    # error: averaging fixes does not remove it, so the reported position sigma includes it
    reacquire_after_gated_s: float = 30.0  # ekf: fixes refused this long → start over from GPS
    inflate_after_gated_fixes: int = 3  # ekf: refused this often in a row → widen position P
    reset_heading_after_gated_courses: int = 3  # ekf: GPS course refused this often → adopt it
    max_hdop: float = 20.0  # thesis validity: DOP > 20 is bad
    min_sats: int = 3  # thesis validity: fewer than 3 satellites is bad
    stationary_after_samples: int = 20  # thesis: odometer zero for 20+ samples
    odometer_window_s: float = 0.25  # speed from distance over at least this long (ticks)
    initial_heading_min_move_m: float = 15.0  # heading from two fixes at least this far apart
    initial_heading_min_move_sigmas: float = 4.0  # ... and this many fix sigmas apart
    initial_speed_sigma_mps: float = 5.0  # speed at start-up when nothing measured it
    odo_scale_limits: tuple[float, float] = (0.7, 1.3)  # a wheel odometer is never further off
    reorder_window_s: float = 0.25
    output_interval_s: float = 1.0  # emit an estimate at least this often (GPS outages)
    max_step_s: float = 0.1  # longer gaps are propagated in steps of this size
    initial_gyro_bias_sigma_rps: float = 0.02
    initial_odo_scale_sigma: float = 0.05
    rules: RuleParams = RuleParams()
    fuzzy: FuzzySets = THESIS_SETS

    def __post_init__(self) -> None:
        positive = ("gyro_sigma_rps", "odometer_sigma_mps", "accel_sigma_mps2", "wheelbase_m",
                    "ticks_per_m", "gps_uere_m", "gps_default_sigma_m", "max_step_s",
                    "output_interval_s", "gps_gate_scale")
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ConfigError(f"{name} must be a finite number > 0, got {value}")
        if self.sensors == SensorConfig.GPS_ONLY and self.process.turn_rate_tau_s is None:
            object.__setattr__(self, "process", replace(self.process, turn_rate_tau_s=3.0))
        if self.sensors == SensorConfig.STRAPDOWN and self.gps_mode != GpsMode.EKF:
            raise ConfigError("strapdown fuses GPS in its error-state EKF: fusion must be ekf")
        if self.sensors == SensorConfig.GPS_ONLY and self.gps_mode != GpsMode.EKF:
            raise ConfigError("gps_only needs gps_mode ekf: the rules and fuzzy modes blend GPS "
                              "into dead reckoning, and gps_only has none")
        if self.reorder_window_s < 0.0:
            raise ConfigError(f"reorder_window_s must be >= 0, got {self.reorder_window_s}")


SNAPSHOT_EVERY = 8  # packets between saved states in the reorder window
MAX_PLAUSIBLE_SPEED_MPS = 70.0  # two fixes implying more are not the same car's track


@dataclass
class FusionState:
    """Everything one vehicle's filter remembers (plain data, owned by the session)."""

    x: Array = field(default_factory=lambda: np.zeros(N_STATES))
    P: Array = field(default_factory=lambda: np.eye(N_STATES))
    t: float | None = None  # time of x
    initialized: bool = False
    first_fix: tuple[float, float, float, float] | None = None  # (t, x, y, sigma) awaiting a
    # heading
    odo_speed_mps: float | None = None  # the odometer's latest speed (start-up, re-acquiring)
    last_odo: tuple[float, float] | None = None  # (t, cumulative distance m) window start
    last_odo_distance_m: float | None = None  # previous raw reading (stationary detection)
    still_samples: int = 0
    accel_fwd_mps2: float | None = None  # last forward acceleration (configs 3 and 4)
    gated_fixes: int = 0  # consecutive GPS fixes refused by the gate
    first_gated_t: float | None = None  # when the current run of refused fixes began
    gps_nis_mean: float = 2.0  # running mean of the fixes' NIS (2 when their sigma is right)
    gps_bias_var_m2: float = 0.0  # variance of the GPS error the filter cannot average out
    gated_courses: int = 0  # consecutive GPS course/speed updates refused by the gate
    last_gps_t: float | None = None
    last_output_t: float | None = None
    gps: GpsUsage | None = None
    late_rejected: int = 0


class FusionEngine:
    """One vehicle's filter. ``add`` a packet, get the estimates it produced."""

    def __init__(self, config: FusionConfig = FusionConfig(),
                 frame: LocalFrame | None = None) -> None:
        if config.sensors == SensorConfig.STRAPDOWN:
            raise ConfigError("the strapdown configuration runs in StrapdownEngine "
                              "(navsvc.fusion.strapdown)")
        self.config = config
        self.frame = frame
        self.state = FusionState()
        self._gyro = config.sensors not in (SensorConfig.STEERING_ODOMETER, SensorConfig.GPS_ONLY)
        # the reorder window: groups of packets applied, each with the state before its first
        self._history: deque[tuple[FusionState, list[Packet]]] = deque()

    # --- public --------------------------------------------------------------------------
    @property
    def t(self) -> float | None:
        """Time of the filter's state (the latest packet applied)."""
        return self.state.t

    def add(self, packet: Packet) -> list[FusedEstimate]:
        """Apply one packet in time order; return the estimates it emitted (GPS epochs, ticks).

        Raises :class:`PacketError` (``time_backwards``) for a packet older than the window.
        """
        t_now = self.state.t
        if t_now is None or packet.t >= t_now:
            return self._apply_logged(packet)
        if packet.t < t_now - self.config.reorder_window_s or not self._history \
                or packet.t < self._history[0][1][0].t:
            self.state.late_rejected += 1
            raise PacketError(RejectReason.TIME_BACKWARDS,
                              f"t={packet.t} is {t_now - packet.t:.3f} s before the latest "
                              f"packet (window {self.config.reorder_window_s} s)")
        return self._replay_with(packet)

    def estimate(self) -> FusedEstimate | None:
        """The current estimate, or None before initialisation."""
        return self._estimate() if self.state.initialized else None

    def correct(self, z: Array, h: Array, H: Array, R: Array) -> bool:
        """Apply an external measurement (map feedback); False when it fails the gate."""
        if not self.state.initialized:
            return False
        s, limit = self.state, kalman.gate_limit(len(z))
        s.x, s.P, nis = kalman.correct(s.x, s.P, z, h, H, R, limit)
        if not nis <= limit:
            return False
        self._history.clear()  # an external correction cannot be replayed
        return True

    # --- ordering ------------------------------------------------------------------------
    def _apply_logged(self, packet: Packet) -> list[FusedEstimate]:
        if self.config.reorder_window_s > 0.0:
            history = self._history
            if not history or len(history[-1][1]) >= SNAPSHOT_EVERY:
                history.append((_snapshot(self.state), [packet]))
            else:
                history[-1][1].append(packet)
            # a group can go once the next one starts before the window: it covers the rest
            horizon = packet.t - self.config.reorder_window_s
            while len(history) > 1 and history[1][1][0].t < horizon:
                history.popleft()
        return self._apply(packet)

    def _replay_with(self, late: Packet) -> list[FusedEstimate]:
        groups = list(self._history)
        g = next(k for k in range(len(groups) - 1, -1, -1) if groups[k][1][0].t <= late.t)
        replay = [p for _, packets in groups[g:] for p in packets]
        before = next((i for i, p in enumerate(replay) if p.t > late.t), len(replay))
        for _ in range(len(groups) - g):
            self._history.pop()
        late_count = self.state.late_rejected  # refusals since the saved state stay counted
        self.state = groups[g][0]  # out of the history now: no copy needed
        for p in replay[:before]:
            self._apply_logged(p)  # outputs of replayed packets were already emitted
        out = self._apply_logged(late)
        for p in replay[before:]:
            self._apply_logged(p)
        self.state.late_rejected = late_count
        return out

    # --- one packet ----------------------------------------------------------------------
    def _apply(self, packet: Packet) -> list[FusedEstimate]:
        s = self.state
        if not s.initialized:
            if isinstance(packet, GpsFix):
                self._try_initialize(packet)
                return [self._estimate()] if s.initialized else []
            self._remember_odometer(packet)
            return []
        gyro = packet.yaw_rate_rps if isinstance(packet, ImuSample) and self._gyro else None
        self._propagate_to(packet.t, gyro)
        if isinstance(packet, GpsFix):
            self._fuse_gps(packet)
            s.last_output_t = packet.t
            return [self._estimate()]
        if isinstance(packet, GpsVelocity):
            self._fuse_gps_velocity(packet)
        else:
            self._fuse_dead_reckoning(packet)
        if s.last_output_t is None or packet.t - s.last_output_t >= self.config.output_interval_s:
            s.last_output_t = packet.t
            return [self._estimate()]
        return []

    def _propagate_to(self, t: float, gyro_rps: float | None = None) -> None:
        """Predict to ``t``; with a gyro sample, its update too (one compiled call)."""
        s, cfg = self.state, self.config
        assert s.t is not None
        accel = s.accel_fwd_mps2 if cfg.sensors.speed_from_accel else None
        if gyro_rps is not None:
            s.x, s.P = motion.predict_with_gyro(s.x, s.P, max(t - s.t, 0.0), cfg.max_step_s,
                                                accel, cfg.process, gyro_rps, cfg.gyro_sigma_rps)
        elif t - s.t > 1e-9:
            s.x, s.P = motion.predict(s.x, s.P, t - s.t, cfg.max_step_s, accel, cfg.process)
        s.t = max(s.t, t)

    def _update(self, m: motion.Measurement, gate_dof: int | None = None) -> float | None:
        """Kalman update; with ``gate_dof``, refuse (return None) past the chi-square gate."""
        z, h, H, R = m
        s = self.state
        limit = math.inf if gate_dof is None else \
            kalman.gate_limit(gate_dof, self.config.gps_gate_scale)
        s.x, s.P, nis = kalman.correct(s.x, s.P, z, h, H, R, limit)
        if not nis <= limit:
            return None
        s.x[HEADING] %= 2.0 * math.pi
        low, high = self.config.odo_scale_limits
        s.x[ODO_SCALE] = min(max(s.x[ODO_SCALE], low), high)
        return nis

    # --- dead reckoning ------------------------------------------------------------------
    def _fuse_dead_reckoning(self, packet: Packet) -> None:
        cfg, x = self.config, self.state.x
        if isinstance(packet, ImuSample):  # its gyro rate went in with the prediction
            if packet.accel_fwd_mps2 is not None:
                self.state.accel_fwd_mps2 = packet.accel_fwd_mps2
            if packet.accel_left_mps2 is not None and \
                    cfg.sensors == SensorConfig.GYRO_TWO_ACCELS:
                self._update(motion.lateral_accel(self.state.x, packet.accel_left_mps2,
                                                  cfg.accel_sigma_mps2))
        elif isinstance(packet, OdometerSample):
            self._fuse_odometer(packet)
        elif isinstance(packet, SteeringSample) and \
                cfg.sensors == SensorConfig.STEERING_ODOMETER:
            self._update(motion.steering_rate(x, packet.angle_rad, cfg.wheelbase_m,
                                              cfg.steering_sigma_rad))

    def _fuse_odometer(self, packet: OdometerSample) -> None:
        cfg, s = self.config, self.state
        if cfg.sensors.speed_from_accel or cfg.sensors == SensorConfig.GPS_ONLY:
            return
        if self._odometer_still(packet):
            s.still_samples += 1
            if s.still_samples >= cfg.stationary_after_samples:
                self._update(motion.zero_motion(s.x))
                return
        else:
            s.still_samples = 0
        speed = self._odometer_speed(packet)
        if speed is not None:
            s.odo_speed_mps = speed
            self._update(motion.odometer_speed(s.x, speed, cfg.odometer_sigma_mps))

    def _odometer_distance_m(self, packet: OdometerSample) -> float | None:
        if packet.distance_m is not None:
            return packet.distance_m
        return None if packet.ticks is None else packet.ticks / self.config.ticks_per_m

    def _odometer_still(self, packet: OdometerSample) -> bool:
        if packet.speed_mps is not None:
            return packet.speed_mps == 0.0
        distance = self._odometer_distance_m(packet)
        previous, self.state.last_odo_distance_m = self.state.last_odo_distance_m, distance
        return distance is not None and distance == previous

    def _odometer_speed(self, packet: Packet) -> float | None:
        """Speed from a speed reading, or from cumulative distance over a window (ticks are
        coarse: one tick in 20 ms is 1.8 m/s)."""
        if not isinstance(packet, OdometerSample):
            return None
        if packet.speed_mps is not None:
            return packet.speed_mps
        distance = self._odometer_distance_m(packet)
        if distance is None:
            return None
        last = self.state.last_odo
        if last is None or packet.t < last[0] or distance < last[1]:
            self.state.last_odo = (packet.t, distance)
            return None
        if packet.t - last[0] < self.config.odometer_window_s:
            return None
        self.state.last_odo = (packet.t, distance)
        return (distance - last[1]) / (packet.t - last[0])

    def _remember_odometer(self, packet: Packet) -> None:
        if isinstance(packet, OdometerSample):
            self._odometer_still(packet)
            speed = self._odometer_speed(packet)
            if speed is not None:
                self.state.odo_speed_mps = speed
        self.state.t = packet.t if self.state.t is None else max(self.state.t, packet.t)

    # --- GPS -----------------------------------------------------------------------------
    def _local(self, fix: GpsFix) -> tuple[float, float]:
        if self.frame is None:
            self.frame = LocalFrame.for_point(fix.lon_deg, fix.lat_deg)
        return self.frame.to_local(fix.lon_deg, fix.lat_deg)

    def _try_initialize(self, fix: GpsFix) -> None:
        """Start once the heading is known: from the GPS course when fast enough for it to
        mean something, else from the bearing between two fixes a long way apart against
        their error. Each starting value gets the variance of how it was obtained."""
        s, cfg = self.state, self.config
        bad = gps_problem(fix, self.config)
        s.t = fix.t if s.t is None else max(s.t, fix.t)
        if bad is not None:
            s.gps = GpsUsage(False, 0.0, bad)
            return
        east, north = self._local(fix)
        sigma = gps_sigma_m(fix, cfg)
        heading = self._gps_course(fix)
        speed = self._measured_speed(fix)
        first = s.first_fix
        if heading is None and first is not None and fix.t > first[0]:
            t0, e0, n0, sigma0 = first
            moved, spread = math.hypot(east - e0, north - n0), math.hypot(sigma, sigma0)
            if moved > MAX_PLAUSIBLE_SPEED_MPS * (fix.t - t0) or self._standing():
                first = None  # an outlier, or the fixes of a car standing still: start over
            elif moved >= max(cfg.initial_heading_min_move_m,
                              cfg.initial_heading_min_move_sigmas * spread):
                heading = bearing_rad(e0, n0, east, north), (spread / moved) ** 2
                if speed is None:
                    speed = moved / (fix.t - t0), (spread / (fix.t - t0)) ** 2
        if heading is None:
            s.first_fix = first or (fix.t, east, north, sigma)
            s.gps = GpsUsage(False, 0.0, "initialising: waiting for a heading")
            return
        self._reset_from_gps(fix, east, north, heading,
                             speed or (0.0, cfg.initial_speed_sigma_mps ** 2))
        s.initialized = True
        s.first_fix = None
        s.gps = GpsUsage(True, 1.0, "initialised from GPS")

    def _standing(self) -> bool:
        """The odometer says the car stands still (GPS fixes then only wander)."""
        return self.state.odo_speed_mps == 0.0

    def _measured_speed(self, fix: GpsFix) -> tuple[float, float] | None:
        """Speed and its variance from the odometer when there is one, else the GPS."""
        cfg, s = self.config, self.state
        if s.odo_speed_mps is not None and cfg.sensors not in (SensorConfig.GPS_ONLY,
                                                                SensorConfig.GYRO_ACCEL,
                                                                SensorConfig.GYRO_TWO_ACCELS):
            v = s.odo_speed_mps
            return v, cfg.odometer_sigma_mps ** 2 + (cfg.initial_odo_scale_sigma * v) ** 2
        if fix.speed_mps is not None:
            return fix.speed_mps, cfg.gps_velocity_sigma_mps ** 2
        return None

    def _gps_course(self, fix: GpsFix) -> tuple[float, float] | None:
        """The GPS course and its variance, when the receiver is fast enough for it to mean
        something (its error grows as the speed falls)."""
        cfg, speed = self.config, fix.speed_mps or 0.0
        if fix.heading_rad is None or speed < cfg.min_speed_for_gps_heading_mps:
            return None
        sigma = max(math.radians(2.0), math.atan2(cfg.gps_velocity_sigma_mps, speed))
        return fix.heading_rad, sigma ** 2

    def _reset_from_gps(self, fix: GpsFix, east: float, north: float,
                        heading: tuple[float, float] | None,
                        speed: tuple[float, float] | None) -> None:
        """Position from the fix; heading and speed, with their variances, when given."""
        s, cfg = self.state, self.config
        sigma = gps_sigma_m(fix, self.config)
        s.x[X_M], s.x[Y_M] = east, north
        s.P[[X_M, Y_M], :] = 0.0
        s.P[:, [X_M, Y_M]] = 0.0
        s.P[X_M, X_M] = s.P[Y_M, Y_M] = sigma ** 2
        if heading is not None:
            s.x[HEADING] = heading[0] % (2.0 * math.pi)
            _reset_variance(s.P, HEADING, heading[1])
        if speed is not None:
            s.x[SPEED] = speed[0]
            _reset_variance(s.P, SPEED, speed[1])
        if not s.initialized:
            s.x[HEADING_RATE], s.x[GYRO_BIAS], s.x[ODO_SCALE] = 0.0, 0.0, 1.0
            for i, var in ((HEADING_RATE, 0.1 ** 2),
                           (GYRO_BIAS, cfg.initial_gyro_bias_sigma_rps ** 2),
                           (ODO_SCALE, cfg.initial_odo_scale_sigma ** 2),
                           (motion.ACCEL_BIAS, 0.1 ** 2)):
                _reset_variance(s.P, i, var)
        s.gated_fixes, s.first_gated_t = 0, None

    def _fuse_gps(self, fix: GpsFix) -> None:
        s = self.state
        dt = fix.t - s.last_gps_t if s.last_gps_t is not None else 1.0
        s.last_gps_t = fix.t
        bad = gps_problem(fix, self.config)
        if bad is not None:
            s.gps = GpsUsage(False, 0.0, bad)
            return
        if self.config.gps_mode == GpsMode.EKF:
            self._fuse_gps_ekf(fix, dt)
        else:
            self._fuse_gps_weighted(fix, dt)

    def _fuse_gps_ekf(self, fix: GpsFix, dt_s: float) -> None:
        """A fix, weighted by how well it agrees (innovation NIS).

        - Its sigma is learnt: scaled up when the fixes have been further off than their
          sigmas say (HDOP x UERE is optimistic in a street canyon); fixes faster than one a
          second are not taken as independent (their errors are one slowly changing error).
        - Past ``gps_huber_nis`` it pulls as a fix at that NIS would (Huber), so that a run of
          biased fixes is down-weighted, not followed.
        - Past the chi-square gate it is refused, but still pulls as one at the Huber limit;
          when fixes keep being refused the position variance widens by a fix's variance a
          second, so that fixes which agree with each other are taken within seconds; after
          ``reacquire_after_gated_s`` the filter starts over from GPS.
        - ``gps_bias_share`` of the sigma is an error no averaging removes: it is added to the
          reported position covariance, not to the filter's (that would make it follow GPS
          noise)."""
        s, cfg = self.state, self.config
        east, north = self._local(fix)
        sigma = self._gps_sigma_learnt(fix) * math.sqrt(max(1.0, 1.0 / max(dt_s, 1e-3)))
        z, h, H, R = motion.gps_position(s.x, east, north, sigma)
        y = z - h
        nis = float(y @ np.linalg.solve(H @ s.P @ H.T + R, y))
        if math.isfinite(nis):
            memory = cfg.gps_nis_memory_fixes * max(1.0, 1.0 / max(dt_s, 1e-3))
            s.gps_nis_mean += (min(nis, 10.0 * cfg.gps_huber_nis) - s.gps_nis_mean) / memory
        if not nis <= kalman.gate_limit(2, cfg.gps_gate_scale):  # NaN too
            self._refused_fix(fix, east, north, (z, h, H, R), nis, min(dt_s, 1.0))
            return
        weight = min(1.0, cfg.gps_huber_nis / nis) if nis > 0.0 else 1.0
        self._update((z, h, H, R / weight))
        s.gps_bias_var_m2 = (cfg.gps_bias_share * self._gps_sigma_learnt(fix)) ** 2
        s.gated_fixes, s.first_gated_t = 0, None
        course = self._gps_course(fix)
        if course is not None and fix.speed_mps is not None:
            self._fuse_gps_course(course[0], fix.speed_mps)
        elif cfg.sensors == SensorConfig.GPS_ONLY and fix.speed_mps is not None \
                and fix.speed_mps < 0.5:
            self._update(motion.zero_motion(s.x, sigma_mps=0.3, sigma_rps=0.05))
        s.gps = GpsUsage(True, weight, "accepted" if weight == 1.0 else "down-weighted",
                         nis=nis)

    def _gps_sigma_learnt(self, fix: GpsFix) -> float:
        """The fix's sigma, scaled by the running mean of the NIS (innovation-based
        adaptation: 2 is the mean when the sigmas are right)."""
        return gps_sigma_m(fix, self.config) * math.sqrt(max(1.0, self.state.gps_nis_mean / 2.0))

    def _refused_fix(self, fix: GpsFix, east: float, north: float, m: motion.Measurement,
                     nis: float, dt_s: float) -> None:
        s, cfg = self.state, self.config
        z, h, H, R = m
        s.gated_fixes += 1
        s.first_gated_t = fix.t if s.first_gated_t is None else s.first_gated_t
        if not math.isfinite(nis) or fix.t - s.first_gated_t >= cfg.reacquire_after_gated_s:
            s.initialized = False  # heading and speed are not to be trusted either
            s.first_fix = (fix.t, east, north, gps_sigma_m(fix, cfg))
            s.gps = GpsUsage(False, 0.0, "re-acquiring: estimate far from GPS too long")
            return
        weight = cfg.gps_huber_nis / nis
        self._update((z, h, H, R / weight))
        if s.gated_fixes >= cfg.inflate_after_gated_fixes:
            s.P[X_M, X_M] += R[0, 0] * dt_s
            s.P[Y_M, Y_M] += R[1, 1] * dt_s
        s.gps = GpsUsage(True, weight, "down-weighted: innovation too large", nis=nis)

    def _fuse_gps_velocity(self, v: GpsVelocity) -> None:
        """A velocity-only GPS message (NMEA VTG): course and speed when moving."""
        if v.heading_rad is not None and v.speed_mps >= self.config.min_speed_for_gps_heading_mps:
            self._fuse_gps_course(v.heading_rad, v.speed_mps)

    def _fuse_gps_course(self, course_rad: float, speed_mps: float) -> None:
        """GPS course and speed; a heading the gate keeps refusing is replaced by the course
        (after a long stop or outage the filter's heading can be far off and overconfident)."""
        s, cfg = self.state, self.config
        gate = None if cfg.sensors == SensorConfig.GPS_ONLY else 2  # GPS is the only heading
        nis = self._update(motion.gps_velocity(s.x, speed_mps, course_rad,
                                               cfg.gps_velocity_sigma_mps), gate_dof=gate)
        if nis is not None:
            s.gated_courses = 0
            return
        s.gated_courses += 1
        if s.gated_courses >= cfg.reset_heading_after_gated_courses:
            s.x[HEADING], s.x[SPEED] = course_rad % (2.0 * math.pi), speed_mps
            _reset_variance(s.P, HEADING, math.radians(10.0) ** 2)
            _reset_variance(s.P, SPEED, 1.0)
            s.gated_courses = 0

    def _fuse_gps_weighted(self, fix: GpsFix, dt_s: float) -> None:
        s, cfg = self.state, self.config
        east, north = self._local(fix)
        distance = math.hypot(east - s.x[X_M], north - s.x[Y_M])
        if cfg.gps_mode == GpsMode.RULES:
            decision = decide_rules(cfg.rules, gps_ok=True, initialized=True,
                                    distance_m=distance, gps_speed_mps=fix.speed_mps,
                                    rejected_fixes=s.gated_fixes, dt_s=dt_s)
        else:
            pos_w, head_w = fuzzy_weights(cfg.fuzzy, distance, fix.speed_mps or 0.0,
                                          s.gated_fixes)
            action = GpsAction.REINITIALIZE if pos_w > 0.99 else \
                GpsAction.BLEND if pos_w > 0.0 else GpsAction.REJECT
            decision = GpsDecision(action, pos_w, head_w, f"fuzzy weight {pos_w:.3f}")
        self._apply_decision(fix, decision, east, north)

    def _apply_decision(self, fix: GpsFix, d: GpsDecision, east: float, north: float) -> None:
        s = self.state
        if d.action == GpsAction.REJECT:
            s.gated_fixes += 1
            s.gps = GpsUsage(False, 0.0, d.reason)
            return
        s.gated_fixes = 0
        if d.action in (GpsAction.REINITIALIZE, GpsAction.INITIALIZE):
            self._reset_from_gps(fix, east, north, self._gps_course(fix),
                                 self._measured_speed(fix))
            s.gps = GpsUsage(True, 1.0, d.reason)
            return
        sigma = gps_sigma_m(fix, self.config)
        z, h, H, R = motion.gps_position(s.x, east, north, sigma)
        s.x, s.P = kalman.fixed_gain_update(s.x, s.P, z - h, H, R, d.position_weight * H.T)
        course = self._gps_course(fix)
        if course is not None and d.heading_weight > 0.0 and fix.speed_mps is not None:
            heading = course[0]
            # weighted sum of heading (wrapped) and speed with the GPS course and speed
            H = np.zeros((2, N_STATES))
            H[0, HEADING] = H[1, SPEED] = 1.0
            y = np.array([math.remainder(heading - s.x[HEADING], 2.0 * math.pi),
                          fix.speed_mps - s.x[SPEED]])
            R = np.diag([math.radians(5.0) ** 2, self.config.gps_velocity_sigma_mps ** 2])
            s.x, s.P = kalman.fixed_gain_update(s.x, s.P, y, H, R, d.heading_weight * H.T)
            s.x[HEADING] %= 2.0 * math.pi
        s.gps = GpsUsage(True, d.position_weight, d.reason)

    # --- output --------------------------------------------------------------------------
    def _estimate(self) -> FusedEstimate:
        s = self.state
        return FusedEstimate(
            t=float(s.t or 0.0), x_m=float(s.x[X_M]), y_m=float(s.x[Y_M]),
            heading_rad=float(s.x[HEADING] % (2.0 * math.pi)), speed_mps=float(s.x[SPEED]),
            yaw_rate_rps=float(s.x[HEADING_RATE]),
            position_cov_m2=s.P[:2, :2] + s.gps_bias_var_m2 * np.eye(2),
            heading_sigma_rad=float(math.sqrt(max(s.P[HEADING, HEADING], 0.0))),
            initialized=s.initialized, gps=s.gps, gps_bias_var_m2=s.gps_bias_var_m2,
        )


def _reset_variance(P: Array, i: int, variance: float) -> None:
    P[i, :] = 0.0
    P[:, i] = 0.0
    P[i, i] = variance


def _snapshot(state: FusionState) -> FusionState:
    """A copy that later updates cannot reach (taken every ``SNAPSHOT_EVERY`` packets: kept
    cheap; the only mutable fields are the two arrays, ``gps`` is frozen)."""
    snap = object.__new__(FusionState)  # copy.copy took a third of the time, for the same
    snap.__dict__.update(state.__dict__)
    snap.x = state.x.copy()
    snap.P = state.P.copy()
    return snap
