"""Readers for KF-GINS's text formats, so its users can bring their data (I/O).

- IMU file: 7 whitespace-separated columns per line: GPS seconds of week, angle increments
  x, y, z (rad), velocity increments x, y, z (m/s), body frame forward-right-down.
- GNSS file: 7 columns: GPS seconds of week, latitude, longitude (degrees), ellipsoidal height
  (m), standard deviations north, east, up (m).
- Navigation result (``.nav``): 11 columns: week, seconds of week, lat, lon (deg), height (m),
  velocity north, east, down (m/s), roll, pitch, yaw (deg).
- Configuration (YAML): initial state, its standard deviations, IMU noise, lever arm.

Files may be gzipped (``.gz``). Bad lines raise :class:`TraceError` naming the file and line.
"""

from __future__ import annotations

import gzip
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from navsvc.errors import TraceError
from navsvc.fusion.ins import (
    Array,
    EarthModel,
    GnssFix,
    ImuNoise,
    InsFilter,
    Integration,
    Mechanisation,
    NavState,
    euler_to_dcm,
    ins_filter,
)


def _read(path: Path, columns: int, what: str) -> Array:
    rows = []
    try:
        raw = gzip.decompress(path.read_bytes()) if path.suffix == ".gz" else path.read_bytes()
        lines = raw.decode().splitlines()
    except (OSError, EOFError, UnicodeDecodeError) as exc:
        raise TraceError(f"{path}: cannot read: {getattr(exc, 'strerror', None) or exc}") \
            from exc
    for number, line in enumerate(lines, start=1):
        parts = line.split()
        if not parts or parts[0].startswith("#"):
            continue
        if len(parts) < columns:
            raise TraceError(f"{path}:{number}: expected {columns} columns of a KF-GINS {what} "
                             f"file, found {len(parts)}")
        try:
            values = [float(p) for p in parts[:columns]]
        except ValueError:
            raise TraceError(f"{path}:{number}: not a number in {line.strip()!r}") from None
        if not all(math.isfinite(v) for v in values):
            raise TraceError(f"{path}:{number}: NaN or infinite value")
        rows.append(values)
    if not rows:
        raise TraceError(f"{path}: no {what} records")
    data = np.array(rows)
    backwards = np.flatnonzero(np.diff(data[:, 1 if what == "navigation" else 0]) <= 0.0)
    if backwards.size:
        raise TraceError(f"{path}: time does not increase at record {int(backwards[0]) + 2}")
    return data


def read_imu(path: Path) -> Array:
    """``(n, 7)``: t, dtheta x y z (rad), dvel x y z (m/s)."""
    return _read(path, 7, "IMU")


def read_gnss(path: Path) -> Array:
    """``(n, 7)``: t, lat, lon (deg), h (m), sigma north, east, up (m)."""
    data = _read(path, 7, "GNSS")
    bad = np.flatnonzero(~(data[:, 4:7] > 0.0).all(axis=1))
    if bad.size:
        raise TraceError(f"{path}: record {int(bad[0]) + 1}: standard deviations must be > 0")
    return data


def read_nav(path: Path) -> Array:
    """``(n, 11)``: week, t, lat, lon (deg), h (m), v north east down, roll pitch yaw (deg)."""
    return _read(path, 11, "navigation")


