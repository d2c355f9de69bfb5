"""The INS's loosely coupled GNSS error-state EKF (pure): the ``feedback`` and ``feedforward``
integrations.

Seed: Giroux, Gourdeau, Landry 2005 (docs/seed-digest.md); conventions as KF-GINS.

- Error state (25): KF-GINS's 21, position error (NED, m), velocity error (NED, m/s), attitude
  error ψ (rad; estimated attitude = (I + [ψ×]) true), gyro and accelerometer biases (rad/s,
  m/s²) and scale factors (measured = (1 + scale) true + bias), each a first-order
  Gauss–Markov process; and the GNSS position bias (north, east, m), the slowly changing part
  of the fixes' error (as the road filter's), a Gauss–Markov process of its own time constant
  and steady sigma, which the caller sets from the fixes' sigma (zero: none, as KF-GINS).
  The bias is *considered*, not estimated (a Schmidt filter: every update leaves it, with a
  zero gain, and the Joseph form keeps ``P`` right for that gain): its covariance says that
  successive fixes err alike, so they no longer average into a heading and position surer
  than they are, while the position cannot drift off under a bias estimate that follows it.
  Taken as white, the fixes' error averaged away: over 20 harsh drives the heading was a
  median 1.3 degrees off and 46 % of the epochs at speed lay past 2.45 of its sigmas (the
  road filter, with its bias states: 0.5 degrees, 1.5 %; considered: 0.84 degrees, 21 %, the
  rest mostly non-line-of-sight runs); estimated, the bias's random walk
  took what the fixes said of the position (the INS ran 20 m off with the bias estimate
  following it, every fix "accepted"). And the receiver's latency (s): a fix is where the
  antenna was that long before its time stamp, metres back along the track at speed
  (comma2k19's u-blox: about 0.1 s, 2 m on the highway). Considered too, at the road
  filter's prior (0.1 +- 0.1 s): a constant along-track offset is the bias's as much as the
  latency's, so fixes hardly teach it (300 s of simulated 10 Hz fixes 0.2 s late took an
  estimate from 0.1 s to 0.04-0.11 s), and an estimate took up what a wrong heading left
  (0.43 s on a drive that was 0.14 s late, 7 -> 22 m rms). And the IMU's mount pitch (a
  constant, estimated): the non-holonomic constraint and the wheel speed hold for the
  vehicle's axes, not for an IMU pitched in it (comma2k19's phone: about 4 degrees); taken
  as level, the constraint pitched the attitude until gravity leaked into the velocity (78 m
  off after a 20 s outage). A yawed mount needs no state: the heading takes it up (the
  gyro's down axis does not see it; forward acceleration leaks sideways only while the car
  speeds up or slows down, gravity never). Zero sigmas leave these out, as KF-GINS.
- Integrations: ``feedback`` (default; each correction goes into the navigation state and the
  biases, and the error state is reset to zero) and ``feedforward`` (the inertial solution runs
  open loop; the output is that solution less the estimated error, which keeps propagating);
  the paper's third, ``direct`` (the EKF over the navigation state itself), is
  :class:`navsvc.fusion.ins.total_state.DirectInsFilter`, on the same measurement interface.
- GNSS position updates with lever arm and a chi-square gate, GNSS velocity; body-frame
  velocity updates for wheel speed, the non-holonomic constraint (no sideways or vertical
  motion) and stops.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from navsvc.fusion import kalman
from navsvc.fusion._jit import Array, jit
from navsvc.fusion.ins.attitude import body_to_vehicle, dcm_to_euler, rotation, skew
from navsvc.fusion.ins.earth import EARTH_RATE_RPS, EarthModel, nav_rates, radii_m
from navsvc.fusion.ins.measurements import BodyVelocity, GnssPosition
from navsvc.fusion.ins.mechanisation import Mechanisation, NavState, mechanise, sample_problem

if TYPE_CHECKING:
    from navsvc.fusion.ins.measurements import InsMeasurement

N_ERR = 25
N_KFGINS = 21  # the states KF-GINS has (all but the GNSS bias, its latency, the mount)
POS, VEL, ATT, BG, BA = (slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12), slice(12, 15))
SG, SA = slice(15, 18), slice(18, 21)  # gyro and accelerometer scale factors
GB = slice(21, 23)  # GNSS position bias, north and east
LAT = 23  # GNSS latency
MNT = 24  # the mount's pitch
CONSIDERED = (21, 22, 23)  # the states every update leaves as they are: GNSS bias, latency
GATE_FLOOR_M = 0.5
GATED_BEFORE_SOFT = 3


class Integration(enum.Enum):
    FEEDBACK = "feedback"
    FEEDFORWARD = "feedforward"
    DIRECT = "direct"  # the EKF over the navigation state itself: total_state.DirectInsFilter


@dataclass(frozen=True)
class ImuNoise:
    """Continuous noise densities and bias processes (KF-GINS's units converted to SI)."""

    arw_rad_per_sqrt_s: float
    vrw_mps_per_sqrt_s: float
    gyro_bias_sigma_rps: float
    accel_bias_sigma_mps2: float
    bias_corr_time_s: float  # of the biases and the scale factors
    gyro_scale_sigma: float = 1e-3
    accel_scale_sigma: float = 1e-3

    @classmethod
    def from_kfgins(cls, arw_deg_per_sqrt_h: float, vrw_mps_per_sqrt_h: float,
                    gyro_bias_deg_per_h: float, accel_bias_mgal: float,
                    corr_time_h: float, gyro_scale_ppm: float = 1000.0,
                    accel_scale_ppm: float = 1000.0) -> ImuNoise:
        return cls(math.radians(arw_deg_per_sqrt_h) / 60.0, vrw_mps_per_sqrt_h / 60.0,
                   math.radians(gyro_bias_deg_per_h) / 3600.0, accel_bias_mgal * 1e-5,
                   corr_time_h * 3600.0, gyro_scale_ppm * 1e-6, accel_scale_ppm * 1e-6)


@dataclass
class GnssFix:
    t: float
    lat_rad: float
    lon_rad: float
    h_m: float
    sigma_ned_m: Array  # 1-σ north, east, down


class InsFilter:
    """One vehicle's INS with its 25-state error-state EKF."""

    def __init__(self, state: NavState, p0: Array, noise: ImuNoise,
                 lever_arm_b_m: Array | None = None,
                 integration: Integration = Integration.FEEDBACK,
                 mechanisation: Mechanisation = Mechanisation.FIRST_ORDER,
                 earth: EarthModel = EarthModel.WGS84, gps_bias_sigma_m: float = 0.0,
                 gps_bias_tau_s: float = 30.0, gps_latency_sigma_s: float = 0.0,
                 mount_sigma_rad: float = 0.0) -> None:
        """``p0``: the covariance of KF-GINS's 21 states; the GNSS bias starts at its
        steady sigma ``gps_bias_sigma_m`` (:meth:`set_gps_bias_sigma`), the latency (the
        state's) with ``gps_latency_sigma_s``, the mount's pitch (the state's) with
        ``mount_sigma_rad``."""
        self.state = state  # the inertial solution (open loop in feedforward mode)
        self.P = np.zeros((N_ERR, N_ERR))
        self.P[:N_KFGINS, :N_KFGINS] = p0
        self.P[GB, GB] = gps_bias_sigma_m**2 * np.eye(2)
        self.P[LAT, LAT] = gps_latency_sigma_s**2
        self.P[MNT, MNT] = mount_sigma_rad**2
        self.gps_bias_tau_s = gps_bias_tau_s
        self.dx = np.zeros(N_ERR)  # estimated error (stays zero in feedback mode)
        self.noise = noise
        self.lever_arm_b_m = np.zeros(3) if lever_arm_b_m is None else lever_arm_b_m
        self.integration = integration
        self.mechanisation = mechanisation
        self.earth = earth
        self._rotating = 1.0 if earth == EarthModel.WGS84 else 0.0
        self.gated = 0
        q = np.zeros(N_ERR)  # continuous white-noise densities of the error states
        q[VEL] = noise.vrw_mps_per_sqrt_s**2
        q[ATT] = noise.arw_rad_per_sqrt_s**2
        q[BG] = 2.0 * noise.gyro_bias_sigma_rps**2 / noise.bias_corr_time_s
        q[BA] = 2.0 * noise.accel_bias_sigma_mps2**2 / noise.bias_corr_time_s
        q[SG] = 2.0 * noise.gyro_scale_sigma**2 / noise.bias_corr_time_s
        q[SA] = 2.0 * noise.accel_scale_sigma**2 / noise.bias_corr_time_s
        self._q_density = q
        self.set_gps_bias_sigma(gps_bias_sigma_m)

    def set_gps_bias_sigma(self, sigma_m: float) -> None:
        """The GNSS bias's steady sigma (from the latest fix's): its process noise. The
        array is replaced, not written into (snapshots share it)."""
        q = self._q_density.copy()
        q[GB] = 2.0 * sigma_m**2 / self.gps_bias_tau_s
        self._q_density = q

    def predict(self, t: float, dtheta: Array, dvel: Array) -> None:
        """One IMU interval: mechanise, then propagate the error covariance.

        Refused with ValueError, changing nothing: time not increasing, a non-finite sample,
        or a saturated one (above ``MAX_RATE_RPS`` or ``MAX_ACCEL_MPS2``). A gap in IMU time
        is integrated as one long step; the covariance grows with it.
        """
        self._check_sample(t, dtheta, dvel)
        dt = t - self.state.t
        dtheta_c, dvel_c = self.state.compensate(dtheta, dvel, dt)
        self.state, f_n = mechanise(self.state, t, dtheta_c, dvel_c, self.mechanisation,
                                    self.earth)
        s = self.state
        phi = _transition(s.lat_rad, s.h_m, s.v_ned, s.c_bn, f_n, dtheta_c / dt, dvel_c / dt,
                          dt, self.noise.bias_corr_time_s, self.gps_bias_tau_s, self._rotating)
        self.P = _propagate(self.P, phi, self._q_density * dt)
        if self.integration == Integration.FEEDFORWARD:
            self.dx = phi @ self.dx

    def _check_sample(self, t: float, dtheta: Array, dvel: Array) -> None:
        dt = t - self.state.t
        if not dt > 0.0:
            raise ValueError(f"IMU time must increase: {t} after {self.state.t}")
        problem = sample_problem(dtheta, dvel, dt)
        if problem:
            raise ValueError(f"IMU sample at t={t} {problem}")

    def update(self, m: InsMeasurement) -> bool:
        """A measurement at the state's time (the caller predicts to it first), by the one
        Kalman update of :mod:`navsvc.fusion.kalman`; False when the chi-square gate refuses
        it.

        A soft-gated measurement (GNSS position) refused ``GATED_BEFORE_SOFT`` times in a row
        is taken with its noise inflated to the gate: the INS may be the one that is wrong,
        and one outlier cannot drag the solution far. Its gate allows for model error the
        fix's own sigma leaves out (an RTK fix says 1 cm; lever arm, timing and mechanisation
        are not that good).
        """
        z, h, H, R = m.model(self)
        limit = kalman.gate_limit(m.gate_dof)
        if m.soft_gate:
            nis = self.soft_gate_nis(H, R, z - h)
            if nis > limit:
                self.gated += 1
                if self.gated < GATED_BEFORE_SOFT:
                    return False
                R = R * (nis / limit)
            else:
                self.gated = 0
            limit = math.inf
        dx, self.P, nis = kalman.correct_leaving(self.dx, self.P, z, h, H, R, CONSIDERED,
                                                 limit)
        if not nis <= limit:
            return False
        self._correct(dx)
        return True

    def move(self, north_east_m: Array) -> None:
        """Move the solution's position by (north, east) m: following fixes that leapt away
        (which the update refused), not a measurement; the covariance stays."""
        dx = np.zeros(N_ERR)
        dx[0:2] = -north_east_m
        if self.integration == Integration.FEEDFORWARD:
            self.dx = self.dx + dx
        else:
            self.state = corrected(self.state, dx)

    def soft_gate_nis(self, H: Array, R: Array, y: Array) -> float:
        """The NIS a soft-gated measurement's innovation ``y`` is gated by: its noise with
        the gate's floor for the model error its own sigma leaves out (``GATE_FLOOR_M``)."""
        return kalman.nis(self.P, H, R + GATE_FLOOR_M**2 * np.eye(len(y)), y)

    def position_cov_ned_m2(self) -> Array:
        """Covariance of the position (north, east, down; m²)."""
        return self.P[POS, POS].copy()

    def heading_sigma_rad(self) -> float:
        return float(math.sqrt(self.P[8, 8]))

    # measurement models: (predicted - measured, its Jacobian in the filter's state) --------
    def gnss_position_residual(self, fix: GnssFix) -> tuple[Array, Array]:
        """:meth:`position_residual` of a GNSS fix: the antenna's position a latency before
        the fix's time stamp (back along the velocity) plus the GNSS bias (north, east;
        considered, so its value stays at its prior, zero)."""
        y, h = self.position_residual(fix)
        s = self.state
        y[:2] += s.gps_bias_ne_m
        h[:2, GB] = np.eye(2)
        y -= s.v_ned * s.gps_latency_s
        h[:, VEL] = -s.gps_latency_s * np.eye(3)
        h[:, LAT] = -s.v_ned
        return y, h

    def position_residual(self, fix: GnssFix) -> tuple[Array, Array]:
        s = self.state
        rm, rn = radii_m(s.lat_rad)
        lever_n = s.c_bn @ self.lever_arm_b_m
        y = np.array([(s.lat_rad - fix.lat_rad) * (rm + s.h_m),
                      (s.lon_rad - fix.lon_rad) * (rn + s.h_m) * math.cos(s.lat_rad),
                      -(s.h_m - fix.h_m)]) + lever_n
        h = np.zeros((3, N_ERR))
        h[:, POS] = np.eye(3)
        h[:, ATT] = -skew(lever_n)
        return y, h

    def body_velocity_residual(self, z_v: Array) -> tuple[Array, Array]:
        """The velocity in the vehicle's frame (the body's pitched by the mount)."""
        s = self.state
        r, d_pitch = body_to_vehicle(s.mount_pitch_rad)
        c_nb = s.c_bn.T
        v_b = c_nb @ s.v_ned
        h = np.zeros((3, N_ERR))
        h[:, VEL] = r @ c_nb
        h[:, ATT] = r @ c_nb @ skew(s.v_ned)
        h[:, MNT] = d_pitch @ v_b
        return r @ v_b - z_v, h

    def velocity_residual(self, v_ned: Array) -> tuple[Array, Array]:
        h = np.zeros((3, N_ERR))
        h[:, VEL] = np.eye(3)
        return self.state.v_ned - v_ned, h

    def rest_residual(self, gyro_rps: Array) -> tuple[Array, Array]:
        s = self.state
        h = np.zeros((6, N_ERR))
        h[0:3, VEL] = np.eye(3)
        h[3:6, BG] = np.eye(3)  # the residual rate is the bias error (true - estimate)
        return np.concatenate([s.v_ned, gyro_rps - s.gyro_bias_rps - earth_rate_body(
            s, self._rotating)]), h

    def _correct(self, dx: Array) -> None:
        """Take the updated estimate of the error: fed back at once (feedback) or kept
        (feedforward)."""
        self.dx = dx
        if self.integration == Integration.FEEDBACK:
            self._feed_back()

    def output(self) -> NavState:
        """The navigation solution: the state itself (feedback) or the state less the
        estimated error (feedforward)."""
        if self.integration != Integration.FEEDFORWARD:
            return self.state
        return corrected(self.state, self.dx)

    def _feed_back(self) -> None:
        self.state = corrected(self.state, self.dx)
        self.state.gyro_bias_rps = self.state.gyro_bias_rps + self.dx[BG]
        self.state.accel_bias_mps2 = self.state.accel_bias_mps2 + self.dx[BA]
        self.state.gyro_scale = self.state.gyro_scale + self.dx[SG]
        self.state.accel_scale = self.state.accel_scale + self.dx[SA]
        self.state.mount_pitch_rad = self.state.mount_pitch_rad - self.dx[MNT]
        self.dx = np.zeros(N_ERR)


def earth_rate_body(s: NavState, rotating: float) -> Array:
    """The earth's rotation as the body's gyros see it."""
    return s.c_bn.T @ (rotating * EARTH_RATE_RPS * np.array(
        [math.cos(s.lat_rad), 0.0, -math.sin(s.lat_rad)]))


@jit
def _transition(lat: float, h: float, v: Array, c: Array, f_n: Array, w_b: Array, f_b: Array,
                dt: float, tau: float, gps_tau: float, rotating: float) -> Array:
    """Φ = I + F dt of the ψ-angle error model with Gauss–Markov biases and scale factors
    (``w_b``, ``f_b``: the compensated body rate and specific force; ``tau`` the IMU's,
    ``gps_tau`` the GNSS bias's time constant)."""
    w_ie, w_en = nav_rates(lat, h, v, rotating)
    f = np.zeros((N_ERR, N_ERR))
    f[0:3, 3:6] = np.eye(3)
    f[3:6, 6:9] = -skew(f_n)
    f[3:6, 3:6] = -skew(2.0 * w_ie + w_en)
    f[3:6, 12:15] = c
    f[6:9, 6:9] = -skew(w_ie + w_en)
    f[6:9, 9:12] = c
    f[6:9, 15:18] = c * w_b  # C diag(w): a scale error acts as a bias in proportion
    f[3:6, 18:21] = c * f_b
    for i in range(9, N_KFGINS):
        f[i, i] = -1.0 / tau
    for i in range(N_KFGINS, LAT):  # the GNSS bias
        f[i, i] = -1.0 / gps_tau
    return np.eye(N_ERR) + f * dt


@jit
def _propagate(p: Array, phi: Array, q_dt: Array) -> Array:
    out = phi @ p @ phi.T
    for i in range(N_ERR):
        out[i, i] += q_dt[i]
    return 0.5 * (out + out.T)


def corrected(s: NavState, dx: Array) -> NavState:
    """The navigation state less an estimated error (position, velocity, attitude, GNSS
    bias; the IMU's and the latency are the feedback's)."""
    out = s.copy()
    rm, rn = radii_m(s.lat_rad)
    out.lat_rad = s.lat_rad - dx[0] / (rm + s.h_m)
    out.lon_rad = s.lon_rad - dx[1] / ((rn + s.h_m) * math.cos(s.lat_rad))
    out.h_m = s.h_m + dx[2]
    out.v_ned = s.v_ned - dx[VEL]
    out.c_bn = rotation(-dx[ATT]) @ s.c_bn
    out.gps_bias_ne_m = s.gps_bias_ne_m - dx[GB]
    if not (np.isfinite(out.lat_rad) and np.all(np.isfinite(out.c_bn))):
        raise FloatingPointError("INS correction produced a non-finite state")
    return out


def replay(ins: InsFilter, imu: Array, fixes: list[GnssFix],
           nhc_sigma_mps: float | None = None) -> Array:
    """Run IMU rows ``(t, dtheta xyz, dvel xyz)`` and GNSS fixes through the filter; a fix
    between two IMU samples splits that interval (increments in proportion) so the update
    happens at the fix's time. With ``nhc_sigma_mps`` the non-holonomic constraint is applied
    at 10 Hz while moving faster than 2 m/s. Returns ``(n, 7)`` for each IMU epoch's output:
    t, lat, lon (rad), h (m), roll, pitch, yaw (rad)."""
    out = []
    last_nhc = -math.inf
    k = 0
    while k < len(fixes) and fixes[k].t <= ins.state.t:
        k += 1
    for row in imu:
        t = float(row[0])
        if t <= ins.state.t:
            continue
        dtheta, dvel = row[1:4].copy(), row[4:7].copy()
        while k < len(fixes) and fixes[k].t <= t:
            fix = fixes[k]
            frac = (fix.t - ins.state.t) / (t - ins.state.t)
            if frac > 1e-6:
                ins.predict(fix.t, dtheta * frac, dvel * frac)
                dtheta, dvel = dtheta * (1 - frac), dvel * (1 - frac)
            ins.update(GnssPosition(fix))
            k += 1
        if t - ins.state.t > 1e-9:
            ins.predict(t, dtheta, dvel)
        if nhc_sigma_mps is not None and t - last_nhc >= 0.1 and \
                math.hypot(ins.state.v_ned[0], ins.state.v_ned[1]) > 2.0:
            ins.update(BodyVelocity(np.zeros(3), (1, 2), np.full(3, nhc_sigma_mps)))
            last_nhc = t
        s = ins.output()
        out.append((s.t, s.lat_rad, s.lon_rad, s.h_m, *dcm_to_euler(s.c_bn)))
    return np.array(out)
