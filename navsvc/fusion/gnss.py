"""GNSS fixes as both filters read them (pure): is a fix good, and how good is it.

Seed: Mayhew 1999, section 5.4 (validity from the receiver status: a fix is bad if the
receiver says so, there is no 2D/3D fix, fewer than 3 satellites are visible, or DOP > 20).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

from navsvc.types import FusedEstimate, GpsFix, GpsFixType, GpsUsage
from roadgraph.geometry import bearing_rad

if TYPE_CHECKING:
    from navsvc.fusion.config import FusionConfig

# A fix type alone says little: only the corrected solutions are trusted by type (a plain 3D
# fix in a street canyon is off by tens of metres as often as not).
_FIX_SIGMA_M = {GpsFixType.RTK: 0.05, GpsFixType.DGPS: 1.0}
MAX_PLAUSIBLE_SPEED_MPS = 70.0  # faster fixes (or wheels) are an outlier, not a car
CRAWL_MPS = 3.0  # slower than this, or turning faster than CORNERING_RPS, a car's heading
CORNERING_RPS = 0.1  # need not lie along any road (pulling up at a kerb, half-way round a corner)


def leap_m(config: FusionConfig, sigma_m: float) -> float:
    """How far the fixes must move in one step to be a leap, not their error wandering: a
    non-line-of-sight run's size (``jump_spread_m``) or 4 sigma of a fix, whichever is more.
    Dead reckoning does not leap; fixes do."""
    return max(config.jump_spread_m, 4.0 * sigma_m)


def gps_problem(fix: GpsFix, min_sats: int, max_hdop: float) -> str | None:
    """Why a fix is bad (thesis validity rules), or None when it is good."""
    if not fix.status_ok:
        return "receiver status bad"
    if fix.fix == GpsFixType.NONE:
        return "no fix"
    if fix.sats is not None and fix.sats < min_sats:
        return f"{fix.sats} satellites (< {min_sats})"
    if fix.hdop is not None and fix.hdop > max_hdop:
        return f"HDOP {fix.hdop:g} (> {max_hdop:g})"
    return None


MIN_SIGMA_M = 0.01  # no receiver is surer than a centimetre (RTK: about 2 cm)


def course_sigma_rad(speed_mps: float, velocity_sigma_mps: float) -> float:
    """1-sigma error of a receiver's course at this speed: its velocity's error across the
    track over the speed (it grows as the car slows), never below 2 degrees."""
    return max(math.radians(2.0), math.atan2(velocity_sigma_mps, speed_mps))


def gps_sigma_m(fix: GpsFix, uere_m: float, default_sigma_m: float) -> float:
    """1-σ horizontal error of a fix: its own accuracy, else HDOP × UERE, else by fix type
    (RTK, DGPS), else the conservative ``default_sigma_m``; never below ``MIN_SIGMA_M`` (a
    client's accuracy of 5e-324 m squared to zero, and the filters divided by it)."""
    if fix.accuracy_m is not None and fix.accuracy_m > 0.0:
        return max(fix.accuracy_m, MIN_SIGMA_M)
    if fix.hdop is not None and fix.hdop > 0.0:
        return max(fix.hdop * uere_m, MIN_SIGMA_M)
    if fix.fix in _FIX_SIGMA_M:
        return _FIX_SIGMA_M[fix.fix]
    return default_sigma_m


def unstarted_estimate(t: float, east_m: float, north_m: float, cov_m2: np.ndarray,
                       speed_mps: float | None, gps: GpsUsage | None) -> FusedEstimate:
    """Before start-up (and at the fix that makes the filter re-acquire), while the heading
    is unknown: where the fixes put the car, with their covariance (all of it GPS error), a
    speed when one is measured, and no heading (NaN: the wire sends null). Without it a car
    standing when the fixes came back after a gap had no position for the rest of the drive
    (Monaco 516 of the tune split: 250 s), and a client had none until the car moved."""
    return FusedEstimate(t=t, x_m=east_m, y_m=north_m, heading_rad=math.nan,
                         speed_mps=math.nan if speed_mps is None else speed_mps,
                         yaw_rate_rps=math.nan, position_cov_m2=cov_m2,
                         heading_sigma_rad=math.inf, initialized=False, gps=gps,
                         gps_bias_var_m2=float(np.trace(cov_m2)) / 2.0)


class RoadDistance(Protocol):
    """How far a position is from the nearest road along a heading (the map's fit,
    :meth:`roadgraph.RoadGraph.distance_to_road_m`), for the filters to ask the map."""

    def __call__(self, x_m: float, y_m: float, heading_rad: float, radius_m: float,
                 max_bearing_diff_rad: float) -> float: ...


def nearest_road_var_m2(road_distance: RoadDistance | None, x_m: float, y_m: float,
                        radius_m: float) -> float:
    """The square of the distance from a position to the nearest road, whatever its
    bearing (at most ``radius_m``; zero without a map): the car is on a road, so an
    estimate that far from every road is at least that far off. Before start-up the fixes
    alone give the position, with a sigma that leaves out their slowly changing error
    (the offset of a standstill's fixes does not average away); as a floor under that
    variance, on the tune split (600 drives, gyro + odometer, ekf; estimates unchanged)
    the 2.45-sigma circle held 90.8 % of the errors in the first 10 s against 81.4 %,
    90.5 % of the next 20 s against 87.0 % (all epochs 94.1 against 93.3 %)."""
    if road_distance is None:
        return 0.0
    return road_distance(x_m, y_m, 0.0, radius_m, math.pi / 2.0) ** 2


@dataclass(frozen=True)
class JumpMapTest:
    """A refused jump tested against the map: two tracks, the estimate's and the estimate
    moved by the jumped fixes' mean innovation, each fitted to the roads along the heading
    (any road while the car crawls or corners). A start inside a non-line-of-sight run
    settles on fixes off the roads; when the true fixes return, they are the "jump"."""

    fixes: int = 0
    sum_east_m: float = 0.0  # of the jumped fixes' innovations
    sum_north_m: float = 0.0
    track_sq_m2: float = 0.0  # sums of the squared road distances of the two tracks
    jump_sq_m2: float = 0.0

    def updated(self, innovation_en_m: tuple[float, float], x_m: float, y_m: float,
                heading_rad: float, speed_mps: float, turn_rate_rps: float,
                road_distance: RoadDistance, config: FusionConfig) -> JumpMapTest:
        """With one more jumped fix, its innovation (east, north), the estimate at
        ``x_m``, ``y_m`` moving at that heading, speed and turn rate."""
        along_a_road = speed_mps >= CRAWL_MPS and abs(turn_rate_rps) <= CORNERING_RPS
        args = (heading_rad, config.road_fit_radius_m,
                config.road_fit_max_bearing_rad if along_a_road else math.pi)
        n = self.fixes + 1
        sum_e, sum_n = self.sum_east_m + innovation_en_m[0], self.sum_north_m + innovation_en_m[1]
        return JumpMapTest(n, sum_e, sum_n,
                           self.track_sq_m2 + road_distance(x_m, y_m, *args) ** 2,
                           self.jump_sq_m2 + road_distance(x_m + sum_e / n, y_m + sum_n / n,
                                                           *args) ** 2)

    def mean_innovation_en_m(self) -> tuple[float, float]:
        return self.sum_east_m / self.fixes, self.sum_north_m / self.fixes

    def prefers_jump(self, age_s: float, config: FusionConfig) -> bool:
        """After ``jump_map_after_s`` (3 fixes at least): the estimate's track lies
        ``jump_map_track_off_m`` (rms) from the roads and ``jump_map_ratio`` times farther
        than the jumped one."""
        if self.fixes < 3 or age_s < config.jump_map_after_s:
            return False
        track_rms = math.sqrt(self.track_sq_m2 / self.fixes)
        jump_rms = math.sqrt(self.jump_sq_m2 / self.fixes)
        return track_rms >= config.jump_map_track_off_m and \
            track_rms >= config.jump_map_ratio * jump_rms


@dataclass(frozen=True)
class MapSeenError:
    """The fixes' error as the map sees it. Their slowly changing error moves the estimate
    with them, so their NIS does not see it; the map does: a fix's distance from the road
    the car drives along is its error across that road. This is the running mean square of
    that distance over ``memory_s``, winsorised at 3 rms (a non-line-of-sight run is the
    jump test's business, not an error level)."""

    learnt_s: float = 0.0  # seconds of driving learnt (at most the memory)
    mean_sq_m2: float = 0.0

    def updated(self, distance_m: float, dt_s: float, memory_s: float) -> MapSeenError:
        """With one more fix, ``dt_s`` after the previous one."""
        learnt_s = min(self.learnt_s + dt_s, memory_s)
        if learnt_s <= 0.0:
            return self
        d = distance_m if self.learnt_s <= 0.0 else \
            min(distance_m, 3.0 * math.sqrt(max(self.mean_sq_m2, 1.0)))
        weight = dt_s / learnt_s  # first: a denormal dt times d^2 rounds past d^2
        return MapSeenError(learnt_s, self.mean_sq_m2 + (d * d - self.mean_sq_m2) * weight)

    def variance_ratio(self, sigma_m: float, memory_s: float, max_sigma_m: float,
                       min_ratio: float) -> float:
        """The fixes' error variance as the map sees it over the variance of ``sigma_m``
        (its mean square at most ``max_sigma_m`` squared), at least ``min_ratio``; taken
        from 1 toward it as the evidence comes (:meth:`learnt_share`)."""
        if sigma_m <= 0.0:
            return 1.0
        seen = max(min(self.mean_sq_m2, max_sigma_m ** 2) / sigma_m ** 2, min_ratio)
        return 1.0 + self.learnt_share(memory_s) * (seen - 1.0)

    def unseen_var_m2(self, sigma_m: float, memory_s: float, max_sigma_m: float) -> float:
        """How much more variance the fixes' error has (at most ``max_sigma_m`` squared)
        than the sigma a filter weighs them by; zero until learnt over half the memory.

        Not counted as it comes, as :meth:`variance_ratio` is: the filters that add this in
        full (the weighted modes, GPS alone, the INS) then held 98.4-99.6 % of the errors in
        the 2.45-sigma circle on the median drive (tune split, 60 drives each)."""
        if self.learnt_s < memory_s / 2.0:
            return 0.0
        return max(min(self.mean_sq_m2, max_sigma_m ** 2) - sigma_m ** 2, 0.0)

    def learnt_share(self, memory_s: float) -> float:
        """How much of the map's judgement the ratio takes: the seconds learnt over half the
        memory, at most all of it. With none of it before half the memory, the first 30 s
        after start-up, when a fix's own sigma leaves out most of its error, held 80.6 % of
        the errors in the 2.45-sigma circle for the first 10 s and 86.3 % for the next 20 s
        (gyro and odometer, ekf; tune split, 600 harsh drives; all the epochs 93.6 %).
        Counted as it comes: 83.5 % and 88.5 % (all 94.2 %), fused RMS -0.3 % (13 drives
        better by more than 5 %, 3 worse: the map feedback's gate reads the sigma), one
        drive fewer more than 50 m off with GPS; the median drive 97.9 -> 98.2 %. Over the
        whole memory instead of half: 82.3 and 88.7 %, -0.2 %, the median drive 98.3 %."""
        return min(self.learnt_s / (memory_s / 2.0), 1.0)


@dataclass(frozen=True)
class TrackFit:
    """A heading fitted to fixes along a straight line an odometer drove."""

    heading_rad: float  # clockwise from north
    variance_rad2: float
    agrees: bool  # the fixes lie where the odometer's distances put them, within their error
    distance_ratio: float = 1.0  # metres the fixes moved along the line per odometer metre


def fit_track(fixes: tuple[tuple[float, float, float, float], ...],
              sigma_m: float) -> TrackFit:
    """Weighted least-squares fit of fixes ``(t, east, north, distance driven)`` to
    ``p0 + d u``: a start, and the unit direction ``u`` the car drove along (distances
    known, from the odometer). ``u`` is the normalised sum of ``w (d - mean d)(p - mean
    p)``; its variance ``sigma^2 / sum w (d - mean d)^2``. A fix weighs the mean of the
    times to its neighbours, each a second at most: fixes faster than one a second are not
    independent (their errors are one slowly changing error), and a cluster of them before
    a gap counts as about one fix. The fixes agree with the line when each lies within
    ``3 sigma`` (plus a tenth of its distance: the odometer's scale) of where the fit puts
    it, and the fitted distance per odometer metre is one within 3 of its sigmas and a
    tenth. Fixes that do not yet span any distance say nothing: an infinite variance."""
    unknown = TrackFit(0.0, math.inf, True)
    if len(fixes) < 2:
        return unknown
    t = np.array([f[0] for f in fixes])
    p = np.array([(f[1], f[2]) for f in fixes])
    d = np.array([f[3] for f in fixes])
    gaps = np.minimum(np.diff(t), 1.0)
    w = (np.append(gaps[:1], gaps) + np.append(gaps, gaps[-1:])) / 2.0
    e = d - (w @ d) / w.sum()
    q = p - (w @ p) / w.sum()
    spread_m2 = float(w @ e ** 2)
    if spread_m2 <= 0.0:
        return unknown
    g = (w * e) @ q
    slope = math.hypot(float(g[0]), float(g[1])) / spread_m2  # fitted metres per odometer one
    if slope == 0.0:
        return unknown
    u = g / (slope * spread_m2)
    misfit_m = np.hypot(*(q - np.outer(e, u)).T)
    variance = sigma_m ** 2 / spread_m2
    agrees = bool(np.all(misfit_m <= 3.0 * sigma_m + 0.1 * np.abs(e))) and \
        abs(slope - 1.0) <= 3.0 * math.sqrt(variance) + 0.1
    return TrackFit(math.atan2(float(u[0]), float(u[1])) % (2.0 * math.pi), variance, agrees,
                    slope)


def baseline_heading(fit: TrackFit | None, ends: tuple[float, float, float, float],
                     travelled_m: float, spread_m: float, min_move_m: float,
                     min_move_sigmas: float, max_distance_misfit: float = math.inf
                     ) -> tuple[float, float] | None:
    """A start-up heading (clockwise from north) and its variance from a baseline of fixes,
    once it is ``min_move_m`` and ``min_move_sigmas`` of the fixes' spread long: with an
    odometer, the fit (:func:`fit_track`), once the odometer drove that far (the fixes' own
    distance is no baseline: a fix 22 m off after a few metres driven made one, and the
    heading started with a sigma of 600 degrees) and while the fixes moved along the line
    within ``max_distance_misfit`` (a share) of the distance it drove: a non-line-of-sight
    ramp swept urban fixes across the drive, 8 m along it in 21 m driven, and the heading
    started 126 degrees off, which the fit's own test (3 of its sigmas, 0.3 at that
    baseline) let through (gh-issue-70 168 of the tune split). Without an odometer, the
    bearing between the baseline's ends ``(east, north, east, north)``, once they lie that
    far apart. None before. Both filters start so."""
    need_m = max(min_move_m, min_move_sigmas * spread_m)
    if fit is not None:
        if travelled_m < need_m or abs(fit.distance_ratio - 1.0) > max_distance_misfit or \
                not math.isfinite(fit.variance_rad2):  # the odometer drove, the fixes did
            return None  # not span it (a jump of its ticks): the heading started with an
            # infinite variance, and every number of the state went NaN (the WebSocket fuzzer)
        return fit.heading_rad, fit.variance_rad2
    moved_m = math.hypot(ends[2] - ends[0], ends[3] - ends[1])
    return (bearing_rad(*ends), (spread_m / moved_m) ** 2) if moved_m >= need_m else None


@dataclass(frozen=True)
class PathTurn:
    """How far the fixes' path is turned from the estimate's over the same seconds."""

    angle_rad: float  # the fixes' path is the estimate's turned clockwise by this much
    variance_rad2: float
    misfit_m: float  # rms distance of the fixes from the turned path
    shift_misfit_m: float  # ... and from the path only shifted


def turn_between_paths(estimate_m: np.ndarray, fixes_m: np.ndarray,
                       sigma_m: float) -> PathTurn:
    """The rotation (and shift) that best lays the estimate's positions ``(n, 2)`` (east,
    north) onto the fixes taken at the same times: a 2-D Procrustes fit about their
    centroids. A heading error turns the dead-reckoned path about where it began, so the
    angle is that error; a non-line-of-sight offset shifts the fixes' path without turning
    it. The angle's variance is ``sigma^2`` over the estimate path's spread about its
    centroid; infinite before the path spans any distance."""
    def rms(d: np.ndarray) -> float:
        return math.sqrt(float(np.mean(np.sum(d * d, axis=1))))

    a = estimate_m - estimate_m.mean(axis=0)
    b = fixes_m - fixes_m.mean(axis=0)
    spread_m2 = float(np.sum(a * a))
    if spread_m2 <= 0.0:
        return PathTurn(0.0, math.inf, math.inf, rms(b - a))
    dot = float(np.sum(a * b))
    cross = float(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]))  # counter-clockwise
    angle = math.atan2(cross, dot)
    c, s = math.cos(angle), math.sin(angle)
    turned = np.column_stack([c * a[:, 0] - s * a[:, 1], s * a[:, 0] + c * a[:, 1]])
    return PathTurn(-angle, sigma_m ** 2 / spread_m2, rms(b - turned), rms(b - a))


def disagreement_cov_m2(disagreement: tuple[float, float, float] | None, t: float,
                        tau_s: float, sigmas: float) -> np.ndarray:
    """What the latest fix past a filter's gate, ``(t, east, north)`` of its innovation
    ``y``, says of the estimate: that it may be off by ``y``. Reported as
    ``y y^T / sigmas^2`` (``1 / sigmas`` of it as a sigma along it), fading with the GPS
    error's time constant ``tau_s``; the filter's own covariance is left alone (it decided,
    refusing or following the fix, and a wrong decision is what no Kalman covariance
    holds)."""
    if disagreement is None:
        return np.zeros((2, 2))
    t_d, east, north = disagreement
    y = np.array([east, north])
    return np.outer(y, y) / sigmas ** 2 * math.exp(-max(t - t_d, 0.0) / tau_s)
