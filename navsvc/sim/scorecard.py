"""The scorecard of issue 15: five scores of one run against its drive, and their targets.

On top of :func:`navsvc.sim.evaluate.evaluate` (position errors, outage drift, right road):

* fused RMS over raw GPS RMS (the evaluation's ratio);
* drift in one planned GPS outage, as a share of the distance driven in it;
* consistency: the share of epochs whose true fused-position error lies inside the circle of
  radius 2.45 sigma the output reports (``position_sigma_m``, the square root of the mean of
  the covariance's eigenvalues). For a consistent filter with a round covariance the squared
  error over sigma squared is chi-square with 2 degrees of freedom, whose 95 % point is
  2.45 squared (Bar-Shalom, Li and Kirubarajan 2001, section 5.4: NEES); also the mean of that
  normalised error over 2 (1 when consistent). The target holds for the errors of all the
  runs together (:func:`pooled_circle_share`); :func:`check` also asks it of every drive;
* the largest error of the output (matched) position while GPS is present: at epochs with a
  fix in the second before;
* the share of epochs on the right road;
* the share of the drive's seconds that had an estimate at all (a drive with none scores an
  infinite ratio: it fails, where a NaN had dropped it from the medians unseen);
* how many fixes (one a second: faster ones are not independent) after the planned outage
  the fused estimate takes to be back within twice the drive's raw GPS RMS error (issue 15:
  "within 5 fixes"); infinite when it never is.

Inputs are wire records, as for ``evaluate``.
"""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass
from typing import Any

import numpy as np

from navsvc.sim.evaluate import evaluate
from roadgraph import LocalFrame

CIRCLE_SIGMAS = 2.45  # sqrt of chi-square(2 dof) at 95 %
GPS_PRESENT_WINDOW_S = 1.0  # an epoch has GPS when a fix came in the second before it


@dataclass(frozen=True)
class Scorecard:
    """One run's scores (None where the drive gave nothing to score)."""

    fused_to_raw_ratio: float
    outage_drift_pct: float | None
    circle_share: float | None  # inside 2.45 sigma
    mean_nees_per_dof: float | None
    max_matched_error_with_gps_m: float | None
    right_road_share: float | None
    fused_rms_m: float
    raw_gps_rms_m: float
    output_share: float  # of the drive's seconds, those with an estimate
    recovery_fixes: float | None = None  # after the planned outage, to 2x raw GPS RMS
    circle_epochs: int = 0  # the epochs circle_share counts


@dataclass(frozen=True)
class Target:
    """A bound on the median and on the worst drive of one score."""

    score: str
    median: tuple[float, float]  # the median must lie in [low, high]
    worst: tuple[float, float]  # every drive must lie in [low, high]
    text: str


TARGETS = (
    Target("fused_to_raw_ratio", (0.0, 0.6), (0.0, 0.9), "median <= 0.6, every drive <= 0.9"),
    Target("outage_drift_pct", (0.0, 2.0), (0.0, 4.0), "median <= 2 %, worst <= 4 %"),
    Target("circle_share", (0.90, 0.98), (0.90, 0.98), "90-98 % inside 2.45 sigma"),
    Target("max_matched_error_with_gps_m", (0.0, 50.0), (0.0, 50.0), "none > 50 m"),
)


def _truth_xy(drive: list[dict[str, Any]]) -> tuple[LocalFrame, np.ndarray, np.ndarray]:
    truth = sorted((r for r in drive if r.get("kind") == "truth"), key=lambda r: r["t"])
    frame = LocalFrame.for_point(truth[0]["lon"], truth[0]["lat"])
    return (frame, np.array([r["t"] for r in truth]),
            frame.coords_to_local(np.array([(r["lon"], r["lat"]) for r in truth])))


def _errors(drive: list[dict[str, Any]], estimates: list[dict[str, Any]], lat: str,
            lon: str) -> tuple[np.ndarray, np.ndarray]:
    """Times and horizontal errors of the estimates within the truth's time span."""
    frame, t, xy = _truth_xy(drive)
    within = [r for r in estimates if t[0] <= r["t"] <= t[-1]]
    if not within:
        return np.zeros(0), np.zeros(0)
    est_t = np.array([r["t"] for r in within])
    est = frame.coords_to_local(np.array([(r[lon], r[lat]) for r in within]))
    true = np.column_stack([np.interp(est_t, t, xy[:, 0]), np.interp(est_t, t, xy[:, 1])])
    return est_t, np.hypot(*(est - true).T)


