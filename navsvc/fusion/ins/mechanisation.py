"""Strapdown mechanisation (pure): the navigation state and its advance over one IMU interval.

Seed: Giroux, Gourdeau, Landry 2005 (docs/seed-digest.md); conventions as KF-GINS: position as
geodetic latitude/longitude (rad) and ellipsoidal height (m), NED velocity, attitude ``C_bn``,
IMU input as angle and velocity increments. ``first_order`` (rotation-vector attitude update,
mid-point position) or the paper's ``rk4`` on the continuous equations with the rates held over
the step; earth rate, transport rate and normal gravity from :mod:`.earth`.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

import numpy as np

from navsvc.fusion._jit import Array, jit
from navsvc.fusion.ins.attitude import rotation, skew
from navsvc.fusion.ins.earth import EarthModel, nav_rates, normal_gravity_mps2, radii_m

MAX_RATE_RPS = math.radians(2000.0)  # consumer gyros saturate about here
MAX_ACCEL_MPS2 = 16.0 * 9.80665


class Mechanisation(enum.Enum):
    FIRST_ORDER = "first_order"
    RK4 = "rk4"


@dataclass
class NavState:
    """Position (lat, lon rad; h m), NED velocity (m/s), attitude C_bn, and the estimates of
    the IMU's biases and scale factors; the GNSS receiver's bias (north, east m) and
    latency (s: a fix is where the antenna was this long before its time stamp), which the
    filter considers but does not estimate (they stay at their priors); and the mount's
    pitch (rad: the vehicle's axes pitched this much from the IMU's body axes)."""

    t: float
    lat_rad: float
    lon_rad: float
    h_m: float
    v_ned: Array
    c_bn: Array
    gyro_bias_rps: Array = field(default_factory=lambda: np.zeros(3))
    accel_bias_mps2: Array = field(default_factory=lambda: np.zeros(3))
    gyro_scale: Array = field(default_factory=lambda: np.zeros(3))
    accel_scale: Array = field(default_factory=lambda: np.zeros(3))
    gps_bias_ne_m: Array = field(default_factory=lambda: np.zeros(2))
    gps_latency_s: float = 0.0
    mount_pitch_rad: float = 0.0

    def copy(self) -> NavState:
        return NavState(self.t, self.lat_rad, self.lon_rad, self.h_m, self.v_ned.copy(),
                        self.c_bn.copy(), self.gyro_bias_rps.copy(),
                        self.accel_bias_mps2.copy(), self.gyro_scale.copy(),
                        self.accel_scale.copy(), self.gps_bias_ne_m.copy(),
                        self.gps_latency_s, self.mount_pitch_rad)

    def compensate(self, dtheta: Array, dvel: Array, dt: float) -> tuple[Array, Array]:
        """IMU increments less the estimated bias and scale errors."""
        return _compensate(dtheta, dvel, dt, self.gyro_bias_rps, self.accel_bias_mps2,
                           self.gyro_scale, self.accel_scale)


@jit
def _compensate(dtheta: Array, dvel: Array, dt: float, bg: Array, ba: Array, sg: Array,
                sa: Array) -> tuple[Array, Array]:
    return (dtheta - bg * dt) / (1.0 + sg), (dvel - ba * dt) / (1.0 + sa)


@jit
def sample_problem(dtheta: Array, dvel: Array, dt: float) -> str:
    """Why an IMU sample cannot be used ("" when it can)."""
    for i in range(3):
        if not (math.isfinite(dtheta[i]) and math.isfinite(dvel[i])):
            return "is not finite"
    for i in range(3):
        if abs(dtheta[i]) > MAX_RATE_RPS * dt or abs(dvel[i]) > MAX_ACCEL_MPS2 * dt:
            return "is saturated"
    return ""


@jit
def _derivatives(lat: float, h: float, v: Array, c: Array, w_ib: Array, f_b: Array,
                 rotating: float) -> tuple[Array, Array, Array]:
    """d(lat, lon, h)/dt, dv/dt, dC/dt of the continuous strapdown equations."""
    rm, rn = radii_m(lat)
    w_ie, w_en = nav_rates(lat, h, v, rotating)
    g = np.array([0.0, 0.0, normal_gravity_mps2(lat, h)])
    dpos = np.array([v[0] / (rm + h), v[1] / ((rn + h) * math.cos(lat)), -v[2]])
    dv = c @ f_b + g - np.cross(2.0 * w_ie + w_en, v)
    dc = c @ skew(w_ib) - skew(w_ie + w_en) @ c
    return dpos, dv, dc


def mechanise(s: NavState, t: float, dtheta: Array, dvel: Array,
              method: Mechanisation = Mechanisation.FIRST_ORDER,
              earth: EarthModel = EarthModel.WGS84) -> tuple[NavState, Array]:
    """Advance the navigation state by one IMU interval; return it and the specific force in
    the navigation frame (for the error model). The increments are compensated already
    (:meth:`NavState.compensate`)."""
    rotating = 1.0 if earth == EarthModel.WGS84 else 0.0
    dt = t - s.t
    out = s.copy()
    out.t = t
    if method == Mechanisation.RK4:
        return _rk4(s, out, dt, dtheta, dvel, rotating)
    out.lat_rad, out.lon_rad, out.h_m, out.v_ned, out.c_bn, f_n = _first_order(
        s.lat_rad, s.lon_rad, s.h_m, s.v_ned, s.c_bn, dtheta, dvel, dt, rotating)
    return out, f_n


@jit
def _first_order(lat: float, lon: float, h: float, v: Array, c: Array, dtheta: Array,
                 dvel: Array, dt: float,
                 rotating: float) -> tuple[float, float, float, Array, Array, Array]:
    w_ie, w_en = nav_rates(lat, h, v, rotating)
    dv_b = dvel + 0.5 * np.cross(dtheta, dvel)  # rotation compensation
    dv_n = c @ dv_b
    g = np.array([0.0, 0.0, normal_gravity_mps2(lat, h)])
    v_new = v + dv_n + (g - np.cross(2.0 * w_ie + w_en, v)) * dt
    v_mid = 0.5 * (v + v_new)
    rm, rn = radii_m(lat)
    h_new = h - v_mid[2] * dt
    h_mid = 0.5 * (h + h_new)
    lat_new = lat + v_mid[0] / (rm + h_mid) * dt
    lon_new = lon + v_mid[1] / ((rn + h_mid) * math.cos(0.5 * (lat + lat_new))) * dt
    c_new = rotation(-(w_ie + w_en) * dt) @ c @ rotation(dtheta)
    return lat_new, lon_new, h_new, v_new, c_new, dv_n / dt


def _rk4(s: NavState, out: NavState, dt: float, dtheta: Array, dvel: Array,
         rotating: float) -> tuple[NavState, Array]:
    pos, out.v_ned, out.c_bn = _rk4_kernel(np.array([s.lat_rad, s.lon_rad, s.h_m]), s.v_ned,
                                           s.c_bn, dtheta / dt, dvel / dt, dt, rotating)
    out.lat_rad, out.lon_rad, out.h_m = float(pos[0]), float(pos[1]), float(pos[2])
    return out, s.c_bn @ (dvel / dt)


@jit
def _rk4_kernel(pos: Array, v: Array, c: Array, w_ib: Array, f_b: Array, dt: float,
                rotating: float) -> tuple[Array, Array, Array]:
    """The paper's 4th-order Runge–Kutta step, the body rates held over the interval."""
    p1, v1, c1 = _derivatives(pos[0], pos[2], v, c, w_ib, f_b, rotating)
    p2, v2, c2 = _derivatives(pos[0] + dt / 2 * p1[0], pos[2] + dt / 2 * p1[2],
                              v + dt / 2 * v1, c + dt / 2 * c1, w_ib, f_b, rotating)
    p3, v3, c3 = _derivatives(pos[0] + dt / 2 * p2[0], pos[2] + dt / 2 * p2[2],
                              v + dt / 2 * v2, c + dt / 2 * c2, w_ib, f_b, rotating)
    p4, v4, c4 = _derivatives(pos[0] + dt * p3[0], pos[2] + dt * p3[2],
                              v + dt * v3, c + dt * c3, w_ib, f_b, rotating)
    pos_new = pos + dt / 6.0 * (p1 + 2.0 * p2 + 2.0 * p3 + p4)
    v_new = v + dt / 6.0 * (v1 + 2.0 * v2 + 2.0 * v3 + v4)
    c_new = c + dt / 6.0 * (c1 + 2.0 * c2 + 2.0 * c3 + c4)
    u, _, vt = np.linalg.svd(c_new)  # back to a rotation matrix
    return pos_new, v_new, u @ vt


