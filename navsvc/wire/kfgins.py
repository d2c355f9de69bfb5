"""Readers for KF-GINS's text formats, so its users can bring their data (I/O).

- IMU file: 7 whitespace-separated columns per line: GPS seconds of week, angle increments
  x, y, z (rad), velocity increments x, y, z (m/s), body frame forward-right-down.
- GNSS file: 7 columns: GPS seconds of week, latitude, longitude (degrees), ellipsoidal height
  (m), standard deviations north, east, up (m).
- Navigation result (``.nav``): 11 columns: week, seconds of week, lat, lon (deg), height (m),
  velocity north, east, down (m/s), roll, pitch, yaw (deg).

Bad lines raise :class:`TraceError` naming the file and line.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import numpy.typing as npt

from navsvc.errors import TraceError

Array = npt.NDArray[np.float64]


def _read(path: Path, columns: int, what: str) -> Array:
    rows = []
    try:
        lines = path.read_text().splitlines()
    except OSError as exc:
        raise TraceError(f"{path}: cannot read: {exc.strerror}") from exc
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
    if np.any(np.diff(data[:, 1 if what == "navigation" else 0]) <= 0.0):
        bad = int(np.argmax(np.diff(data[:, 1 if what == "navigation" else 0]) <= 0.0)) + 2
        raise TraceError(f"{path}: time does not increase at record {bad}")
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
