"""Accuracy of a run against the truth of a drive (the metrics of ``navsvc evaluate``).

Inputs are wire records: the drive (``kind: "truth"`` records and the GPS packets the vehicle
sent) and the matched positions of ``navsvc run``. Truth (10 Hz) is interpolated to each
estimate's time. Errors are horizontal distances in metres.

* position error of the output (``lat``/``lon``: on the road when matched) and of the fusion
  alone (``fused_lat``/``fused_lon``), with the raw GPS error of the same drive beside them;
  their ratio compares the two at the same epochs: each GPS fix against the fused estimate
  within ``SAME_EPOCH_S`` of it (over the whole drive the fused error would include the
  outages and tunnels, where raw GPS has no error to compare because it has no fix);
* drift in each GPS outage (a gap in the drive's GPS packets): the fused error when GPS returns
  as a share of the distance driven in the gap;
* heading error while moving;
* share of epochs on the right road (within 5 m of an intersection either road counts) and
  intersections traversed correctly: the road matched most while on each new road, leaving
  out the epochs within 5 m of its ends (when the run matched positions to edges).
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import asdict, dataclass
from functools import cached_property
from typing import Any

import numpy as np

from roadgraph import LocalFrame

MIN_OUTAGE_S = 3.0  # a GPS gap longer than this is an outage
NODE_TOLERANCE_M = 5.0  # within this of an intersection, the roads on both sides are right
MIN_SPEED_FOR_HEADING_MPS = 1.0
SAME_EPOCH_S = 0.5  # a fused estimate this close to a fix is the fix's epoch


@dataclass(frozen=True)
class ErrorStats:
    rms_m: float
    p95_m: float
    max_m: float
    n: int

    @classmethod
    def of(cls, errors: np.ndarray) -> ErrorStats:
        if len(errors) == 0:
            return cls(math.nan, math.nan, math.nan, 0)
        return cls(float(np.sqrt(np.mean(errors ** 2))), float(np.percentile(errors, 95)),
                   float(errors.max()), len(errors))


@dataclass(frozen=True)
class OutageResult:
    start_s: float
    end_s: float
    distance_m: float
    end_error_m: float  # fused error at the last estimate before GPS returned
    max_error_m: float

    @property
    def drift_pct(self) -> float:
        return 100.0 * self.end_error_m / self.distance_m if self.distance_m > 0 else math.nan


@dataclass(frozen=True)
class Evaluation:
    position: ErrorStats  # the output position (matched when on a road)
    fused: ErrorStats  # the fusion engine alone
    raw_gps: ErrorStats  # the GPS packets of the drive
    fused_at_gps: ErrorStats  # the fused estimates at the fixes' epochs ...
    raw_at_fused: ErrorStats  # ... and the raw GPS at the same epochs
    heading_rms_deg: float
    heading_p95_deg: float
    outages: tuple[OutageResult, ...]
    on_right_road_share: float | None  # of all epochs; None when the run matched nothing
    intersections_correct: int
    intersections_total: int

    @property
    def fused_to_raw_ratio(self) -> float:
        return self.fused_at_gps.rms_m / self.raw_at_fused.rms_m if self.raw_at_fused.n \
            else math.nan

    def to_json(self) -> dict[str, Any]:
        out = asdict(self)
        out["fused_to_raw_ratio"] = self.fused_to_raw_ratio
        out["outages"] = [asdict(o) | {"drift_pct": o.drift_pct} for o in self.outages]
        return out


@dataclass(frozen=True)
class _Truth:
    t: np.ndarray
    xy: np.ndarray
    heading_rad: np.ndarray  # unwrapped
    speed_mps: np.ndarray
    road: list[frozenset[int]]  # undirected node pair of the true edge
    s_m: np.ndarray  # distance driven

    def at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return (np.column_stack([np.interp(t, self.t, self.xy[:, 0]),
                                 np.interp(t, self.t, self.xy[:, 1])]),
                np.interp(t, self.t, self.heading_rad))

    @cached_property
    def changes(self) -> np.ndarray:
        """Indices of the first record on each new road."""
        return np.array([i for i in range(1, len(self.road)) if self.road[i] != self.road[i - 1]],
                        dtype=int)

    def roads_at(self, t: float) -> set[frozenset[int]]:
        """The true road at ``t``, and the roads on both sides of any change of road within
        NODE_TOLERANCE_M (truth and map disagree by a few metres at intersections)."""
        i = int(np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, len(self.t) - 1))
        s = float(np.interp(t, self.t, self.s_m))
        change_s = self.s_m[self.changes]
        lo = np.searchsorted(change_s, s - NODE_TOLERANCE_M)
        hi = np.searchsorted(change_s, s + NODE_TOLERANCE_M, side="right")
        roads = {self.road[i]}
        for k in self.changes[lo:hi]:
            roads |= {self.road[k - 1], self.road[k]}
        return roads


def _truth(records: list[dict[str, Any]], frame: LocalFrame) -> _Truth:
    truth = sorted((r for r in records if r.get("kind") == "truth"), key=lambda r: r["t"])
    if len(truth) < 2:
        raise ValueError("the drive has fewer than 2 truth records")
    xy = frame.coords_to_local(np.array([(r["lon"], r["lat"]) for r in truth]))
    steps = np.hypot(*np.diff(xy, axis=0).T)
    return _Truth(
        t=np.array([r["t"] for r in truth]), xy=xy,
        heading_rad=np.unwrap(np.radians([r["heading_deg"] for r in truth])),
        speed_mps=np.array([r.get("speed_mps", 0.0) for r in truth]),
        road=[frozenset((r["u"], r["v"])) for r in truth],
        s_m=np.concatenate([[0.0], np.cumsum(steps)]))


def _errors(truth: _Truth, t: np.ndarray, xy: np.ndarray) -> np.ndarray:
    where, _ = truth.at(t)
    return np.hypot(*(xy - where).T) if len(t) else np.zeros(0)


def _points(records: list[dict[str, Any]], frame: LocalFrame, lat: str,
            lon: str) -> np.ndarray:
    if not records:
        return np.zeros((0, 2))
    return frame.coords_to_local(np.array([(r[lon], r[lat]) for r in records]))


def _same_epochs(est_t: np.ndarray, fused_err: np.ndarray, gps_t: np.ndarray,
                 raw_err: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fused and raw errors at the fixes with a fused estimate within SAME_EPOCH_S."""
    if not len(est_t) or not len(gps_t):
        return np.zeros(0), np.zeros(0)
    order = np.argsort(est_t, kind="stable")
    t_sorted = est_t[order]
    right = np.clip(np.searchsorted(t_sorted, gps_t), 0, len(t_sorted) - 1)
    left = np.clip(right - 1, 0, len(t_sorted) - 1)
    nearest = np.where(np.abs(t_sorted[left] - gps_t) <= np.abs(t_sorted[right] - gps_t),
                       left, right)
    close = np.abs(t_sorted[nearest] - gps_t) <= SAME_EPOCH_S
    return fused_err[order[nearest[close]]], raw_err[close]


