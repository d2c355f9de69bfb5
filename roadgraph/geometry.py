"""Plane geometry in a map's local metric frame (pure: no I/O).

Owns the conventions every other module follows:

* Positions are metres in the map's projected CRS (UTM of the map's centre): ``x_m`` east,
  ``y_m`` north. WGS84 degrees appear only at the edges, through :class:`LocalFrame`.
* Bearings and headings are radians **clockwise from north** in ``[0, 2π)``, the compass
  convention used on the wire (``heading_deg``), so the two differ only by a unit.
* A turn angle is the wrapped change of bearing in ``(-π, π]``: positive turns right
  (clockwise), negative turns left.

Seed: Mayhew 1999, section 5.2 and appendix B converted geodetic to ground metres with an
ellipsoid formula; a proper projection (pyproj) replaces it here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import NamedTuple

import numba
import numpy as np
import numpy.typing as npt
from pyproj import CRS, Transformer

FloatArray = npt.NDArray[np.float64]

TWO_PI = 2.0 * math.pi


def wrap_angle_rad(angle_rad: float) -> float:
    """Wrap an angle to ``(-π, π]``."""
    wrapped = math.fmod(angle_rad + math.pi, TWO_PI)
    if wrapped <= 0.0:
        wrapped += TWO_PI
    return wrapped - math.pi


def normalize_bearing_rad(bearing_rad: float) -> float:
    """Wrap a bearing to ``[0, 2π)``."""
    b = math.fmod(bearing_rad, TWO_PI)
    if b < 0.0:
        b += TWO_PI
    return 0.0 if b >= TWO_PI else b


def bearing_rad(x0_m: float, y0_m: float, x1_m: float, y1_m: float) -> float:
    """Bearing of the direction from point 0 to point 1, clockwise from north."""
    return normalize_bearing_rad(math.atan2(x1_m - x0_m, y1_m - y0_m))


def turn_angle_rad(bearing_in_rad: float, bearing_out_rad: float) -> float:
    """Signed turn from one bearing to another: positive right, negative left."""
    return wrap_angle_rad(bearing_out_rad - bearing_in_rad)


def utm_crs_for(lon_deg: float, lat_deg: float) -> CRS:
    """The WGS84 UTM zone CRS that contains a point."""
    zone = int((lon_deg + 180.0) // 6.0) % 60 + 1
    epsg = (32600 if lat_deg >= 0.0 else 32700) + zone
    return CRS.from_epsg(epsg)


@dataclass(frozen=True)
class LocalFrame:
    """A map's metric CRS and WGS84, both ways; one per map, shared by fusion and matching."""

    crs_wkt: str

    @classmethod
    def for_point(cls, lon_deg: float, lat_deg: float) -> LocalFrame:
        """The UTM frame of the zone containing a point (used when no map is loaded)."""
        return cls(utm_crs_for(lon_deg, lat_deg).to_wkt())

    @cached_property
    def _forward(self) -> Transformer:
        return Transformer.from_crs("EPSG:4326", CRS.from_wkt(self.crs_wkt), always_xy=True)

    @cached_property
    def _inverse(self) -> Transformer:
        return Transformer.from_crs(CRS.from_wkt(self.crs_wkt), "EPSG:4326", always_xy=True)

    def to_local(self, lon_deg: float, lat_deg: float) -> tuple[float, float]:
        """WGS84 degrees → local metres ``(x_m, y_m)``."""
        x, y = self._forward.transform(lon_deg, lat_deg)
        return float(x), float(y)

    def to_wgs84(self, x_m: float, y_m: float) -> tuple[float, float]:
        """Local metres → WGS84 ``(lon_deg, lat_deg)``."""
        lon, lat = self._inverse.transform(x_m, y_m)
        return float(lon), float(lat)

    def coords_to_wgs84(self, coords: FloatArray) -> FloatArray:
        """An ``(n, 2)`` array of local metres → ``(n, 2)`` of ``(lon_deg, lat_deg)``."""
        lon, lat = self._inverse.transform(coords[:, 0], coords[:, 1])
        return np.column_stack([lon, lat]).astype(np.float64)

    def coords_to_local(self, lonlat: FloatArray) -> FloatArray:
        """An ``(n, 2)`` array of ``(lon_deg, lat_deg)`` → ``(n, 2)`` of local metres."""
        x, y = self._forward.transform(lonlat[:, 0], lonlat[:, 1])
        return np.column_stack([x, y]).astype(np.float64)


