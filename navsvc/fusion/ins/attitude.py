"""Attitude of the strapdown INS (pure): skew matrices, rotation vectors, direction-cosine
matrices ``C_bn`` (body forward-right-down to north-east-down) and Euler angles, coarse
levelling, the mount pitch between the IMU's axes and the vehicle's. Conventions as KF-GINS
(Giroux, Gourdeau, Landry 2005; docs/seed-digest.md).
"""

from __future__ import annotations

import math

import numpy as np

from navsvc.fusion._jit import Array, jit


@jit
def skew(v: Array) -> Array:
    m = np.zeros((3, 3))
    m[0, 1], m[0, 2], m[1, 0] = -v[2], v[1], v[2]
    m[1, 2], m[2, 0], m[2, 1] = -v[0], -v[1], v[0]
    return m


@jit
def rotation(rotvec: Array) -> Array:
    """The rotation matrix of a rotation vector (Rodrigues)."""
    angle = float(np.linalg.norm(rotvec))
    k = skew(rotvec)
    if angle < 1e-9:
        return np.eye(3) + k + 0.5 * k @ k
    return np.eye(3) + math.sin(angle) / angle * k + (1.0 - math.cos(angle)) / angle**2 * k @ k


@jit
def euler_to_dcm(roll_rad: float, pitch_rad: float, yaw_rad: float) -> Array:
    """C_bn from roll, pitch, yaw (Z-Y-X rotation sequence)."""
    cr, sr, cp, sp = math.cos(roll_rad), math.sin(roll_rad), math.cos(pitch_rad), \
        math.sin(pitch_rad)
    cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
    c = np.empty((3, 3))
    c[0, 0], c[0, 1], c[0, 2] = cp * cy, -cr * sy + sr * sp * cy, sr * sy + cr * sp * cy
    c[1, 0], c[1, 1], c[1, 2] = cp * sy, cr * cy + sr * sp * sy, -sr * cy + cr * sp * sy
    c[2, 0], c[2, 1], c[2, 2] = -sp, sr * cp, cr * cp
    return c


@jit
def dcm_to_euler(c: Array) -> tuple[float, float, float]:
    """(roll, pitch, yaw) of C_bn; yaw in [0, 2π)."""
    pitch = math.atan2(-c[2, 0], math.hypot(c[2, 1], c[2, 2]))
    return math.atan2(c[2, 1], c[2, 2]), pitch, math.atan2(c[1, 0], c[0, 0]) % (2 * math.pi)


def level_from_accel(mean_f_b: Array) -> tuple[float, float]:
    """Roll and pitch from the mean specific force of a static interval (coarse levelling)."""
    fx, fy, fz = mean_f_b
    return math.atan2(-fy, -fz), math.atan2(fx, math.hypot(fy, fz))


def body_to_vehicle(mount_pitch_rad: float) -> tuple[Array, Array]:
    """The rotation from the IMU's body frame to the vehicle's (forward along its wheels'
    track, right, down) when the vehicle's axes are pitched ``mount_pitch_rad`` from the
    body's, and its derivative by that pitch."""
    c, s = math.cos(mount_pitch_rad), math.sin(mount_pitch_rad)
    return (np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]]),
            np.array([[-s, 0.0, -c], [0.0, 0.0, 0.0], [c, 0.0, -s]]))