def _outages(gps_t: np.ndarray, truth: _Truth, est_t: np.ndarray,
             fused_err: np.ndarray) -> tuple[OutageResult, ...]:
    out = []
    for start, end in zip(gps_t[:-1], gps_t[1:]):
        if end - start <= MIN_OUTAGE_S:
            continue
        inside = (est_t > start) & (est_t < end)
        if not inside.any():
            continue
        s0, s1 = np.interp([start, end], truth.t, truth.s_m)
        errors = fused_err[inside]
        out.append(OutageResult(float(start), float(end), float(s1 - s0), float(errors[-1]),
                                float(errors.max())))
    return tuple(out)


def _intersections(truth: _Truth, est_t: np.ndarray,
                   est_road: list[frozenset[int] | None]) -> tuple[int, int]:
    """Each time the truth enters a new road: did the run mostly match that road there?

    Epochs within NODE_TOLERANCE_M of either end of the road are left out of the vote when
    others remain, as for the right-road share: a car standing on the intersection itself
    (stopped at the line) is on both roads and says nothing of the road it takes. A road the
    truth never gets NODE_TOLERANCE_M along (the drive ends on the node) was not traversed."""
    changes = truth.changes.tolist()
    est_s = np.interp(est_t, truth.t, truth.s_m) if len(est_t) else np.zeros(0)
    correct = total = 0
    for k, i in enumerate(changes):
        last = changes[k + 1] if k + 1 < len(changes) else len(truth.t) - 1
        span = [(s, road) for t, s, road in zip(est_t, est_s, est_road)
                if truth.t[i] <= t < truth.t[last] and road is not None]
        if not span or truth.s_m[last] - truth.s_m[i] < NODE_TOLERANCE_M:
            continue
        inside = [road for s, road in span if truth.s_m[i] + NODE_TOLERANCE_M <= s
                  <= truth.s_m[last] - NODE_TOLERANCE_M]
        matched = inside or [road for _, road in span]
        total += 1
        correct += Counter(matched).most_common(1)[0][0] == truth.road[i]
    return correct, total