def consistency(drive: list[dict[str, Any]], estimates: list[dict[str, Any]]
                ) -> tuple[float | None, float | None, int]:
    """(share of epochs inside 2.45 sigma, mean squared error over sigma squared over 2,
    epochs scored)."""
    _, err = _errors(drive, estimates, "fused_lat", "fused_lon")
    sigma = _sigmas(drive, estimates)
    ok = sigma > 0
    if not ok.any():
        return None, None, 0
    ratio = err[ok] / sigma[ok]
    return float(np.mean(ratio <= CIRCLE_SIGMAS)), float(np.mean(ratio ** 2) / 2.0), \
        int(ok.sum())


START_UP_S = (10.0, 30.0)  # the phases after the run's first estimate
AFTER_OUTAGE_S = 10.0
PHASES = ("start-up, first 10 s", "start-up, 10-30 s", "planned outage",
          "10 s after the outage", "other epochs without GPS", "with GPS")


def circle_by_phase(drive: list[dict[str, Any]], estimates: list[dict[str, Any]],
                    outage_start_s: float, outage_length_s: float
                    ) -> dict[str, tuple[int, int]]:
    """Where the 2.45-sigma circle holds: (epochs inside, epochs) in each phase of the drive
    (:data:`PHASES`; an epoch counts in the first that fits). A pooled share can meet its
    band while one phase misses it: on the tune split (600 harsh drives) the drives held
    93.6 % of their errors, the first 10 s after start-up 80.6 % and the next 20 s 86.3 %."""
    est_t, err = _errors(drive, estimates, "fused_lat", "fused_lon")
    sigma = _sigmas(drive, estimates)
    counts = {phase: (0, 0) for phase in PHASES}
    if not len(est_t):
        return counts
    outage_end_s = outage_start_s + outage_length_s
    for t, since_start_s, e, s, gps in zip(est_t, est_t - est_t[0], err, sigma,
                                           _with_gps(drive, est_t)):
        phase = PHASES[0] if since_start_s < START_UP_S[0] else \
            PHASES[1] if since_start_s < START_UP_S[1] else \
            PHASES[2] if outage_start_s <= t < outage_end_s else \
            PHASES[3] if outage_end_s <= t < outage_end_s + AFTER_OUTAGE_S else \
            PHASES[5] if gps else PHASES[4]
        inside, epochs = counts[phase]
        counts[phase] = (inside + int(s > 0 and e <= CIRCLE_SIGMAS * s), epochs + int(s > 0))
    return counts


def _sigmas(drive: list[dict[str, Any]], estimates: list[dict[str, Any]]) -> np.ndarray:
    """The reported sigmas of the estimates within the truth's time span (those of
    :func:`_errors`, in its order)."""
    t0, t1 = _truth_span(drive)
    return np.array([r["position_sigma_m"] for r in estimates if t0 <= r["t"] <= t1])


def _truth_span(drive: list[dict[str, Any]]) -> tuple[float, float]:
    t = [r["t"] for r in drive if r.get("kind") == "truth"]
    return min(t), max(t)


def output_share(drive: list[dict[str, Any]], estimates: list[dict[str, Any]]) -> float:
    """The share of the drive's whole seconds in which the run gave an estimate."""
    t0, t1 = _truth_span(drive)
    seconds = max(int(math.ceil(t1 - t0)), 1)
    had = {min(int(r["t"] - t0), seconds - 1) for r in estimates if t0 <= r["t"] <= t1}
    return len(had) / seconds


def max_error_with_gps_m(drive: list[dict[str, Any]],
                         estimates: list[dict[str, Any]]) -> float | None:
    """The largest matched-position error at epochs with a GPS fix in the second before."""
    est_t, err = _errors(drive, estimates, "lat", "lon")
    has = _with_gps(drive, est_t)
    return float(err[has].max()) if has.any() else None


