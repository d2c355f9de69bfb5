"""The paper's *direct* INS/GNSS integration: an EKF over the navigation state itself (pure).

Giroux, Gourdeau, Landry 2005 (docs/seed-digest.md) compare three integrations. The two indirect
ones (``feedback``, ``feedforward``) estimate the error of the inertial solution, in
:class:`.error_state.InsFilter`. Here the filter's state is the navigation solution (the
paper's set N) and its system model is the equations of motion themselves:

- state (25): latitude, longitude (rad), height (m), NED velocity (m/s), roll, pitch, yaw (rad),
  gyro and accelerometer biases (rad/s, m/s²) and scale factors, the GNSS bias (north, east,
  m) and latency (s), the mount's pitch (rad);
- the mean follows the same mechanisation as the other modes (first order or RK4);
- the covariance follows the Jacobian of the continuous equations of motion (Euler-angle
  kinematics, transport and earth rate, gravity), taken by central differences, so there is
  no separate error model to keep in step with the equations;
- measurements are functions of the state (GNSS antenna position, velocities, a stop); the
  correction is added to the state, angles and all.

What the paper found, and our bench (``bench/ins_eval.py``, ``bench/comma2k19.py``) measures:
the linearisation is taken about the full state rather than about a small error, the
Euler-angle kinematics are singular at ±90° pitch, and the filter works on the full state at IMU
rate, so it costs more.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from navsvc.fusion._jit import Array, jit
from navsvc.fusion.ins.attitude import body_to_vehicle, dcm_to_euler, euler_to_dcm
from navsvc.fusion.ins.earth import EarthModel, nav_rates, normal_gravity_mps2, radii_m
from navsvc.fusion.ins.error_state import (
    LAT,
    MNT,
    N_ERR,
    N_KFGINS,
    POS,
    GnssFix,
    ImuNoise,
    InsFilter,
    Integration,
    earth_rate_body,
)
from navsvc.fusion.ins.mechanisation import Mechanisation, NavState, mechanise

# central-difference steps per state: about 0.1 m, 1 mm/s, 2 arc-seconds, tiny biases, 1 cm,
# 1 ms, 2 arc-seconds
STEP = np.array([1.5e-8, 1.5e-8, 0.1, 1e-3, 1e-3, 1e-3, 1e-5, 1e-5, 1e-5,
                 1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4, 1e-5, 1e-5, 1e-5, 1e-5, 1e-5, 1e-5,
                 1e-2, 1e-2, 1e-3, 1e-5])
MAX_PITCH_RAD = math.radians(85.0)  # Euler kinematics are singular at ±90°
MAX_COVARIANCE_STEP_S = 0.02
MAX_ANGLE_SIGMA_RAD = math.pi


@jit
def _state_derivative(x: Array, w_ib: Array, f_b: Array, tau: float, gps_tau: float,
                      rotating: float) -> Array:
    """dx/dt of the navigation state under measured body rate and specific force."""
    lat, h, v = x[0], x[2], x[3:6]
    rm, rn = radii_m(lat)
    c = euler_to_dcm(x[6], x[7], x[8])
    w_ie, w_en = nav_rates(lat, h, v, rotating)
    out = np.empty(N_ERR)
    out[0] = v[0] / (rm + h)
    out[1] = v[1] / ((rn + h) * math.cos(lat))
    out[2] = -v[2]
    g = np.array([0.0, 0.0, normal_gravity_mps2(lat, h)])
    out[3:6] = c @ ((f_b - x[12:15]) / (1.0 + x[18:21])) + g - np.cross(2.0 * w_ie + w_en, v)
    # body rate relative to the NED frame
    w = (w_ib - x[9:12]) / (1.0 + x[15:18]) - c.T @ (w_ie + w_en)
    sr, cr = math.sin(x[6]), math.cos(x[6])
    pitch = min(max(x[7], -MAX_PITCH_RAD), MAX_PITCH_RAD)  # kept off the singularity
    out[6] = w[0] + (w[1] * sr + w[2] * cr) * math.tan(pitch)
    out[7] = w[1] * cr - w[2] * sr
    out[8] = (w[1] * sr + w[2] * cr) / math.cos(pitch)
    out[9:N_KFGINS] = -x[9:N_KFGINS] / tau
    out[N_KFGINS:LAT] = -x[N_KFGINS:LAT] / gps_tau
    out[LAT:] = 0.0  # the latency and the mount: constants
    return out


@jit
def _propagate_direct(p: Array, x: Array, w_ib: Array, f_b: Array, dt: float, tau: float,
                      gps_tau: float, rotating: float, q_density: Array) -> Array:
    """P through one step: Φ = I + F dt with F = ∂f/∂x by central differences; the sensor
    noise enters through ∂f/∂(rate, force), which is −∂f/∂(biases) as biases subtract
    (``q_density`` in the error state's layout: the angle and velocity random walks where
    the attitude and velocity errors are). A long
    step (a gap in the IMU data) is taken as sub-steps of ``MAX_COVARIANCE_STEP_S``, as
    Φ = I + F dt only holds while F dt is small. Angle variances are capped: near ±90° pitch
    the Euler kinematics would otherwise grow them without bound."""
    f_mat = np.empty((N_ERR, N_ERR))
    for i in range(N_ERR):
        xp, xm = x.copy(), x.copy()
        xp[i] += STEP[i]
        xm[i] -= STEP[i]
        f_mat[:, i] = (_state_derivative(xp, w_ib, f_b, tau, gps_tau, rotating)
                       - _state_derivative(xm, w_ib, f_b, tau, gps_tau, rotating)
                       ) / (2.0 * STEP[i])
    g = -f_mat[:, 9:15]
    steps = max(1, math.ceil(dt / MAX_COVARIANCE_STEP_S))
    h = dt / steps
    phi = np.eye(N_ERR) + f_mat * h
    rate_force = np.concatenate((q_density[6:9], q_density[3:6]))
    q = (g * rate_force) @ g.T * h
    for i in range(9, N_ERR):
        q[i, i] += q_density[i] * h
    out = p
    for _ in range(steps):
        out = phi @ out @ phi.T + q
        for i in range(6, 9):  # an angle is never more uncertain than a half turn
            if out[i, i] > MAX_ANGLE_SIGMA_RAD**2:
                scale = MAX_ANGLE_SIGMA_RAD / math.sqrt(out[i, i])
                out[i, :] *= scale  # D P D with D diagonal keeps P positive definite
                out[:, i] *= scale
    return 0.5 * (out + out.T)


def total_state(s: NavState) -> Array:
    roll, pitch, yaw = dcm_to_euler(s.c_bn)
    return np.concatenate([[s.lat_rad, s.lon_rad, s.h_m], s.v_ned, [roll, pitch, yaw],
                           s.gyro_bias_rps, s.accel_bias_mps2, s.gyro_scale, s.accel_scale,
                           s.gps_bias_ne_m, [s.gps_latency_s, s.mount_pitch_rad]])


def nav_state(t: float, x: Array) -> NavState:
    return NavState(t, float(x[0]), float(x[1]), float(x[2]), x[3:6].copy(),
                    euler_to_dcm(x[6], x[7], x[8]), x[9:12].copy(), x[12:15].copy(),
                    x[15:18].copy(), x[18:21].copy(), x[21:23].copy(), float(x[LAT]),
                    float(x[MNT]))


def _metres_per_unit(s: NavState) -> Array:
    """North, east, down metres per unit of latitude, longitude (rad) and height (m)."""
    rm, rn = radii_m(s.lat_rad)
    return np.array([rm + s.h_m, (rn + s.h_m) * math.cos(s.lat_rad), -1.0])


class DirectInsFilter(InsFilter):
    """The ``direct`` integration: the EKF estimates the navigation state (see the module)."""

    def __init__(self, state: NavState, p0: Array, noise: ImuNoise,
                 lever_arm_b_m: Array | None = None,
                 mechanisation: Mechanisation = Mechanisation.FIRST_ORDER,
                 earth: EarthModel = EarthModel.WGS84, gps_bias_sigma_m: float = 0.0,
                 gps_bias_tau_s: float = 30.0, gps_latency_sigma_s: float = 0.0,
                 mount_sigma_rad: float = 0.0) -> None:
        """``p0`` as for the other modes (position in NED metres, attitude per axis); it is
        carried into the state's units."""
        super().__init__(state, p0, noise, lever_arm_b_m, Integration.DIRECT, mechanisation,
                         earth, gps_bias_sigma_m, gps_bias_tau_s, gps_latency_sigma_s,
                         mount_sigma_rad)
        scale = np.ones(N_ERR)
        scale[POS] = 1.0 / _metres_per_unit(state)
        self.P = self.P * np.outer(scale, scale)

    def predict(self, t: float, dtheta: Array, dvel: Array) -> None:
        """One IMU interval: the equations of motion carry the state, their Jacobian the
        covariance. Refused as ``InsFilter.predict`` refuses."""
        self._check_sample(t, dtheta, dvel)
        before = self.state
        dt = t - before.t
        self.P = _propagate_direct(self.P, total_state(before), dtheta / dt, dvel / dt, dt,
                                   self.noise.bias_corr_time_s, self.gps_bias_tau_s,
                                   self._rotating, self._q_density)
        self.state, _ = mechanise(before, t, *before.compensate(dtheta, dvel, dt),
                                  self.mechanisation, self.earth)
        decay = 1.0 - dt / self.noise.bias_corr_time_s
        self.state.gyro_bias_rps = before.gyro_bias_rps * decay
        self.state.accel_bias_mps2 = before.accel_bias_mps2 * decay
        self.state.gyro_scale = before.gyro_scale * decay
        self.state.accel_scale = before.accel_scale * decay

    def position_cov_ned_m2(self) -> Array:
        m = _metres_per_unit(self.state)
        return self.P[POS, POS] * np.outer(m, m)

    def _correct(self, dx: Array) -> None:
        """The estimated error comes off the state itself (``dx`` stays zero)."""
        x = total_state(self.state) - dx
        if not np.all(np.isfinite(x)):
            raise FloatingPointError("INS correction produced a non-finite state")
        x[7] = float(np.clip(x[7], -MAX_PITCH_RAD, MAX_PITCH_RAD))
        self.state = nav_state(self.state.t, x)

    def _numeric(self, residual: Callable[[Array], Array]) -> tuple[Array, Array]:
        """A residual at the state and its Jacobian by central differences."""
        x = total_state(self.state)
        y = residual(x)
        h = np.empty((len(y), N_ERR))
        for i in range(N_ERR):
            step = np.zeros(N_ERR)
            step[i] = STEP[i]
            h[:, i] = (residual(x + step) - residual(x - step)) / (2.0 * STEP[i])
        return y, h

    def position_residual(self, fix: GnssFix) -> tuple[Array, Array]:
        # in metres north, east, down at the fix, so that it compares with the fix's sigmas
        m = _metres_per_unit(NavState(fix.t, fix.lat_rad, fix.lon_rad, fix.h_m,
                                      np.zeros(3), np.eye(3)))
        z = np.array([fix.lat_rad, fix.lon_rad, fix.h_m])

        def antenna_minus_fix(x: Array) -> Array:
            lever_n = euler_to_dcm(x[6], x[7], x[8]) @ self.lever_arm_b_m
            rm, rn = radii_m(x[0])
            antenna = x[0:3] + np.array([lever_n[0] / (rm + x[2]),
                                         lever_n[1] / ((rn + x[2]) * math.cos(x[0])),
                                         -lever_n[2]])
            metres: Array = (antenna - z) * m
            return metres

        return self._numeric(antenna_minus_fix)

    def body_velocity_residual(self, z_v: Array) -> tuple[Array, Array]:
        return self._numeric(lambda x: body_to_vehicle(x[MNT])[0]
                             @ euler_to_dcm(x[6], x[7], x[8]).T @ x[3:6] - z_v)

    def velocity_residual(self, v_ned: Array) -> tuple[Array, Array]:
        return self._numeric(lambda x: x[3:6] - v_ned)

    def rest_residual(self, gyro_rps: Array) -> tuple[Array, Array]:
        def still(x: Array) -> Array:
            rate = earth_rate_body(nav_state(self.state.t, x), self._rotating)
            return np.concatenate([x[3:6], gyro_rps - x[9:12] - rate])

        return self._numeric(still)


def ins_filter(state: NavState, p0: Array, noise: ImuNoise, lever_arm_b_m: Array | None = None,
               integration: Integration = Integration.FEEDBACK,
               mechanisation: Mechanisation = Mechanisation.FIRST_ORDER,
               earth: EarthModel = EarthModel.WGS84, gps_bias_sigma_m: float = 0.0,
               gps_bias_tau_s: float = 30.0, gps_latency_sigma_s: float = 0.0,
               mount_sigma_rad: float = 0.0) -> InsFilter:
    """The filter of an integration: ``DirectInsFilter`` for ``direct``, else ``InsFilter``.
    ``p0`` is in the error-state units of ``InsFilter`` (position in NED metres)."""
    beyond_kfgins = (gps_bias_sigma_m, gps_bias_tau_s, gps_latency_sigma_s, mount_sigma_rad)
    if integration == Integration.DIRECT:
        return DirectInsFilter(state, p0, noise, lever_arm_b_m, mechanisation, earth,
                               *beyond_kfgins)
    return InsFilter(state, p0, noise, lever_arm_b_m, integration, mechanisation, earth,
                     *beyond_kfgins)