def evaluate(drive: list[dict[str, Any]], estimates: list[dict[str, Any]]) -> Evaluation:
    """Compare a run's matched positions with the truth records of its drive."""
    first = next((r for r in drive if r.get("kind") == "truth"), None)
    if first is None:
        raise ValueError("the drive has no truth records")
    frame = LocalFrame.for_point(first["lon"], first["lat"])
    truth = _truth(drive, frame)
    within = [r for r in estimates if truth.t[0] <= r["t"] <= truth.t[-1]]
    est_t = np.array([r["t"] for r in within])
    position_err = _errors(truth, est_t, _points(within, frame, "lat", "lon"))
    fused_err = _errors(truth, est_t, _points(within, frame, "fused_lat", "fused_lon"))
    gps = [r for r in drive if r.get("kind") == "gps" and truth.t[0] <= r["t"] <= truth.t[-1]]
    gps_t = np.array([r["t"] for r in gps])
    raw_err = _errors(truth, gps_t, _points(gps, frame, "lat", "lon"))

    fused_at_gps, raw_at_fused = _same_epochs(est_t, fused_err, gps_t, raw_err)
    _, true_heading = truth.at(est_t)
    moving = np.interp(est_t, truth.t, truth.speed_mps) >= MIN_SPEED_FOR_HEADING_MPS
    est_heading = np.radians([math.nan if r["heading_deg"] is None else r["heading_deg"]
                              for r in within]) if within else np.zeros(0)
    heading_err = np.degrees(np.abs(np.angle(np.exp(1j * (est_heading - true_heading)))))[
        moving & np.isfinite(est_heading)]  # none before start-up

    est_road = [frozenset((r["edge"]["u"], r["edge"]["v"])) if r.get("edge") else None
                for r in within]
    with_edge = [(t, road) for t, road in zip(est_t, est_road) if road is not None]
    right = [road in truth.roads_at(t) for t, road in with_edge]
    correct, total = _intersections(truth, est_t, est_road)
    return Evaluation(
        position=ErrorStats.of(position_err), fused=ErrorStats.of(fused_err),
        raw_gps=ErrorStats.of(raw_err), fused_at_gps=ErrorStats.of(fused_at_gps),
        raw_at_fused=ErrorStats.of(raw_at_fused),
        heading_rms_deg=float(np.sqrt(np.mean(heading_err ** 2))) if len(heading_err)
        else math.nan,
        heading_p95_deg=float(np.percentile(heading_err, 95)) if len(heading_err) else math.nan,
        outages=_outages(gps_t, truth, est_t, fused_err),
        on_right_road_share=sum(right) / len(within) if right else None,
        intersections_correct=correct, intersections_total=total)
