"""The comma2k19 example segment (real car, 60 s) as our wire records, with its truth.

Sensors: the phone gyro (104 Hz, forward/right/down: our yaw rate, z up, is minus the down
axis) and, when present, its accelerometer (both then also as the 6-axis fields), CAN vehicle
speed (89 Hz, odometer ``speed_mps``), CAN steering-wheel angle (89 Hz, positive left; the
front-wheel angle is it over the steering ratio) and the u-blox fix (10 Hz). Truth is
``global_pose`` (20 Hz, ECEF). All of them carry the device boot time, so they align without
the UTC conversion; ``t`` is seconds since the first record.

The vehicle constants are openpilot's for the Toyota RAV4 (steering ratio 16.88, wheelbase
2.65 m).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pyproj import Transformer

from navsvc.errors import TraceError

STEERING_RATIO = 16.88
WHEELBASE_M = 2.65


@dataclass(frozen=True)
class Gnss:
    """How much of the u-blox stream to keep."""

    rate_hz: float = 10.0  # 10 (all) or lower (thinned)
    outage: tuple[float, float] | None = None  # (start_s, length_s) without fixes


def _load(folder: Path, name: str) -> np.ndarray:
    path = folder / name
    try:
        return np.asarray(np.load(path, allow_pickle=False))
    except (OSError, ValueError) as exc:
        raise TraceError(f"{path}: cannot read a NumPy array ({exc})") from None


def _truth(folder: Path, t0: float) -> list[dict[str, Any]]:
    times = _load(folder, "global_pose/frame_times")
    ecef = _load(folder, "global_pose/frame_positions")
    vel = _load(folder, "global_pose/frame_velocities")
    to_geo = Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
    lon, lat, _ = to_geo.transform(ecef[:, 0], ecef[:, 1], ecef[:, 2])
    out = []
    for i, t in enumerate(times):
        la, lo = math.radians(lat[i]), math.radians(lon[i])
        east = -math.sin(lo) * vel[i, 0] + math.cos(lo) * vel[i, 1]
        north = (-math.sin(la) * math.cos(lo) * vel[i, 0] - math.sin(la) * math.sin(lo)
                 * vel[i, 1] + math.cos(la) * vel[i, 2])
        out.append({"t": round(float(t - t0), 4), "kind": "truth", "lat": float(lat[i]),
                    "lon": float(lon[i]),
                    "heading_deg": math.degrees(math.atan2(east, north)) % 360.0,
                    "speed_mps": math.hypot(east, north), "osm_way_id": None, "u": 0, "v": 0})
    return out


def _gnss(folder: Path, t0: float, gnss: Gnss) -> list[dict[str, Any]]:
    times = _load(folder, "processed_log/GNSS/live_gnss_ublox/t")
    values = _load(folder, "processed_log/GNSS/live_gnss_ublox/value")
    out, next_t = [], -math.inf
    for t, (lat, lon, speed, _utc_ms, alt, bearing) in zip(times - t0, values):
        if t < next_t - 1e-3:
            continue
        if gnss.outage and gnss.outage[0] <= t < gnss.outage[0] + gnss.outage[1]:
            continue
        next_t = t + 1.0 / gnss.rate_hz
        out.append({"t": round(float(t), 4), "kind": "gps", "lat": float(lat),
                    "lon": float(lon), "alt_m": float(alt), "speed_mps": float(speed),
                    "heading_deg": float(bearing) % 360.0, "fix": "3d"})
    return out


def _add_full_imu(folder: Path, gyro_t: np.ndarray, gyro: np.ndarray,
                  imu: list[dict[str, Any]]) -> None:
    """The 6-axis fields (``strapdown``): the phone's forward-right-down axes turned to the
    wire's forward-left-up, the accelerometer interpolated to the gyro's times."""
    acc_t = _load(folder, "processed_log/IMU/accelerometer/t")
    acc = _load(folder, "processed_log/IMU/accelerometer/value")
    acc_at = np.column_stack([np.interp(gyro_t, acc_t, acc[:, k]) for k in range(3)])
    for record, g, a in zip(imu, np.degrees(gyro), acc_at):
        record["gyro_dps"] = [float(g[0]), -float(g[1]), -float(g[2])]
        record["accel_mps2"] = [float(a[0]), -float(a[1]), -float(a[2])]


def read_segment(folder: Path, gnss: Gnss = Gnss()) -> list[dict[str, Any]]:
    """Wire records (truth, gps, imu, odometer, steering) in time order."""
    gyro_t = _load(folder, "processed_log/IMU/gyro/t")
    t0 = float(min(gyro_t[0], _load(folder, "global_pose/frame_times")[0]))
    gyro = _load(folder, "processed_log/IMU/gyro/value")
    records = _truth(folder, t0) + _gnss(folder, t0, gnss)
    imu = [{"t": round(float(t - t0), 4), "kind": "imu",
            "yaw_rate_dps": -math.degrees(float(g[2]))} for t, g in zip(gyro_t, gyro)]
    if (folder / "processed_log/IMU/accelerometer").is_dir():
        _add_full_imu(folder, gyro_t, gyro, imu)
    records += imu
    speed_t = _load(folder, "processed_log/CAN/speed/t")
    speed = _load(folder, "processed_log/CAN/speed/value").ravel()
    records += [{"t": round(float(t - t0), 4), "kind": "odometer",
                 "speed_mps": max(float(v), 0.0)} for t, v in zip(speed_t, speed)]
    steer_t = _load(folder, "processed_log/CAN/steering_angle/t")
    steer = _load(folder, "processed_log/CAN/steering_angle/value").ravel()
    records += [{"t": round(float(t - t0), 4), "kind": "steering",
                 "angle_deg": float(a) / STEERING_RATIO} for t, a in zip(steer_t, steer)]
    order = {"truth": 0, "gps": 1, "imu": 2, "odometer": 3, "steering": 4}
    records.sort(key=lambda r: (r["t"], order[r["kind"]]))
    return [r for r in records if r["t"] >= 0.0]
