"""A packed uniform grid over polyline segments, for "which edges lie within r of this point,
and where on each is the closest point" (pure).

The polylines are one flat ``(n, 2)`` array of vertices and the offsets where each polyline
starts (its segments are the pairs of consecutive vertices between two offsets; a segment is
named by the index of its first vertex). The grid is three arrays: the sorted keys of the
cells that hold a segment, where each cell's segments start, and the segments, so that it is
built with a few NumPy sorts, stored in the road-graph database as it is and read back
without any Python object per segment; a query runs in one compiled call.

Chosen over shapely's STRtree after measuring both on the sample map: the grid answers a
50 m query near a road in about 60 % of the STRtree's time (bench/roadgraph_bench.py); the
packed form holds a 2-million-edge map in about 100 MB besides the vertices.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np
import numpy.typing as npt

from roadgraph.geometry import FloatArray

IntArray = npt.NDArray[np.int64]
IndexArray = npt.NDArray[np.int32] | npt.NDArray[np.int64]  # int32 when the values fit

CELL_M = 100.0
_OFF = 1 << 21  # cell indices are kept within +-2^21 (+-209,000 km with 100 m cells)


class NearPolylines(NamedTuple):
    """The polylines near a query point, nearest first, and the closest point on each."""

    polylines: list[int]  # each one by its position in the grid's input
    # per polyline: distance_m, offset_m (along it from its first vertex), x_m, y_m and
    # bearing_rad (of the segment holding the closest point, or the nearest one with a length)
    closest: list[list[float]]


NOTHING_NEAR = NearPolylines([], [])


class GridArrays(NamedTuple):
    """The grid as stored: cell keys (sorted), each cell's first entry, the segments."""

    cell_m: float
    keys: IntArray
    start: IntArray  # len(keys) + 1
    segments: IndexArray  # first vertex of each segment, cell by cell


def cell_key(i: IntArray | int, j: IntArray | int) -> IntArray | int:
    """One integer per cell (column ``i``, row ``j``)."""
    return (i + _OFF) * (2 * _OFF) + (j + _OFF)


def build_grid(coords: FloatArray, offsets: IntArray, cell_m: float = CELL_M) -> GridArrays:
    """Bin every segment into the cells its bounding box meets."""
    if cell_m <= 0.0:
        raise ValueError(f"cell_m must be > 0, got {cell_m}")
    coords = np.ascontiguousarray(coords, dtype=np.float64)
    if len(coords) and float(np.abs(coords).max()) / cell_m >= _OFF - 1:
        raise ValueError("coordinates too large for the grid")
    key, segments = _bin_segments(coords, np.ascontiguousarray(offsets, dtype=np.int64),
                                  cell_m)
    order = np.argsort(key, kind="stable")  # segments were binned in order: ties stay so
    key = key[order]
    segments = segments[order]
    del order
    first = np.ones(len(key), dtype=bool)
    first[1:] = key[1:] != key[:-1]
    begin = np.flatnonzero(first)
    start = np.append(begin, key.size).astype(np.int64)
    if len(coords) < 2**31:  # the largest array of a big map: half the size
        segments = segments.astype(np.int32)
    return GridArrays(cell_m, key[begin], start, segments)


@numba.njit(cache=True)
def _bin_segments(coords: FloatArray, offsets: IntArray, cell_m: float
                  ) -> tuple[IntArray, IntArray]:  # pragma: no cover - compiled
    """(cell key, segment) for each cell each segment's bounding box meets, segment by
    segment (two passes: count, then fill)."""
    total = 0
    for p in range(offsets.size - 1):
        for s in range(offsets[p], offsets[p + 1] - 1):
            i0, i1, j0, j1 = _cell_range(coords, s, cell_m)
            total += (i1 - i0 + 1) * (j1 - j0 + 1)
    key = np.empty(total, dtype=np.int64)
    seg = np.empty(total, dtype=np.int64)
    n = 0
    for p in range(offsets.size - 1):
        for s in range(offsets[p], offsets[p + 1] - 1):
            i0, i1, j0, j1 = _cell_range(coords, s, cell_m)
            for i in range(i0, i1 + 1):
                for j in range(j0, j1 + 1):
                    key[n] = (i + _OFF) * (2 * _OFF) + (j + _OFF)
                    seg[n] = s
                    n += 1
    return key, seg