def _with_gps(drive: list[dict[str, Any]], est_t: np.ndarray) -> np.ndarray:
    """Which of the times ``est_t`` had a fix in the second before."""
    gps_t = np.sort([r["t"] for r in drive if r.get("kind") == "gps"])
    if not len(gps_t):
        return np.zeros(len(est_t), dtype=bool)
    last = np.searchsorted(gps_t, est_t, side="right") - 1
    with_gps: np.ndarray = (last >= 0) & \
        (est_t - gps_t[np.maximum(last, 0)] < GPS_PRESENT_WINDOW_S)
    return with_gps


def fixes_to_recover(drive: list[dict[str, Any]], estimates: list[dict[str, Any]],
                     after_s: float, within_m: float) -> float | None:
    """The fixes after ``after_s``, one a second, up to the first at which the fused
    estimate (the first at or after the fix) lies within ``within_m`` of the truth;
    infinite when none does, None without fixes after it."""
    est_t, err = _errors(drive, estimates, "fused_lat", "fused_lon")
    fixes: list[float] = []
    for t in sorted(r["t"] for r in drive if r.get("kind") == "gps" and r["t"] > after_s):
        if not fixes or t - fixes[-1] >= 1.0:
            fixes.append(t)
    if not fixes:
        return None
    for n, t in enumerate(fixes, start=1):
        i = int(np.searchsorted(est_t, t - 1e-9))
        if i < len(est_t) and err[i] <= within_m:
            return float(n)
    return math.inf


def score(drive: list[dict[str, Any]], estimates: list[dict[str, Any]],
          outage_start_s: float) -> Scorecard:
    """The scorecard of a run; the outage scored is the GPS gap around ``outage_start_s``."""
    e = evaluate(drive, estimates)
    outage = next((o for o in e.outages if o.start_s <= outage_start_s + 1.0 <= o.end_s), None)
    circle, nees, circle_epochs = consistency(drive, estimates)
    share = output_share(drive, estimates)
    return Scorecard(
        fused_to_raw_ratio=e.fused_to_raw_ratio if share > 0.0 else math.inf,
        outage_drift_pct=outage.drift_pct if outage else None,
        circle_share=circle, mean_nees_per_dof=nees, circle_epochs=circle_epochs,
        max_matched_error_with_gps_m=max_error_with_gps_m(drive, estimates),
        right_road_share=e.on_right_road_share,
        fused_rms_m=e.fused.rms_m, raw_gps_rms_m=e.raw_gps.rms_m, output_share=share,
        recovery_fixes=fixes_to_recover(drive, estimates, outage.end_s,
                                        2.0 * e.raw_gps.rms_m) if outage else None)


def _worst(values: list[float], bounds: tuple[float, float]) -> float:
    """The largest value for an upper bound alone; else the farthest from the band's middle."""
    low, high = bounds
    if low <= 0.0:
        return max(values)
    return max(values, key=lambda v: abs(v - 0.5 * (low + high)))


def pooled_circle_share(cards: list[Scorecard]) -> float | None:
    """The share of all the runs' epochs inside 2.45 sigma: the consistency target is a
    statement about the errors, and one drive's errors are too few and too correlated (a
    non-line-of-sight run, an outage) for each drive to hold 90-98 % on its own."""
    epochs = sum(c.circle_epochs for c in cards if c.circle_share is not None)
    inside = sum(c.circle_share * c.circle_epochs for c in cards if c.circle_share is not None)
    return inside / epochs if epochs else None


def check(cards: list[Scorecard]) -> list[tuple[str, float, float, str, bool]]:
    """Per target: (score, median, worst drive, target text, met). A drive without a score
    (None, NaN) has nothing to count; an infinite one (no output at all) counts, and fails."""
    out = []
    for target in TARGETS:
        values = [v for c in cards if (v := getattr(c, target.score)) is not None
                  and not math.isnan(v)]
        if not values:
            out.append((target.score, math.nan, math.nan, target.text, False))
            continue
        median, worst = statistics.median(values), _worst(values, target.worst)
        met = target.median[0] <= median <= target.median[1] and \
            all(target.worst[0] <= v <= target.worst[1] for v in values)
        out.append((target.score, median, worst, target.text, met))
    return out
