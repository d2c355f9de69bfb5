"""Recorded GNSS error, replayed onto simulated drives (pure: parses text, never opens files).

A recording is the error of a real receiver against its ground truth, second by second over
the window the truth covers: ``fix - truth`` in local metres east and north, or nothing where
the receiver gave no fix. The simulator adds it to the true position of a simulated drive,
starting at an offset into the recording (chosen from the drive's seed) and wrapping around at
the end, and sends no fix where the recording has none; so the drive sees the real error's
runs (multipath, non-line-of-sight reception) and its gaps, not independent noise.

Source: UrbanNav Hong Kong, Tsim Sha Tsui (Hsu et al., ION GNSS+ 2021): single-point fixes
computed with RTKLIB from a u-blox receiver's observations, against a NovAtel SPAN-CPT ground
truth at 1 Hz (``tests/data/urbannav/``, provenance in ``tests/data/README.md``).

Between whole seconds (fixes faster than 1 Hz) the error is interpolated linearly towards the
next second when the recording has a fix there, else held; a time is covered when the
recording has a fix at the whole second at or before it. East and north are added as the map
frame's x and y (a UTM frame's grid north is within a degree or two of true north, a metre at
most on the recording's largest error).
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

_WGS84_A_M = 6378137.0
_WGS84_E2 = 6.69437999014e-3


@dataclass(frozen=True)
class GnssErrorRecording:
    """A real receiver's horizontal error at each whole second of a window.

    ``east_m[k]``, ``north_m[k]`` are the error ``k`` seconds after the window's start;
    ``present[k]`` is False where the receiver had no fix (the error values there are 0).
    """

    name: str
    east_m: tuple[float, ...]
    north_m: tuple[float, ...]
    present: tuple[bool, ...]

    def __post_init__(self) -> None:
        n = len(self.present)
        if n == 0 or len(self.east_m) != n or len(self.north_m) != n:
            raise ValueError(f"recording {self.name!r}: east, north and present must have the "
                             f"same length > 0 (got {len(self.east_m)}, {len(self.north_m)}, {n})")
        if not any(self.present):
            raise ValueError(f"recording {self.name!r} has no fix")

    @property
    def duration_s(self) -> int:
        return len(self.present)


def _metres_per_degree(lat_deg: float) -> tuple[float, float]:
    """(east per degree of longitude, north per degree of latitude) on WGS84 at ``lat_deg``."""
    s = math.sin(math.radians(lat_deg))
    w = math.sqrt(1.0 - _WGS84_E2 * s * s)
    north = _WGS84_A_M * (1.0 - _WGS84_E2) / w ** 3
    east = _WGS84_A_M / w * math.cos(math.radians(lat_deg))
    return math.radians(1.0) * east, math.radians(1.0) * north


def parse_urbannav(spp_csv: str, truth_csv: str, name: str = "urbannav-hk-tst") -> (
        GnssErrorRecording):
    """The recording of UrbanNav's ``spp_fixes.csv`` (with header; fixes and the truth at the
    same second) over the window of ``groundTruth_TST.csv`` (no header: week, tow, lat, lon,
    height). Seconds of the window without a fix are gaps."""
    tows = [float(row[1]) for row in csv.reader(io.StringIO(truth_csv)) if row]
    start, end = int(round(min(tows))), int(round(max(tows)))
    n = end - start + 1
    east, north, present = [0.0] * n, [0.0] * n, [False] * n
    for row in csv.DictReader(io.StringIO(spp_csv)):
        k = int(round(float(row["tow_s"]))) - start
        if not row["truth_lat"] or not 0 <= k < n:
            continue
        truth_lat, truth_lon = float(row["truth_lat"]), float(row["truth_lon"])
        m_east, m_north = _metres_per_degree(truth_lat)
        east[k] = (float(row["lon"]) - truth_lon) * m_east
        north[k] = (float(row["lat"]) - truth_lat) * m_north
        present[k] = True
    return GnssErrorRecording(name, tuple(east), tuple(north), tuple(present))


def replay_error(recording: GnssErrorRecording, t_s: npt.NDArray[np.float64],
                 offset_s: int) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.float64]]:
    """At drive times ``t_s``: whether the recording has a fix, and its error (n x 2, east and
    north in metres; 0 where there is none), ``offset_s`` seconds into the recording."""
    present = np.array(recording.present)
    error = np.column_stack([recording.east_m, recording.north_m])
    n = recording.duration_s
    r = np.asarray(t_s, dtype=float) + offset_s
    whole = np.floor(r + 1e-6)
    frac = np.clip(r - whole, 0.0, 1.0)[:, None]
    k = whole.astype(np.int64) % n
    k_next = (k + 1) % n
    blend = np.where(present[k_next][:, None], frac, 0.0)
    out = (1.0 - blend) * error[k] + blend * error[k_next]
    covered = present[k]
    return covered, np.where(covered[:, None], out, 0.0)