@dataclass(frozen=True)
class KfGinsProfile:
    """The parts of a KF-GINS YAML configuration our filter uses (its units)."""

    start_t: float
    init_pos: tuple[float, float, float]  # lat, lon (deg), h (m)
    init_vel: tuple[float, float, float]  # north, east, down (m/s)
    init_att_deg: tuple[float, float, float]  # roll, pitch, yaw
    init_gyro_bias_deg_h: tuple[float, float, float]
    init_accel_bias_mgal: tuple[float, float, float]
    init_gyro_scale_ppm: tuple[float, float, float]
    init_accel_scale_ppm: tuple[float, float, float]
    pos_std_m: tuple[float, float, float]
    vel_std_mps: tuple[float, float, float]
    att_std_deg: tuple[float, float, float]
    gyro_bias_std_deg_h: tuple[float, float, float]
    accel_bias_std_mgal: tuple[float, float, float]
    gyro_scale_std_ppm: tuple[float, float, float]
    accel_scale_std_ppm: tuple[float, float, float]
    noise: ImuNoise
    lever_arm_m: tuple[float, float, float]

    def filter(self, integration: Integration = Integration.FEEDBACK,
               mechanisation: Mechanisation = Mechanisation.FIRST_ORDER,
               earth: EarthModel = EarthModel.WGS84) -> InsFilter:
        """An InsFilter started as KF-GINS starts with this profile."""
        lat, lon, h = self.init_pos
        state = NavState(self.start_t, math.radians(lat), math.radians(lon), h,
                         np.array(self.init_vel), euler_to_dcm(*np.radians(self.init_att_deg)),
                         np.radians(self.init_gyro_bias_deg_h) / 3600.0,
                         np.array(self.init_accel_bias_mgal) * 1e-5,
                         np.array(self.init_gyro_scale_ppm) * 1e-6,
                         np.array(self.init_accel_scale_ppm) * 1e-6)
        sigmas = np.concatenate([self.pos_std_m, self.vel_std_mps,
                                 np.radians(self.att_std_deg),
                                 np.radians(self.gyro_bias_std_deg_h) / 3600.0,
                                 np.array(self.accel_bias_std_mgal) * 1e-5,
                                 np.array(self.gyro_scale_std_ppm) * 1e-6,
                                 np.array(self.accel_scale_std_ppm) * 1e-6])
        return ins_filter(state, np.diag(sigmas**2), self.noise, np.array(self.lever_arm_m),
                         integration, mechanisation, earth)


def read_profile(path: Path) -> KfGinsProfile:
    """A KF-GINS configuration file (its flat YAML: ``key: value``, ``key: [a, b, c]``, and the
    ``imunoise:`` block)."""
    values: dict[str, Any] = {}
    try:
        lines = path.read_text().splitlines()
    except OSError as exc:
        raise TraceError(f"{path}: cannot read: {exc.strerror}") from exc
    for number, line in enumerate(lines, start=1):
        text = line.split("#", 1)[0].rstrip()
        if not text.strip() or text.strip().endswith(":"):
            continue
        key, sep, value = text.strip().partition(":")
        if not sep:
            raise TraceError(f"{path}:{number}: expected 'key: value'")
        value = value.strip().strip('"')
        try:
            values[key] = [float(v) for v in value.strip("[]").split(",")] \
                if value.startswith("[") else value
        except ValueError:
            raise TraceError(f"{path}:{number}: {key}: not a list of numbers") from None
    try:
        noise = ImuNoise.from_kfgins(values["arw"][0], values["vrw"][0], values["gbstd"][0],
                                     values["abstd"][0], float(values["corrtime"]),
                                     values["gsstd"][0], values["asstd"][0])
        return KfGinsProfile(
            start_t=float(values["starttime"]), init_pos=_xyz(values["initpos"]),
            init_vel=_xyz(values["initvel"]), init_att_deg=_xyz(values["initatt"]),
            init_gyro_bias_deg_h=_xyz(values["initgyrbias"]),
            init_accel_bias_mgal=_xyz(values["initaccbias"]),
            pos_std_m=_xyz(values["initposstd"]), vel_std_mps=_xyz(values["initvelstd"]),
            att_std_deg=_xyz(values["initattstd"]),
            gyro_bias_std_deg_h=_xyz(values["initbgstd"]),
            accel_bias_std_mgal=_xyz(values["initbastd"]),
            init_gyro_scale_ppm=_xyz(values["initgyrscale"]),
            init_accel_scale_ppm=_xyz(values["initaccscale"]),
            gyro_scale_std_ppm=_xyz(values["initsgstd"]),
            accel_scale_std_ppm=_xyz(values["initsastd"]), noise=noise,
            lever_arm_m=_xyz(values.get("antlever", [0.0, 0.0, 0.0])))
    except KeyError as exc:
        raise TraceError(f"{path}: missing setting {exc.args[0]!r}") from None
    except (TypeError, ValueError, IndexError) as exc:
        raise TraceError(f"{path}: bad setting: {exc}") from None


def _xyz(values: Any) -> tuple[float, float, float]:
    if not isinstance(values, list) or len(values) != 3:
        raise ValueError(f"expected three numbers, got {values!r}")
    return float(values[0]), float(values[1]), float(values[2])


def gnss_fixes(rows: Array) -> list[GnssFix]:
    """GNSS rows of :func:`read_gnss` as filter fixes (radians; sigmas north, east, down)."""
    return [GnssFix(float(r[0]), math.radians(r[1]), math.radians(r[2]), float(r[3]),
                    np.array([r[4], r[5], r[6]])) for r in rows]