@numba.njit(cache=True)
def _cell_range(coords: FloatArray, s: int, cell_m: float
                ) -> tuple[int, int, int, int]:  # pragma: no cover - compiled
    ax, ay, bx, by = coords[s, 0], coords[s, 1], coords[s + 1, 0], coords[s + 1, 1]
    return (math.floor(min(ax, bx) / cell_m), math.floor(max(ax, bx) / cell_m),
            math.floor(min(ay, by) / cell_m), math.floor(max(ay, by) / cell_m))


class SegmentGrid:
    """Index of the segments of many polylines; results name polylines by their position."""

    def __init__(self, coords: FloatArray, offsets: IntArray,
                 grid: GridArrays | None = None) -> None:
        self._coords = np.ascontiguousarray(coords, dtype=np.float64)
        self._offsets = np.ascontiguousarray(offsets, dtype=np.int64)
        self.grid = grid if grid is not None else build_grid(self._coords, self._offsets)
        self.cell_m = self.grid.cell_m
        keys = self.grid.keys
        if keys.size:  # from the cells (the vertices are many: a pass over them costs 1 s)
            i, j = keys // (2 * _OFF), keys % (2 * _OFF)
            self._extent_m = float(max(np.ptp(i), np.ptp(j)) + 1) * self.cell_m
        else:
            self._extent_m = 0.0

    @classmethod
    def from_polylines(cls, polylines: list[FloatArray], cell_m: float = CELL_M) -> SegmentGrid:
        """A grid over a list of ``(n, 2)`` polylines (each of two vertices or more)."""
        coords = np.vstack(polylines) if polylines else np.empty((0, 2))
        offsets = np.cumsum([0, *(len(p) for p in polylines)]).astype(np.int64)
        return cls(coords, offsets, build_grid(coords, offsets, cell_m))

    def near(self, x_m: float, y_m: float, radius_m: float, limit: int = -1) -> NearPolylines:
        """Each polyline within ``radius_m`` and its closest point, nearest first (ties: the
        lower polyline index, then its first segment); only the first ``limit`` when >= 0.

        A point that is not finite (a position the map's projection cannot hold, such as a
        pole in a UTM frame) is near nothing."""
        if not (math.isfinite(x_m) and math.isfinite(y_m)) or limit == 0:
            return NOTHING_NEAR
        g = self.grid
        owners, closest = _near(x_m, y_m, radius_m, limit, g.cell_m, g.keys, g.start,
                                g.segments, self._coords, self._offsets)
        return NearPolylines(owners.tolist(), closest.tolist())

    def nearest(self, x_m: float, y_m: float) -> NearPolylines:
        """The nearest polyline however far (widening searches, then every segment); nothing
        for a point that is not finite or an empty grid."""
        if not (math.isfinite(x_m) and math.isfinite(y_m)):
            return NOTHING_NEAR
        radius = self.cell_m
        while radius <= self._extent_m:
            found = self.near(x_m, y_m, radius, limit=1)
            if found.polylines:
                return found
            radius *= 4.0
        return self.near(x_m, y_m, math.inf, limit=1)


@numba.njit(cache=True, nogil=True)
def _owner_of(vertex: int, offsets: IntArray) -> int:  # pragma: no cover - compiled
    """The polyline holding a vertex (binary search over the offsets)."""
    lo, hi = 0, offsets.size - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if offsets[mid] <= vertex:
            lo = mid
        else:
            hi = mid
    return lo


@numba.njit(cache=True, nogil=True)
def _candidates(x_m: float, y_m: float, radius_m: float, cell_m: float, keys: IntArray,
                start: IntArray, segments: IndexArray, n_vertices: int,
                offsets: IntArray) -> IntArray:  # pragma: no cover - compiled
    """The segments in the cells the query's box meets, sorted, each once."""
    if not math.isfinite(radius_m):
        return _all_segments(n_vertices, offsets)
    i0 = math.floor((x_m - radius_m) / cell_m)
    i1 = math.floor((x_m + radius_m) / cell_m)
    j0 = math.floor((y_m - radius_m) / cell_m)
    j1 = math.floor((y_m + radius_m) / cell_m)
    if (i1 - i0 + 1) * (j1 - j0 + 1) > keys.size:
        return _all_segments(n_vertices, offsets)
    total = 0
    found = np.empty(((i1 - i0 + 1) * (j1 - j0 + 1), 2), dtype=np.int64)
    n = 0
    for i in range(i0, i1 + 1):
        for j in range(j0, j1 + 1):
            k = (i + _OFF) * (2 * _OFF) + (j + _OFF)
            p = np.searchsorted(keys, k)
            if p < keys.size and keys[p] == k:
                found[n, 0], found[n, 1] = start[p], start[p + 1]
                total += start[p + 1] - start[p]
                n += 1
    out = np.empty(total, dtype=np.int64)
    m = 0
    for c in range(n):
        for s in range(found[c, 0], found[c, 1]):
            out[m] = segments[s]
            m += 1
    return np.unique(out)