def unique_sorted(values: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    """``np.unique`` of integers by sorting (NumPy 2's hashing ``unique`` is ten times
    slower on the import's arrays of millions of ids)."""
    out = np.sort(values)
    if out.size:
        out = out[np.concatenate([[True], out[1:] != out[:-1]])]
    return out


class PolylineProjection(NamedTuple):
    """Where a point falls on a polyline: the closest point and the road direction there."""

    offset_m: float  # distance along the polyline from its first vertex to the closest point
    distance_m: float  # distance from the point to the closest point
    x_m: float
    y_m: float
    bearing_rad: float  # direction of the segment holding the closest point
    segment_index: int


def project_onto_polyline(coords: FloatArray, x_m: float, y_m: float) -> PolylineProjection:
    """Project a point onto a polyline given as an ``(n, 2)`` array of ``n >= 2`` vertices.

    Zero-length segments are allowed; the bearing then comes from the nearest non-degenerate one.
    """
    offset, distance, x, y, bearing, segment = _project(coords, x_m, y_m)
    return PolylineProjection(offset, distance, x, y, normalize_bearing_rad(bearing), segment)


@numba.njit(cache=True, nogil=True)
def _project(coords: FloatArray, x_m: float, y_m: float
             ) -> tuple[float, float, float, float, float, int]:
    """(offset, distance, x, y, bearing, segment) of the closest point; compiled, because the
    matchers call this for every candidate edge and numpy's per-call overhead dominated."""
    best_i, best_d2, best_t, best_off, run = 0, np.inf, 0.0, 0.0, 0.0
    for i in range(coords.shape[0] - 1):
        ax, ay = coords[i, 0], coords[i, 1]
        dx, dy = coords[i + 1, 0] - ax, coords[i + 1, 1] - ay
        len_sq = dx * dx + dy * dy
        t = 0.0
        if len_sq > 0.0:
            t = min(max(((x_m - ax) * dx + (y_m - ay) * dy) / len_sq, 0.0), 1.0)
        cx, cy = ax + t * dx - x_m, ay + t * dy - y_m
        d2 = cx * cx + cy * cy
        seg_len = math.sqrt(len_sq)
        if d2 < best_d2:
            best_i, best_d2, best_t, best_off = i, d2, t, run + t * seg_len
        run += seg_len
    j = _nearest_nondegenerate(coords, best_i)
    dx, dy = coords[j + 1, 0] - coords[j, 0], coords[j + 1, 1] - coords[j, 1]
    px = coords[best_i, 0] + best_t * (coords[best_i + 1, 0] - coords[best_i, 0])
    py = coords[best_i, 1] + best_t * (coords[best_i + 1, 1] - coords[best_i, 1])
    return best_off, math.sqrt(best_d2), px, py, math.atan2(dx, dy), best_i


@numba.njit(cache=True, nogil=True)
def _nearest_nondegenerate(coords: FloatArray, i: int) -> int:
    """The segment nearest to ``i`` (itself first) that has a length, else ``i``."""
    n = coords.shape[0] - 1
    for step in range(n):
        for j in (i - step, i + step):
            if 0 <= j < n and (coords[j + 1, 0] != coords[j, 0] or
                               coords[j + 1, 1] != coords[j, 1]):
                return j
    return i


def polyline_length_m(coords: FloatArray) -> float:
    """Sum of segment lengths of an ``(n, 2)`` polyline."""
    return float(np.sum(np.hypot(*np.diff(coords, axis=0).T)))


def point_at_offset(coords: FloatArray, offset_m: float) -> tuple[float, float, float]:
    """The point ``offset_m`` along a polyline (clamped to its ends) and the bearing there."""
    seg = np.diff(coords, axis=0)
    seg_len = np.hypot(seg[:, 0], seg[:, 1])
    cum = np.concatenate([[0.0], np.cumsum(seg_len)])
    offset = min(max(offset_m, 0.0), float(cum[-1]))
    i = int(np.clip(np.searchsorted(cum, offset, side="right") - 1, 0, len(seg) - 1))
    i = _nearest_nondegenerate(coords, i)
    frac = 0.0 if seg_len[i] == 0.0 else (offset - cum[i]) / seg_len[i]
    x, y = coords[i] + seg[i] * min(max(frac, 0.0), 1.0)
    return float(x), float(y), normalize_bearing_rad(math.atan2(seg[i, 0], seg[i, 1]))


def end_bearings_rad(coords: FloatArray, reach_m: float = 20.0) -> tuple[float, float]:
    """Bearings leaving the first vertex and arriving at the last one.

    Measured over the first/last ``reach_m`` of the polyline rather than a single segment, so
    that a short kink at a junction does not decide the road's direction.
    """
    length = polyline_length_m(coords)
    reach = min(reach_m, length)
    x0, y0 = coords[0]
    xa, ya, _ = point_at_offset(coords, reach)
    xb, yb, _ = point_at_offset(coords, length - reach)
    x1, y1 = coords[-1]
    return bearing_rad(x0, y0, xa, ya), bearing_rad(xb, yb, x1, y1)