@numba.njit(cache=True, nogil=True)
def _all_segments(n_vertices: int, offsets: IntArray) -> IntArray:  # pragma: no cover
    keep = np.ones(n_vertices, dtype=np.bool_)
    for k in range(1, offsets.size):
        if offsets[k] > 0:
            keep[offsets[k] - 1] = False
    return np.flatnonzero(keep)


@numba.njit(cache=True, nogil=True)
def _segment_bearing(s: int, lo: int, hi: int, coords: FloatArray) -> float:  # pragma: no cover
    """Bearing of segment ``s`` of the polyline of vertices ``lo..hi-1``; a zero-length one
    takes that of the nearest segment with a length (0 when none has)."""
    n = hi - lo - 1
    i = s - lo
    for step in range(n):
        for j in (i - step, i + step):
            if 0 <= j < n:
                dx = coords[lo + j + 1, 0] - coords[lo + j, 0]
                dy = coords[lo + j + 1, 1] - coords[lo + j, 1]
                if dx != 0.0 or dy != 0.0:
                    b = math.atan2(dx, dy)
                    if b < 0.0:
                        b += 2.0 * math.pi
                    return 0.0 if b >= 2.0 * math.pi else b
    return 0.0


@numba.njit(cache=True, nogil=True)
def _near(x_m: float, y_m: float, radius_m: float, limit: int, cell_m: float, keys: IntArray,
          start: IntArray, segments: IndexArray, coords: FloatArray, offsets: IntArray
          ) -> tuple[IntArray, FloatArray]:  # pragma: no cover - compiled
    """Each owner's nearest segment within the radius, owners nearest first and at most
    ``limit`` of them (all when negative): the owners, and the rows of
    :class:`NearPolylines` ``closest``. Compiled: a query runs once per map-matching
    candidate search."""
    segs = _candidates(x_m, y_m, radius_m, cell_m, keys, start, segments, coords.shape[0],
                       offsets)
    d2 = np.empty(segs.size)
    ts = np.empty(segs.size)
    for k in range(segs.size):
        s = segs[k]
        ax, ay = coords[s, 0], coords[s, 1]
        dx, dy = coords[s + 1, 0] - ax, coords[s + 1, 1] - ay
        len_sq = dx * dx + dy * dy
        px, py = x_m - ax, y_m - ay
        t = 0.0
        if len_sq > 0.0:
            t = min(max((px * dx + py * dy) / len_sq, 0.0), 1.0)
        ex, ey = px - t * dx, py - t * dy
        d2[k] = ex * ex + ey * ey
        ts[k] = t
    order = np.argsort(d2, kind="mergesort")
    seen = set()
    out_owner = np.empty(segs.size, dtype=np.int64)
    out = np.empty((segs.size, 5))
    n = 0
    radius_sq = radius_m * radius_m
    for k in order:
        if d2[k] > radius_sq or n == limit:
            break
        s = segs[k]
        o = _owner_of(s, offsets)
        if o in seen:
            continue
        seen.add(o)
        lo, hi = offsets[o], offsets[o + 1]
        run = 0.0
        for v in range(lo, s):
            run += math.hypot(coords[v + 1, 0] - coords[v, 0], coords[v + 1, 1] - coords[v, 1])
        ax, ay = coords[s, 0], coords[s, 1]
        dx, dy = coords[s + 1, 0] - ax, coords[s + 1, 1] - ay
        t = ts[k]
        out_owner[n] = o
        out[n, 0] = math.sqrt(d2[k])
        out[n, 1] = run + t * math.sqrt(dx * dx + dy * dy)
        out[n, 2] = ax + t * dx
        out[n, 3] = ay + t * dy
        out[n, 4] = _segment_bearing(s, lo, hi, coords)
        n += 1
    return out_owner[:n], out[:n]
