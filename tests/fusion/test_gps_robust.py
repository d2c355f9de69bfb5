"""Robust GPS handling of the road filter on a straight drive with known truth (issue 15):
a jump away from a settled track is refused, a followed jump that comes back is left at once,
and the gyro bias is known from the standstill before the drive."""

import math
from dataclasses import replace

import numpy as np
import pytest

import navsvc.fusion.road.filter as filter_module
from navsvc.fusion import FusionConfig, GpsMode, SensorConfig
from navsvc.fusion.gnss import JumpMapTest, RoadDistance
from navsvc.fusion.road.filter import RoadFilter
from navsvc.fusion.road.measurements import RoadConstraint
from navsvc.fusion.road.motion import (
    GPS_BIAS_E,
    GPS_BIAS_N,
    GPS_LATENCY,
    GYRO_BIAS,
    HEADING,
    HEADING_RATE,
    ODO_SCALE,
    SPEED,
    X_M,
    Y_M,
)
from navsvc.types import (
    FusedEstimate,
    GpsFix,
    ImuSample,
    OdometerSample,
    Packet,
    SteeringSample,
)
from roadgraph import LocalFrame

FRAME = LocalFrame.for_point(7.42, 43.73)
SPEED_MPS = 10.0
STILL_S = 10.0
GYRO_BIAS_RPS = math.radians(0.5)


def _north_m(t: float) -> float:
    return max(t - STILL_S, 0.0) * SPEED_MPS


def _drive(duration_s: float, jumps: list[tuple[float, float, float]],
           seed: int = 1, accuracy_m: float = 1.0, fix_rate_hz: int = 1,
           noise_m: float | None = None) -> list[Packet]:
    """Stand still, then drive north at 10 m/s: gyro 100 Hz with a bias, odometer speed at
    10 Hz, a fix a second (reporting ``accuracy_m``, with ``noise_m`` of noise new at each
    fix, by default the same; no course); ``jumps`` adds (start, end, east offset)."""
    rng = np.random.default_rng(seed)
    packets: list[Packet] = []
    for k in range(int(duration_s * 100)):
        t = k / 100.0
        packets.append(ImuSample(t, yaw_rate_rps=GYRO_BIAS_RPS + rng.normal(0.0, 0.002)))
        if k % 10 == 0:
            packets.append(OdometerSample(t, speed_mps=SPEED_MPS if t > STILL_S else 0.0))
        if k % (100 // fix_rate_hz) == 0:
            east = sum(offset for start, end, offset in jumps if start <= t < end)
            noise = accuracy_m if noise_m is None else noise_m
            lon, lat = FRAME.to_wgs84(east + rng.normal(0.0, noise),
                                      _north_m(t) + rng.normal(0.0, noise))
            packets.append(GpsFix(t, lat_deg=lat, lon_deg=lon, accuracy_m=accuracy_m))
    return packets


def _north_road(east_m: float) -> RoadDistance:
    """A map of one road, north-south through ``east_m``."""
    def distance(x_m: float, y_m: float, heading_rad: float, radius_m: float,
                 max_bearing_diff_rad: float) -> float:
        along = abs(math.remainder(heading_rad, math.pi)) <= max_bearing_diff_rad
        return min(abs(x_m - east_m), radius_m) if along else radius_m
    return distance


_north_road_distance = _north_road(0.0)  # the map of the drive


def _run(packets: list[Packet], road_distance: RoadDistance | None = None,
         config: FusionConfig | None = None
         ) -> tuple[RoadFilter, list[tuple[float, float, str]]]:
    """The filter after the drive, and (t, error m, GPS reason) at every fix once it
    started (before, the fix itself stands as the position: :func:`_unstarted`)."""
    road = RoadFilter(config or FusionConfig(), FRAME, road_distance)
    out = []
    for p in packets:
        for e in road.apply(p):
            if isinstance(p, GpsFix) and e.gps is not None and not _unstarted(e):
                out.append((p.t, math.hypot(e.x_m, e.y_m - _north_m(p.t)), e.gps.reason))
    return road, out


def _unstarted(e: FusedEstimate) -> bool:
    """An estimate from before start-up (not the one at the fix that re-acquires): the
    fixes, no heading."""
    return not e.initialized and math.isinf(e.heading_sigma_rad) and \
        e.gps is not None and e.gps.reason.startswith("initialising")


def _first_estimate(road: RoadFilter, packets: list[Packet]) -> FusedEstimate:
    """The filter's first estimate once started, after all ``packets`` are applied."""
    start = None
    for p in packets:
        for e in road.apply(p):
            if start is None and e.initialized:
                start = e
    assert start is not None, "the filter never started"
    return start


def test_standstill_gives_the_gyro_bias_at_start_up() -> None:
    road, _ = _run(_drive(STILL_S + 5.0, []))  # just after start-up
    assert road.state.initialized
    assert abs(road.state.x[GYRO_BIAS] - GYRO_BIAS_RPS) < math.radians(0.02)


def test_a_start_up_heading_with_an_infinite_variance_starts_nothing(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Whatever gives it (a jump of the odometer's ticks beside fixes that did not move
    gave one, and every number of the state went NaN), a start that is not finite is no
    start: the filter waits, and emits no start (only the fixes as they come)."""
    monkeypatch.setattr(filter_module, "baseline_heading", lambda *_: (0.0, math.inf))
    road, estimates = RoadFilter(FusionConfig(), FRAME), []
    for p in _drive(STILL_S + 20.0, []):
        estimates += road.apply(p)
    assert not road.state.initialized and all(_unstarted(e) for e in estimates)
    assert road.state.gps is not None and "not finite" in road.state.gps.reason


def test_a_jump_away_from_a_settled_track_is_refused_not_followed() -> None:
    _, fixes = _run(_drive(120.0, [(60.0, 90.0, 50.0)]))
    during = [f for f in fixes if 60.0 <= f[0] < 90.0]
    assert all(err < 10.0 for _, err, _ in during), during  # dead reckoning, not 50 m
    assert all(reason.startswith("refused: jumped") for _, _, reason in during)
    after = [f for f in fixes if f[0] >= 91.0]
    assert all(err < 3.0 for _, err, _ in after), after
    used = [reason in ("accepted", "down-weighted") for _, _, reason in after]
    assert used[:5] == [True] * 5 and sum(used) >= 0.9 * len(used), after


def _sigmas_through_a_jump(config: FusionConfig, duration_s: float
                           ) -> dict[float, tuple[float, float]]:
    """At each fix of a drive whose fixes jump 50 m east from 60 to 90 s: the reported
    position sigma and the filter's own (from its covariance)."""
    road = RoadFilter(config, FRAME)
    sigmas = {}
    for p in _drive(duration_s, [(60.0, 90.0, 50.0)]):
        for e in road.apply(p):
            if isinstance(p, GpsFix):
                own = math.sqrt((road.state.P[0, 0] + road.state.P[1, 1]) / 2.0)
                sigmas[p.t] = (e.position_sigma_m, own)
    return sigmas


def test_fixes_refused_far_off_widen_the_reported_sigma_not_the_filters() -> None:
    """A 50 m jump refused for 30 s: the estimate may be the one that is wrong, so its
    reported sigma holds a third of the jump along it, fading after the fixes come back;
    the filter's own covariance (what it weighs the next fix by) does not take it."""
    reported = _sigmas_through_a_jump(FusionConfig(), 200.0)
    before, first_refused, last_refused, late = (reported[t] for t in (59.0, 60.0, 89.0, 199.0))
    assert before[0] < 3.0 and first_refused[1] < 3.0
    assert first_refused[0] >= 50.0 / 3.0 / math.sqrt(2.0)  # along the jump, mean of two axes
    assert last_refused[0] > 10.0 and last_refused[1] < 10.0
    assert late[0] < 0.5 * last_refused[0] and late[0] < 2.0 * late[1]


@pytest.mark.parametrize(("config", "share"), [
    (FusionConfig(gps_mode=GpsMode.RULES), 1.0 / 2.0),
    (FusionConfig(gps_mode=GpsMode.FUZZY), 1.0),
    (FusionConfig(sensors=SensorConfig.GPS_ONLY), 1.0)])
def test_filters_that_follow_such_fixes_report_more_of_the_jump_as_a_doubt(
        config: FusionConfig, share: float) -> None:
    """The weighted modes follow a fix past the gate slowly (the fuzzy sets even one past
    the rules' 50 m), GPS alone follows it: a wrong decision leaves more of the jump in the
    estimate than with dead reckoning (a third), and the reported sigma holds half of it,
    or all of it."""
    reported = _sigmas_through_a_jump(config, 61.0)
    assert reported[59.0][0] < 3.0
    assert reported[60.0][0] >= share * 50.0 / math.sqrt(2.0) > 3.0 * reported[60.0][1]


@pytest.mark.parametrize("turn_deg", [45.0, 120.0, 180.0])
def test_a_heading_gone_wrong_is_left_once_the_fixes_path_shows_it(turn_deg: float) -> None:
    """The estimate's heading turned by ``turn_deg`` at 60 s, as a start-up on urban fixes
    or a long outage can leave it: the fixes run away from the track and were refused as
    a jump for a minute and more. Their path is the dead-reckoned one turned, which a
    non-line-of-sight run's is not: the heading is turned back and the estimate is on the
    fixes (within twice their sigma) ten fixes later."""
    road = RoadFilter(FusionConfig(), FRAME)
    fixes = []
    for p in _drive(100.0, [], accuracy_m=2.0):
        if p.t == 60.0 and isinstance(p, ImuSample):
            road.state.x[HEADING] += math.radians(turn_deg)
        for e in road.apply(p):
            if isinstance(p, GpsFix) and e.gps is not None:
                fixes.append((p.t, math.hypot(e.x_m, e.y_m - _north_m(p.t)), e.gps.reason))
    assert any("path is turned" in reason for t, _, reason in fixes if 60.0 < t <= 70.0)
    after = [(t, err) for t, err, _ in fixes if t > 70.0]
    assert all(err < 4.0 for _, err in after), after
    assert abs(math.remainder(road.state.x[HEADING], 2.0 * math.pi)) < math.radians(3.0)


def test_with_the_map_a_jump_off_the_roads_is_still_refused() -> None:
    _, fixes = _run(_drive(120.0, [(60.0, 90.0, 50.0)]), _north_road_distance)
    during = [f for f in fixes if 60.0 <= f[0] < 90.0]
    assert all(err < 10.0 and reason.startswith("refused: jumped")
               for _, err, reason in during), during


def test_a_start_inside_a_non_line_of_sight_run_is_left_when_the_map_says_so() -> None:
    """The drive starts with its fixes 50 m off the road and the filter settles on them;
    when the true fixes come back, they are a "jump" from the settled track. Without a map it
    is refused for a minute; with one, the estimate's distance from the road is a lower bound
    of its error, its variance widens to it, and the true fixes are taken within 5 fixes."""
    packets = _drive(120.0, [(0.0, 40.0, 50.0)])
    _, blind = _run(packets)
    assert all(reason.startswith("refused: jumped") for t, _, reason in blind
               if 41.0 <= t < 60.0)
    _, fixes = _run(packets, _north_road_distance)
    assert all(err > 40.0 for t, err, _ in fixes if 20.0 <= t < 40.0)
    back = [f for f in fixes if f[0] >= 40.0]
    taken = next(i for i, f in enumerate(back) if not f[2].startswith("refused"))
    assert taken <= 5
    assert all(err < 5.0 for _, err, _ in back[taken:]), back


@pytest.mark.parametrize("mode", [GpsMode.RULES, GpsMode.FUZZY])
def test_weighted_modes_leave_a_start_inside_a_non_line_of_sight_run_when_the_map_says_so(
        mode: GpsMode) -> None:
    """As in ``ekf``: the drive starts with its fixes 70 m off the road (farther than the
    rules' and fuzzy sets' distance), and the estimate follows them. Without a map the true
    fixes are refused for a minute (a leap away from a close track: a non-line-of-sight
    run's start); with one, the estimate settled off the roads widens its variance, which
    then covers the true fixes: taken at once, and the course is not drawn across the leap
    (it turned the heading, 15 m off 8 s later)."""
    packets = _drive(120.0, [(0.0, 40.0, 70.0)])
    config = FusionConfig(gps_mode=mode)
    _, blind = _run(packets, config=config)
    assert all(err > 60.0 for t, err, _ in blind if 40.0 <= t < 90.0)
    _, fixes = _run(packets, _north_road_distance, config)
    assert all(err > 60.0 for t, err, _ in fixes if 20.0 <= t < 40.0)
    back = [f for f in fixes if f[0] >= 40.0]
    assert back[0][2].startswith("re-acquired")
    assert all(err < 3.0 for _, err, _ in back), back


def _starts_between_and_leaves_the_run_at_its_end(start_s: float, end_s: float) -> float:
    """Fixes (3 m) 50 m east from ``start_s`` to ``end_s``: the filter starts between the
    two tracks, ``leap_onset_share`` of the way back to the one before the leap (most leaps
    start a run), with a variance along the leap that holds the run's track within 2.45
    sigma; it stays there while the run lasts, and follows the fixes' leap back at the
    second fix that says so (within twice their sigma after it). The start's time."""
    road = RoadFilter(FusionConfig(), FRAME)
    start: list[tuple[float, float, float]] = []  # (t, east, sigma east) at the first fix
    fixes = []  # (t, east, error, GPS reason)
    for p in _drive(120.0, [(start_s, end_s, 50.0)], accuracy_m=3.0):
        for e in road.apply(p):
            if isinstance(p, GpsFix) and e.gps is not None and not _unstarted(e):
                if not start:
                    start.append((p.t, e.x_m, math.sqrt(road.state.P[0, 0])))
                fixes.append((p.t, e.x_m, math.hypot(e.x_m, e.y_m - _north_m(p.t)),
                              e.gps.reason))
    t0, east_m, sigma_east_m = start[0]
    between_m = (1.0 - FusionConfig().leap_onset_share) * 50.0
    assert abs(east_m - between_m) < 6.0 and 2.45 * sigma_east_m >= 50.0 - east_m
    assert all(0.0 < east < between_m + 8.0 for t, east, _, _ in fixes if t < end_s)
    back = [f for f in fixes if f[0] >= end_s]
    assert back[0][3] != back[1][3] == "re-acquired: the fixes jumped back"  # two agree
    assert all(err < 2.0 * 3.0 for _, _, err, _ in back[1:]), back
    return t0


def test_a_non_line_of_sight_run_begun_at_the_standstill_is_left_when_it_ends() -> None:
    """The fixes leap 50 m east while the car still stands (5 s in) and leap back 35 s
    later: no map says which side is right, so the filter starts between them, with a
    sigma that holds either side, stays there (the GPS bias states hold the leap, not
    decaying to the fixes), and follows their leap back once two fixes say so (the leap at
    a standstill was a change of their error)."""
    _starts_between_and_leaves_the_run_at_its_end(5.0, 40.0)


def test_a_non_line_of_sight_run_begun_before_start_up_while_moving_is_left_when_it_ends(
) -> None:
    """The car drives off; before the heading's baseline is long enough the fixes leap 50 m
    east (farther than the odometer drove since the fix before) and leap back 40 s later:
    as with a leap at a standstill, the filter starts between the tracks, stays there, and
    follows the leap back. It had started on the leapt fixes, 50 m off (Andorra 257 of the
    tune split: 67 m)."""
    assert _starts_between_and_leaves_the_run_at_its_end(STILL_S + 1.5, 52.0) > STILL_S + 1.5


def test_a_leap_that_ended_in_steps_before_start_up_leaves_nothing_behind() -> None:
    """The fixes leap 40 m south (behind the car) while it stands, and come back as it
    drives off north, 20 m a second, in steps no single one of which undoes the leap; the
    receiver's course starts the filter at the next fix. That fix lies as far from the
    fixes before the leap as the odometer drove, and 40 m farther from the leapt ones: the
    filter starts on it, not between the two tracks 34 m off (gh-issue-13 129 of the tune
    split)."""
    def south_m(t: float) -> float:
        if 5.0 <= t < STILL_S + 1.0:
            return 40.0
        return 20.0 if STILL_S + 1.0 <= t < STILL_S + 2.0 else 0.0

    packets: list[Packet] = []
    for p in _drive(30.0, [], accuracy_m=3.0):
        if isinstance(p, GpsFix):
            east, north = FRAME.to_local(p.lon_deg, p.lat_deg)
            lon, lat = FRAME.to_wgs84(east, north - south_m(p.t))
            course = {"speed_mps": SPEED_MPS, "heading_rad": 0.0} if p.t >= STILL_S + 2.0 else {}
            p = replace(p, lat_deg=lat, lon_deg=lon, **course)
        packets.append(p)
    _, fixes = _run(packets)
    assert fixes[0][2] == "initialised from GPS" and fixes[0][0] <= STILL_S + 4.0
    assert all(err < 2.0 * 3.0 for _, err, _ in fixes), fixes


def test_a_held_run_that_ends_slowly_goes_into_the_bias_states_not_refused() -> None:
    """The fixes leap 50 m east at the standstill and, from 40 s, come back 2.5 m a second;
    map feedback holds the car on its road (east 0), so the bias states hold the run's
    offset. The bias states wander while they hold it: the fixes coming back are taken as
    the bias doing so, not refused as a jump for ten seconds while the position stays on
    the road (gh-issue-13 399 of the tune split)."""
    jumps = [(5.0, 40.0, 50.0)] + [(40.0 + k, 41.0 + k, 50.0 - 2.5 * (k + 1))
                                   for k in range(20)]
    road = RoadFilter(FusionConfig(), FRAME)
    returning = []  # (east m, bias east m, GPS reason) while the fixes come back
    for p in _drive(80.0, jumps, accuracy_m=3.0):
        for e in road.apply(p):
            if isinstance(p, GpsFix) and e.gps is not None and 40.0 <= p.t <= 60.0:
                returning.append((e.x_m, road.state.x[GPS_BIAS_E], e.gps.reason))
        if isinstance(p, GpsFix) and road.state.initialized and p.t > STILL_S + 2.0:
            road.correct(RoadConstraint(0.0, road.state.x[1], 0.0, 2.0, math.radians(5.0)))
    assert sum(reason.startswith("refused") for _, _, reason in returning) <= 3, returning
    assert all(abs(east) < 5.0 for east, _, _ in returning), returning
    assert abs(returning[-1][1]) < 2.0 * 3.0, returning  # the bias followed the fixes back


def test_start_up_waits_out_a_fix_that_leapt_from_the_one_before() -> None:
    """The first fix once moving lies 40 m east of the track, with the receiver's course:
    the filter does not start on it (the odometer drove 10 m since the fix before) but once
    two fixes agree with the odometer, within their error."""
    packets = [replace(p, heading_rad=0.0, speed_mps=SPEED_MPS)
               if isinstance(p, GpsFix) and p.t > STILL_S else p
               for p in _drive(30.0, [(STILL_S + 0.5, STILL_S + 1.5, 40.0)])]
    _, fixes = _run(packets)
    assert fixes[0][2] == "initialised from GPS" and fixes[0][0] > STILL_S + 1.5
    assert all(err < 5.0 for _, err, _ in fixes), fixes


def test_without_an_odometer_a_leap_at_the_standstill_is_no_start_up_heading() -> None:
    """GPS alone: the fixes leap 40 m east while the car stands, then it drives north. The
    leap lies off the line of the fixes before it (no car accelerates like that), so the
    heading's baseline starts again after it, and start-up comes once the car moves, facing
    north (the leap made a heading east and a speed of 40 m/s)."""
    packets = [p for p in _drive(40.0, [(STILL_S - 4.0, 40.0, 40.0)])
               if isinstance(p, GpsFix)]
    road = RoadFilter(FusionConfig(sensors=SensorConfig.GPS_ONLY), FRAME)
    start = None
    for p in packets:
        for e in road.apply(p):
            if start is None and e.initialized:
                start = e
    assert start is not None and start.t > STILL_S
    assert abs(math.remainder(start.heading_rad, 2.0 * math.pi)) < math.radians(20.0)
    assert start.speed_mps < 2.0 * SPEED_MPS


def _unstarted_estimates(packets: list[Packet]) -> list[tuple[GpsFix, FusedEstimate]]:
    road = RoadFilter(FusionConfig(), FRAME)
    return [(p, e) for p in packets for e in road.apply(p) if _unstarted(e)]


def test_before_start_up_each_fix_gives_the_mean_where_the_car_stands() -> None:
    """Before the heading is known, every good fix gives an estimate: not started, no
    heading (NaN, infinite sigma), at the mean of the fixes since the car stopped, with
    the larger of their sigma and their scatter; a car that does not stand gets the fix."""
    out = _unstarted_estimates(_drive(STILL_S + 8.0, [], noise_m=4.0, accuracy_m=2.0))
    standing = [(p, e) for p, e in out if p.t <= STILL_S]
    assert len(standing) == int(STILL_S) + 1  # each fix of the standstill
    assert all(math.isnan(e.heading_rad) and not e.initialized for _, e in out)
    assert all(e.speed_mps == 0.0 for _, e in standing)
    errors = [math.hypot(e.x_m, e.y_m) for _, e in standing[3:]]
    fix_errors = [math.hypot(*FRAME.to_local(p.lon_deg, p.lat_deg)) for p, _ in standing[3:]]
    assert np.mean(errors) < 0.6 * np.mean(fix_errors)  # the mean of 4-11 fixes
    assert standing[0][1].position_sigma_m == pytest.approx(2.0)  # one fix: its own
    assert all(2.0 < e.position_sigma_m < 7.0 for _, e in standing[3:])  # their scatter
    moving = [(p, e) for p, e in out if p.t > STILL_S]
    for p, e in moving:
        assert (e.x_m, e.y_m) == pytest.approx(FRAME.to_local(p.lon_deg, p.lat_deg))
        assert e.speed_mps == pytest.approx(SPEED_MPS)


def test_before_start_up_a_leap_at_the_standstill_is_where_the_start_would_put_it() -> None:
    """Fixes that leap 50 m east while the car stands: the estimate before start-up sits
    where the start would (``leap_onset_share`` of the way back), with the two tracks'
    spread, not on the leapt fixes."""
    out = _unstarted_estimates(_drive(STILL_S, [(5.0, 20.0, 50.0)]))
    leapt = [e for p, e in out if p.t >= 8.0]
    between_m = (1.0 - FusionConfig().leap_onset_share) * 50.0
    assert leapt and all(abs(e.x_m - between_m) < 3.0 for e in leapt)
    assert all(2.45 * math.sqrt(e.position_cov_m2[0, 0]) >= 50.0 - e.x_m for e in leapt)


def test_before_start_up_the_sigma_reaches_the_nearest_road() -> None:
    """Fixes of a sigma of 1 m that agree with each other, 12 m east of the road the car
    stands on: no fix sees that error, the map does (the car is on a road, so the
    estimate is at least as far off as the nearest one): with a map the 2.45-sigma
    circle holds the error, without one it does not."""
    def standing(road_distance: RoadDistance | None) -> list[FusedEstimate]:
        road = RoadFilter(FusionConfig(), FRAME, road_distance)
        return [e for p in _drive(STILL_S, [(0.0, STILL_S, 12.0)]) for e in road.apply(p)
                if _unstarted(e)]

    blind, seen = standing(None), standing(_north_road_distance)
    assert len(seen) == len(blind) == int(STILL_S)  # a fix a second
    assert all(math.hypot(e.x_m, e.y_m) > 2.45 * e.position_sigma_m for e in blind)
    assert all(10.0 < math.hypot(e.x_m, e.y_m) <= 2.45 * e.position_sigma_m for e in seen)


def test_a_leap_at_the_standstill_that_comes_back_leaves_nothing_behind() -> None:
    """A multipath burst within the standstill: the filter starts on the fixes, with no
    jump remembered."""
    road, fixes = _run(_drive(STILL_S + 5.0, [(4.0, 8.0, 50.0)]))
    assert road.state.initialized and road.state.followed_jump is None
    assert all(err < 3.0 for _, err, _ in fixes)


def test_the_map_makes_the_reported_sigma_hold_an_error_the_fixes_share() -> None:
    """Fixes 8 m east of the road all drive long, with a sigma of 1 m: their NIS cannot see
    an error the estimate shares, the road can, and the reported sigma takes it."""
    def sigmas(road_distance: RoadDistance | None) -> list[tuple[float, float]]:
        road = RoadFilter(FusionConfig(), FRAME, road_distance)
        out = []
        for p in _drive(120.0, [(0.0, 120.0, 8.0)]):
            for e in road.apply(p):
                if isinstance(p, GpsFix) and p.t >= 60.0:
                    out.append((math.hypot(e.x_m, e.y_m - _north_m(p.t)), e.position_sigma_m))
        return out

    blind, seen = sigmas(None), sigmas(_north_road_distance)
    assert all(err > 6.0 and err > 2.45 * sigma for err, sigma in blind)
    assert all(err <= 2.45 * sigma <= 2.45 * 12.0 for err, sigma in seen), seen


def test_fixes_back_from_an_outage_far_off_are_a_jump_when_dead_reckoning_is_sure() -> None:
    """Dead reckoning through a 20 s gap stays within metres; fixes that come back 50 m off
    it are refused as a jump (a non-line-of-sight run), and taken when they are right again."""
    packets = [p for p in _drive(120.0, [(60.0, 80.0, 50.0)])
               if not (isinstance(p, GpsFix) and 40.0 <= p.t < 60.0)]
    _, fixes = _run(packets)
    during = [f for f in fixes if 60.0 <= f[0] < 80.0]
    assert all(err < 10.0 and reason.startswith("refused: jumped")
               for _, err, reason in during), during
    assert all(err < 3.0 for t, err, _ in fixes if t >= 81.0)


def test_a_jump_two_fixes_after_an_outage_is_refused_as_from_the_track() -> None:
    """A 30 s outage, two good fixes, then 60 m east for 20 s: dead reckoning carried the
    track through the outage and the two fixes agreed with it, so the leap is a jump away
    from a settled track, refused, not followed as fixes after a gap would be."""
    packets = [p for p in _drive(120.0, [(72.0, 92.0, 60.0)])
               if not (isinstance(p, GpsFix) and 40.0 <= p.t < 70.0)]
    _, fixes = _run(packets)
    during = [f for f in fixes if 72.0 <= f[0] < 92.0]
    assert all(err < 5.0 for _, err, _ in during), during
    assert all(reason.startswith("refused: jumped") for _, _, reason in during)


@pytest.mark.parametrize("fix_rate_hz", [1, 10])
def test_a_leap_of_the_fixes_soon_after_start_up_is_refused_as_a_jump(fix_rate_hz: int
                                                                      ) -> None:
    """The filter starts at about 12 s; at 14 s, a track too young to be trusted over a
    jump, the fixes leap 40 m east for 20 s. One step from the fix before, which dead
    reckoning never makes: refused as a jump, not pulled at and followed."""
    _, fixes = _run(_drive(60.0, [(14.0, 34.0, 40.0)], fix_rate_hz=fix_rate_hz))
    during = [f for f in fixes if 14.0 <= f[0] < 34.0]
    assert all(err < 10.0 and reason.startswith("refused")
               for _, err, reason in during), during
    assert all(err < 3.0 for t, err, _ in fixes if t >= 35.0)


def test_a_track_drifting_from_precise_fixes_is_no_jump_of_theirs() -> None:
    """Fixes of 1 m lie 20 m east for a minute, then walk back in 2 m steps every 2 s: the
    filter follows them, and the walk turns its heading a few degrees west, so its track
    drifts from the fixes once they stop. Those fixes lie a few metres past the gate, many
    sigmas but no non-line-of-sight leap (20-80 m): taken, not refused for a minute while
    the track ran 95 m off."""
    walk = [(60.0 + 2.0 * k, 62.0 + 2.0 * k, 18.0 - 2.0 * k) for k in range(9)]
    _, fixes = _run(_drive(140.0, [(0.0, 60.0, 20.0), *walk]))
    after = [f for f in fixes if f[0] >= 80.0]
    assert not any(reason.startswith("refused: jumped") for _, _, reason in after), after
    assert max(err for _, err, _ in after) < 3.0


def test_a_gap_without_fixes_stops_the_clock_of_a_refused_jump() -> None:
    """The fixes leap 100 m east for 100 s, and 55 s of it have no fixes at all: when they
    come back the jump has been refused for 5 s of fixes, not 60 s, so they are still
    refused (not pulled at and followed, as a jump run out after ``max_jump_s``); when dead
    reckoning's grown variance lets the run through, its end is followed at once."""
    packets = [p for p in _drive(160.0, [(40.0, 140.0, 100.0)])
               if not (isinstance(p, GpsFix) and 45.0 <= p.t < 100.0)]
    _, fixes = _run(packets)
    back = [f for f in fixes if 100.0 <= f[0] < 110.0]
    assert back and all(err < 20.0 and reason.startswith("refused")
                        for _, err, reason in back), back
    assert all(err < 5.0 for t, err, _ in fixes if t >= 141.0)


def test_one_good_fix_between_refused_jumps_confirms_the_dead_reckoned_track() -> None:
    """After a 20 s outage the fixes come back 50 m off (refused as a jump), then one fix
    agrees with dead reckoning, then they leap 50 m off again: that fix confirmed the track
    carried through the outage, so the second leap is refused too, not followed as fixes
    on a track begun again at that one fix would be."""
    packets = [p for p in _drive(130.0, [(60.0, 80.0, 50.0), (81.0, 100.0, 50.0)])
               if not (isinstance(p, GpsFix) and 40.0 <= p.t < 60.0)]
    _, fixes = _run(packets)
    second = [f for f in fixes if 81.0 <= f[0] < 100.0]
    assert all(err < 10.0 and reason.startswith("refused: jumped")
               for _, err, reason in second), second

def test_fixes_of_a_refused_jump_that_come_within_the_gate_are_still_refused() -> None:
    """10 Hz fixes (reporting 3 m, 1 m of it new at each fix) jump 40 m east for 30 s; for
    3 s of it they come back to 30 m, within the gate of fixes this frequent. They lie
    nearer where the fixes jumped to than the track, so they are the run's, not the track's
    return: taken, they ended the refusal and the run was followed (42 m off)."""
    for seed in (1, 2, 3):
        packets = _drive(120.0, [(60.0, 90.0, 40.0), (70.0, 73.0, -10.0)], seed=seed,
                         accuracy_m=3.0, fix_rate_hz=10, noise_m=1.0)
        _, fixes = _run(packets)
        during = [f for f in fixes if 60.0 <= f[0] < 90.0]
        assert all(err < 6.0 and reason.startswith("refused:")
                   for _, err, reason in during), (seed, during)
        assert any(reason.startswith("refused: nearer the jumped fixes")
                   for _, _, reason in during)


def test_after_a_gap_fixes_nearer_the_jump_are_not_refused_as_the_run() -> None:
    """The same fixes, but coming back after a 30 s outage already 40 m off: a leap then
    may be the true fixes returning to an estimate that drifted, so those that get through
    the gate are not refused as part of the run."""
    packets = [p for p in _drive(95.0, [(70.0, 100.0, 40.0), (72.0, 75.0, -10.0)],
                                 accuracy_m=3.0, fix_rate_hz=10)
               if not (isinstance(p, GpsFix) and 40.0 <= p.t < 70.0)]
    _, fixes = _run(packets)
    assert not any(reason.startswith("refused: nearer the jumped fixes")
                   for _, _, reason in fixes)


def test_a_followed_jump_that_jumps_back_is_left_at_once() -> None:
    """Fixes that jump 50 m off the track for 75 s are refused for ``max_jump_s``, then
    followed; when they jump back by the same offset, the filter is back on them at the
    second such fix (two that agree), and the GPS bias states keep nothing of the jump."""
    back_t = STILL_S + 85.0
    road, fixes = _run(_drive(back_t + 20.0, [(STILL_S + 10.0, back_t, 50.0)]))
    assert [err > 30.0 for t, err, _ in fixes if back_t - 10.0 <= t < back_t] == [True] * 10
    back = [f for f in fixes if f[0] >= back_t]
    assert back[0][2] != back[1][2] == "re-acquired: the fixes jumped back"  # two agree
    assert all(err < 4.0 for _, err, _ in back[1:]), back  # 4 sigma of the fixes


def test_one_fix_that_jumps_back_from_a_followed_jump_is_not_followed_alone() -> None:
    """As above, but the fixes jump back for one fix only and the next lies 20 m off it
    (urban fixes swing that much in a second): no restart onto that one fix; the run is
    refused as a jump until the fixes come back for good, and then followed."""
    back_t = STILL_S + 85.0
    packets = _drive(back_t + 20.0, [(STILL_S + 10.0, back_t - 1.0, 50.0),
                                     (back_t, back_t + 1.0, 30.0),
                                     (back_t + 1.0, back_t + 5.0, 50.0)])
    _, fixes = _run(packets)
    swing = [f for f in fixes if back_t - 1.0 <= f[0] < back_t + 5.0]
    assert not any(reason == "re-acquired: the fixes jumped back" for _, _, reason in swing)
    assert all(err > 30.0 for _, err, _ in swing), swing
    back = [f for f in fixes if f[0] >= back_t + 5.0]
    assert back[1][2] == "re-acquired: the fixes jumped back"
    assert all(err < 4.0 for _, err, _ in back[1:]), back


def test_a_jump_the_map_had_followed_that_jumps_back_is_left_at_once() -> None:
    """The car drives a road the map lacks; a non-line-of-sight run puts the fixes 50 m
    east, on the map's road, and the filter follows it at once (its estimate off every road
    widens its variance to that distance). When the run ends the fixes leap back by that
    offset: the filter is back on them at the second such fix, not refusing them as a jump
    from the run's track for ``max_jump_s``."""
    start_t, back_t = STILL_S + 20.0, STILL_S + 40.0
    _, fixes = _run(_drive(back_t + 20.0, [(start_t, back_t, 50.0)]),
                    _north_road(50.0))  # a map that lacks the road driven
    assert all(err > 40.0 for t, err, _ in fixes if start_t + 1.0 <= t < back_t)
    back = [f for f in fixes if f[0] >= back_t]
    assert back[0][2] != back[1][2] == "re-acquired: the fixes jumped back"  # two agree
    assert all(err < 4.0 for _, err, _ in back[1:]), back


def _road_across_and_road_50_m_east(x_m: float, y_m: float, heading_rad: float,
                                    radius_m: float, max_bearing_diff_rad: float) -> float:
    """A map of two roads: one east-west where the car stops (north 300 m), one north-south
    50 m east (the car's own road is missing)."""
    roads = ((abs(y_m - 300.0), math.pi / 2.0), (abs(x_m - 50.0), 0.0))
    return min([min(d, radius_m) for d, bearing in roads
                if abs(math.remainder(heading_rad - bearing, math.pi)) <= max_bearing_diff_rad],
               default=radius_m)


def test_a_car_standing_on_a_road_across_its_heading_does_not_follow_a_run_onto_another(
        ) -> None:
    """The car drives north 300 m and stops on an east-west road (stopped mid-turn: its
    heading is not the road's); a non-line-of-sight run then puts the fixes 50 m east, on a
    north-south road. Standing, any road counts as the estimate's: it is on one, and the run
    is refused as a jump, not followed because the map seemed to prefer it."""
    rng = np.random.default_rng(3)
    packets: list[Packet] = []
    for k in range(10_000):  # 100 s: 10 s still, 30 s north at 10 m/s, 60 s still
        t = k / 100.0
        speed = SPEED_MPS if STILL_S < t <= STILL_S + 30.0 else 0.0
        north = min(_north_m(t), 300.0)
        packets.append(ImuSample(t, yaw_rate_rps=GYRO_BIAS_RPS + rng.normal(0.0, 0.002)))
        if k % 10 == 0:
            packets.append(OdometerSample(t, speed_mps=speed))
        if k % 100 == 0:
            east = 50.0 if 60.0 <= t < 90.0 else 0.0
            lon, lat = FRAME.to_wgs84(east + rng.normal(0.0, 1.0), north + rng.normal(0.0, 1.0))
            packets.append(GpsFix(t, lat_deg=lat, lon_deg=lon, accuracy_m=1.0))
    road = RoadFilter(FusionConfig(), FRAME, _road_across_and_road_50_m_east)
    during = []
    for p in packets:
        for e in road.apply(p):
            if isinstance(p, GpsFix) and e.gps is not None and 60.0 <= p.t < 90.0:
                during.append((p.t, math.hypot(e.x_m, e.y_m - 300.0), e.gps.reason))
    assert all(err < 10.0 for _, err, _ in during), during


def test_the_gps_bias_states_stay_within_their_bound() -> None:
    """A followed 50 m jump is position, not bias: the bias states never hold more than
    ``gps_bias_max_sigmas`` of their steady sigma."""
    config = FusionConfig()
    road = RoadFilter(config, FRAME)
    packets = [p for p in _drive(100.0, [(50.0, 100.0, 50.0)])
               if not (isinstance(p, GpsFix) and 40.0 <= p.t < 48.0)]
    largest = 0.0
    for p in packets:
        road.apply(p)
        s = road.state
        if s.initialized and s.gps_bias_sigma_m > 0.0:
            bias = max(abs(s.x[GPS_BIAS_E]), abs(s.x[GPS_BIAS_N])) / s.gps_bias_sigma_m
            largest = max(largest, bias)
    assert 0.0 < largest <= config.gps_bias_max_sigmas + 1e-9


def test_fixes_refused_past_the_gate_leave_the_gyro_bias_alone() -> None:
    """A heading knocked 60 degrees off on a track not yet settled: the fixes run away from
    the estimate and are refused, each still pulling; the pull moves position, heading and
    speed, never the gyro bias (its linearisation does not hold that far off: a pull once
    put 4.5 deg/s into it and the heading spun for minutes). Seven refused fixes later
    their path shows the heading turned, and it is turned back."""
    road = RoadFilter(FusionConfig(), FRAME)
    refused, worst_rps = 0, 0.0
    for p in _drive(90.0, []):
        if isinstance(p, GpsFix) and p.t == 30.0:
            road.state.x[HEADING] += math.radians(60.0)
            road.state.tracking_since_t = None  # as just after start-up
        for e in road.apply(p):
            if isinstance(p, GpsFix) and p.t > 30.0 and e.gps is not None:
                refused += e.gps.reason == "down-weighted: innovation too large"
                worst_rps = max(worst_rps, abs(road.state.x[GYRO_BIAS] - GYRO_BIAS_RPS))
    assert refused >= 5
    assert worst_rps < math.radians(0.2)


def test_weighted_modes_blend_only_what_gps_measures() -> None:
    """The thesis's weighted sums move position (and heading and speed, from a course the
    fixes' track gives when the receiver sends none), never the latency; the GPS bias states
    carry covariance only (the odometer's Kalman updates, through it, move them by
    micrometres)."""
    for mode in (GpsMode.RULES, GpsMode.FUZZY):
        road = RoadFilter(FusionConfig(gps_mode=mode), FRAME)
        for p in _drive(60.0, []):
            road.apply(p)
        x = road.state.x
        assert np.isfinite(x).all() and np.isfinite(road.state.P).all()
        assert x[GPS_LATENCY] == FusionConfig().initial_gps_latency_s
        assert abs(x[GPS_BIAS_E]) < 1e-3 and abs(x[GPS_BIAS_N]) < 1e-3
        assert abs(x[SPEED] - SPEED_MPS) < 1.0
        assert abs(math.remainder(x[HEADING], 2.0 * math.pi)) < math.radians(5.0)



def test_weighted_modes_take_a_course_from_the_fixes_no_more_than_its_variance() -> None:
    """Fixes with no course, 20 m east for 10 s (a street canyon) as the car drives north:
    the track of the fixes then points east of north, but a course drawn from positions is
    taken by its Kalman gain, not by the thesis's weight for a receiver's course, and the
    heading stays within 10 degrees of north (the thesis's weight turned it 23)."""
    for mode in (GpsMode.RULES, GpsMode.FUZZY):
        road = RoadFilter(FusionConfig(gps_mode=mode), FRAME)
        worst_rad = 0.0
        for p in _drive(60.0, [(40.0, 50.0, 20.0)], accuracy_m=3.0):
            road.apply(p)
            if p.t > 30.0:
                worst_rad = max(worst_rad, abs(math.remainder(road.state.x[HEADING],
                                                              2.0 * math.pi)))
        assert worst_rad < math.radians(10.0), (mode, math.degrees(worst_rad))


def _shift_by_one_fix(east_offset_m: float, road_distance: RoadDistance | None) -> float:
    """How far one fix ``east_offset_m`` off the drive moves a settled estimate east."""
    packets = _drive(60.0, [], accuracy_m=5.0)
    road = RoadFilter(FusionConfig(), FRAME, road_distance)
    for p in packets:
        road.apply(p)
    before = float(road.state.x[0])
    lon, lat = FRAME.to_wgs84(east_offset_m, _north_m(60.0))
    road.apply(GpsFix(60.0, lat_deg=lat, lon_deg=lon, accuracy_m=5.0))
    return float(road.state.x[0]) - before


def test_a_fix_off_the_road_the_estimate_is_on_weighs_less() -> None:
    """A fix 13 m off the road, 2 m beyond two of its learnt sigmas (which a fix 14 m off
    already leaves beyond the gate), pulls less with the map."""
    alone, with_map = _shift_by_one_fix(13.0, None), _shift_by_one_fix(13.0, _north_road_distance)
    assert alone > 0.5  # accepted: within the gate
    assert with_map < 0.9 * alone
    # within two sigmas of the road the map changes nothing
    assert _shift_by_one_fix(6.0, _north_road_distance) == _shift_by_one_fix(6.0, None)


def test_a_sharper_fix_does_not_push_the_offset_the_bias_holds_into_the_position() -> None:
    """The bias states hold a 30 m offset of the fixes (a non-line-of-sight run the estimate
    did not follow); a fix as far off, but with a quarter of the sigma, leaves the position:
    the bias bound shrinks no faster than the bias decays."""
    road = RoadFilter(FusionConfig(), FRAME)
    for p in _drive(60.0, [], accuracy_m=8.0):
        road.apply(p)
    road.state.x[GPS_BIAS_E] += 30.0
    before = float(road.state.x[0])
    lon, lat = FRAME.to_wgs84(before + 30.0, _north_m(60.0))
    road.apply(GpsFix(60.0, lat_deg=lat, lon_deg=lon, accuracy_m=2.0))
    assert abs(float(road.state.x[0]) - before) < 3.0



def _across_after_the_road(sensors: str) -> tuple[float, float, float]:
    """Fixes with a 3 m sigma lying 8 m east of the road for two minutes, then the road
    itself (map feedback, 1 m across): the estimate's error across the road, the reported
    variance across it, and the unseen variance the map had learnt."""
    config = FusionConfig(sensors=SensorConfig(sensors))
    road = RoadFilter(config, FRAME, _north_road_distance)
    packets = _drive(120.0, [(0.0, 120.0, 8.0)], accuracy_m=3.0)
    for p in packets:
        road.apply(p)
    north = _north_m(road.state.t or 0.0)
    for _ in range(5):
        road.correct(RoadConstraint(0.0, north, 0.0, 1.0, math.radians(5.0)))
    e = road.estimate()
    assert e is not None
    return abs(e.x_m), float(e.position_cov_m2[0, 0]), road.state.gps_unseen_var_m2


def test_a_road_that_rivals_share_pulls_a_lost_estimate_only_that_likely() -> None:
    """After a long outage the estimate is 150 m unsure, and the matched road is one of
    several beside it (a fifth of their likelihood). Fed back as a sure road, one update
    took the estimate onto it and its sigma to a few metres (steering, Stockholm 120 of the
    tune split: 777 m off with a sigma of 13 m). Fed back a fifth likely, the estimate moves
    a fifth of the way and keeps four fifths of its variance across the road."""
    road = RoadFilter(FusionConfig(), FRAME, _north_road_distance)
    for p in _drive(60.0, [], accuracy_m=3.0):
        road.apply(p)
    road.state.P[0, 0] = road.state.P[1, 1] = 150.0 ** 2
    before_m, before_var = float(road.state.x[0]), float(road.state.P[0, 0])
    north = float(road.state.x[1])
    sure = road.snapshot()
    assert road.correct(RoadConstraint(before_m + 40.0, north, 0.0, 2.0, math.radians(5.0)))
    sure_pull_m = float(road.state.x[0]) - before_m
    assert float(road.state.P[0, 0]) < 3.0 ** 2
    road.restore(sure)
    assert road.correct(RoadConstraint(before_m + 40.0, north, 0.0, 2.0, math.radians(5.0),
                                       probability=0.2))
    assert float(road.state.x[0]) - before_m == pytest.approx(0.2 * sure_pull_m, rel=0.01)
    assert float(road.state.P[0, 0]) == pytest.approx(
        before_var - 0.2 * (before_var - 2.0 ** 2), rel=0.01)


def test_the_unseen_error_scales_a_dead_reckoned_covariance_and_adds_to_gps_alone() -> None:
    """The map saw the fixes 8 m off while their sigma said 3 m. Once the road has put the
    dead-reckoned estimate back on it, the error the fixes share is no longer the estimate's:
    the reported variance across the road is the filter's own scaled by one plus the fixes'
    unseen share (here 5.6 m2), not that unseen 64 m2 added in full. On GPS alone the
    estimate follows the fixes, so the reported variance takes it in full."""
    error_m, across_var, unseen_var = _across_after_the_road("gyro_odometer")
    assert unseen_var > 30.0
    assert error_m <= 2.45 * math.sqrt(across_var)
    assert across_var < unseen_var / 3.0
    _, across_var_gps, unseen_var_gps = _across_after_the_road("gps_only")
    assert across_var_gps >= unseen_var_gps > 30.0


def test_gps_alone_a_departure_after_a_stop_is_no_jump() -> None:
    """GPS alone (fixes with the receiver's course and speed): north at 10 m/s, a 20 s
    stop, then away east. At the stop the filter loses the heading (a standing receiver has
    no course), so the fixes leaving it are no leap away from a settled track: they are
    taken, not refused as a non-line-of-sight jump while the estimate stands."""
    rng = np.random.default_rng(3)
    fixes: list[GpsFix] = []
    truth: dict[float, tuple[float, float]] = {}
    east, north, speed = 0.0, 0.0, 0.0
    for k in range(90):
        t = float(k)
        if t <= 30.0:
            north, speed, heading = 10.0 * t, 10.0, 0.0
        elif t <= 50.0:
            speed, heading = 0.0, None
        else:
            speed, heading = min(2.5 * (t - 50.0), 10.0), math.pi / 2.0
            east += speed
        truth[t] = (east, north)
        lon, lat = FRAME.to_wgs84(east + rng.normal(0.0, 2.0), north + rng.normal(0.0, 2.0))
        fixes.append(GpsFix(t, lat_deg=lat, lon_deg=lon, accuracy_m=2.0, speed_mps=speed,
                            heading_rad=heading))
    road = RoadFilter(FusionConfig(sensors=SensorConfig.GPS_ONLY), FRAME)
    after = []
    for fix in fixes:
        for e in road.apply(fix):
            if fix.t > 50.0 and e.gps is not None:
                error_m = math.hypot(e.x_m - truth[fix.t][0], e.y_m - truth[fix.t][1])
                after.append((fix.t, round(error_m, 1), e.gps.reason))
    assert not any(reason.startswith("refused: jumped") for _, _, reason in after), after
    assert all(error_m < 10.0 for _, error_m, _ in after), after


@pytest.mark.parametrize(("gap_s", "restart_at_fix"), [(20.0, 0), (0.0, 2)])
def test_fixes_beyond_any_non_line_of_sight_error_restart_a_lost_estimate(
        gap_s: float, restart_at_fix: int) -> None:
    """The fixes come back 200 m east of dead reckoning and stay there: farther than any
    non-line-of-sight error, so the estimate is lost, not the fixes. After a 20 s gap the
    first of them restarts it, and the estimate it emits is at that fix (it had waited for
    3 fixes, and emitted the lost track: gyro_accel after a 150 s gap, 620 m off). Without
    a gap (a leap no dead reckoning makes in a second) it waits for 3 fixes (2 s), not
    for 30 s of refusing them. Either way it is on them within 5 fixes of the restart."""
    packets = [p for p in _drive(120.0, [(60.0, 120.0, 200.0)])
               if not (isinstance(p, GpsFix) and 60.0 - gap_s <= p.t < 60.0)]
    road = RoadFilter(FusionConfig(), FRAME)
    back = []
    for p in packets:
        for e in road.apply(p):
            if isinstance(p, GpsFix) and p.t >= 60.0 and e.gps is not None:
                back.append((p.t, math.hypot(e.x_m - 200.0, e.y_m - _north_m(p.t)),
                             e.gps.reason))
    restart = next(i for i, (_, _, reason) in enumerate(back) if reason.startswith("re-acq"))
    assert restart == restart_at_fix, back
    assert back[restart][1] < 5.0, back
    assert all(err < 5.0 for _, err, _ in back[restart + 5:]), back


def test_a_lost_estimate_restarts_with_the_sensor_errors_it_had_before_the_refusals() -> None:
    """After a 60 s gap the fixes come back 160 m ahead of dead reckoning (along the track,
    where the error looks like the odometer's scale). Not counted as a gap (which would
    restart it at the first fix), the refused fixes pull the scale before the estimate is
    found lost; restarting, it goes back to the scale it had learnt before them, not to the
    pull of fixes from a lost state."""
    packets: list[Packet] = []
    for p in _drive(150.0, []):
        if isinstance(p, GpsFix) and 30.0 <= p.t < 90.0:
            continue
        if isinstance(p, GpsFix) and p.t >= 90.0:
            east, north = FRAME.to_local(p.lon_deg, p.lat_deg)
            lon, lat = FRAME.to_wgs84(east, north + 160.0)
            p = replace(p, lat_deg=lat, lon_deg=lon)
        packets.append(p)
    road = RoadFilter(FusionConfig(gps_gap_s=100.0), FRAME)
    before, pulled = None, None
    for p in packets:
        if isinstance(p, GpsFix) and p.t == 90.0:
            before = float(road.state.x[ODO_SCALE])
        out = road.apply(p)
        reason = road.state.gps.reason if road.state.gps is not None else ""
        if isinstance(p, GpsFix) and p.t > 90.0 and pulled is None and \
                reason.startswith("down-weighted"):
            pulled = float(road.state.x[ODO_SCALE])
        if isinstance(p, GpsFix) and reason.startswith("re-acquiring"):
            assert before is not None and pulled is not None
            assert abs(pulled - before) > 0.01  # the refused fixes did pull the scale
            assert road.state.x[ODO_SCALE] == before
            # emitted at the fix, with no heading: the filter no longer trusts its own
            assert len(out) == 1 and not out[0].initialized
            assert (out[0].x_m, out[0].y_m) == pytest.approx(FRAME.to_local(p.lon_deg,
                                                                            p.lat_deg))
            assert math.isnan(out[0].heading_rad) and math.isinf(out[0].heading_sigma_rad)
            return
    raise AssertionError("the filter never re-acquired")


def test_weighted_modes_restart_from_fixes_beyond_any_non_line_of_sight_error() -> None:
    """The thesis's modes, the same drive: fixes 200 m off after a 20 s gap restart the
    estimate at the first of them (the thesis waits thousands of fixes)."""
    packets = [p for p in _drive(100.0, [(60.0, 100.0, 200.0)])
               if not (isinstance(p, GpsFix) and 40.0 <= p.t < 60.0)]
    for mode in (GpsMode.RULES, GpsMode.FUZZY):
        road = RoadFilter(FusionConfig(gps_mode=mode), FRAME)
        restarts = [p.t for p in packets for e in road.apply(p)
                    if isinstance(p, GpsFix) and e.gps is not None
                    and e.gps.reason.endswith("beyond any non-line-of-sight error")]
        assert restarts and restarts[0] == 60.0, (mode, restarts)
        err = math.hypot(road.state.x[0] - 200.0, road.state.x[1] - _north_m(100.0))
        assert err < 5.0, (mode, err)


def _rules_pull_after_a_gap(offset_m: float, gap_s: float) -> tuple[float, float]:
    """The rules mode, the same drive with a gap of ``gap_s`` in the fixes: the east pull of
    the first fix after it, lying ``offset_m`` east, and the estimate's sigma east before
    it."""
    gap = (100.0 - gap_s, 100.0)
    packets = [p for p in _drive(110.0, [(gap[1], gap[1] + 0.5, offset_m)], noise_m=0.0)
               if not (isinstance(p, GpsFix) and gap[0] <= p.t < gap[1])]
    road = RoadFilter(FusionConfig(gps_mode=GpsMode.RULES), FRAME)
    for p in packets:
        if isinstance(p, GpsFix) and p.t == gap[1]:
            before, sigma_m = road.state.x[0], math.sqrt(road.state.P[0, 0])
            road.apply(p)
            return road.state.x[0] - before, sigma_m
        road.apply(p)
    raise AssertionError("no fix after the gap")


def test_rules_after_a_gap_a_fix_within_the_estimates_uncertainty_pulls_for_the_gap() -> None:
    """The thesis's weight per second, compounded over the 60 s without fixes: the first
    fix after them pulls most of the way when the estimate's own uncertainty covers it."""
    _, sigma_m = _rules_pull_after_a_gap(0.0, 60.0)
    pull_m, _ = _rules_pull_after_a_gap(sigma_m, 60.0)
    assert pull_m > 0.8 * sigma_m


def test_rules_after_a_gap_a_fix_past_the_gate_pulls_as_one_fix() -> None:
    """... but a fix far past it (a non-line-of-sight fix after an outage) pulls as one
    fix (4 %), not as the seconds without fixes (34 % for 10 s, 91 % for 60 s): it had
    pulled an estimate 17 m onto a fix 23 m off (Stockholm 15 of the tune split, rules:
    4.9x raw GPS; 0.8x with this)."""
    pull_m, sigma_m = _rules_pull_after_a_gap(30.0, 10.0)
    assert 30.0 > 5.0 * sigma_m  # far past the gate
    assert 0.0 < pull_m < 0.05 * 30.0


# east error (m) of 2 Hz fixes from t = 6 s: a replayed urban-canyon start-up (UrbanNav's
# error on Stockholm 465 of the tune split), leaping 28 m east and back at the standstill,
# then sweeping 40 m east in 3 s as the car pulls away north
URBAN_START_ERRORS_EAST_M = (-29.1, -1.2, 26.8, -1.0, -28.8, -27.4, -26.0, -14.8, -3.5, -1.5,
                             0.4, 6.1, 11.9, 11.9)


def test_start_up_heading_is_not_taken_from_fixes_sweeping_off_the_driven_line() -> None:
    """The car stands for 8.2 s, then pulls away north at 1.5 m/s^2; 2 Hz fixes of 3.5 m
    accuracy carry the error above. Two ends of the sweep, 36 m apart after 8 m driven,
    gave a start-up heading 77 degrees off with a sigma of 13 degrees; the fixes in between
    do not lie along the line the odometer drove, so the filter waits for ones that do."""
    still_s, accel_mps2 = 8.2, 1.5

    def north_m(t: float) -> float:
        moving = max(t - still_s, 0.0)
        return 0.5 * accel_mps2 * min(moving, 5.0) ** 2 + 7.5 * max(moving - 5.0, 0.0)

    def speed_mps(t: float) -> float:
        return accel_mps2 * min(max(t - still_s, 0.0), 5.0)

    rng = np.random.default_rng(3)
    packets: list[Packet] = []
    for k in range(3000):
        t = k / 100.0
        packets.append(ImuSample(t, yaw_rate_rps=rng.normal(0.0, 0.002)))
        if k % 10 == 0:
            packets.append(OdometerSample(t, speed_mps=speed_mps(t)))
        if k % 50 == 0:
            i = round((t - 6.0) * 2.0)
            east = URBAN_START_ERRORS_EAST_M[i] if 0 <= i < len(URBAN_START_ERRORS_EAST_M) \
                else 0.0
            noise_east, noise_north = rng.normal(0.0, 1.0, 2)
            lon, lat = FRAME.to_wgs84(east + noise_east, north_m(t) + noise_north)
            packets.append(GpsFix(t, lat_deg=lat, lon_deg=lon, accuracy_m=3.5))
    road = RoadFilter(FusionConfig(), FRAME)
    start = _first_estimate(road, packets)
    assert abs(math.remainder(start.heading_rad, 2.0 * math.pi)) < 3.0 * start.heading_sigma_rad
    estimate = road.estimate()
    assert estimate is not None and math.hypot(estimate.x_m, estimate.y_m - north_m(30.0)) < 10.0


def test_start_up_heading_is_not_taken_across_a_gap_in_the_fixes() -> None:
    """GPS alone, no course: the car drives north at 10 m/s. Its first fix is 30 m east (a
    non-line-of-sight fix, as before a receiver loses lock), then none for 4.5 s, then right
    ones. The bearing across the gap was 34 degrees off with a sigma of 4; a baseline does
    not span a gap longer than ``track_gap_s``, so the heading comes from the fixes after it."""
    packets: list[Packet] = []
    for t in (0.0, 4.5, 5.5, 6.5, 7.5, 8.5):
        lon, lat = FRAME.to_wgs84(30.0 if t == 0.0 else 0.0, SPEED_MPS * t)
        packets.append(GpsFix(t, lat_deg=lat, lon_deg=lon, accuracy_m=3.0))
    road = RoadFilter(FusionConfig(sensors=SensorConfig.GPS_ONLY), FRAME)
    start = _first_estimate(road, packets)
    assert start.t > 4.5
    assert abs(math.remainder(start.heading_rad, 2.0 * math.pi)) < 3.0 * start.heading_sigma_rad


def test_re_acquiring_counts_the_heading_baseline_from_the_restarting_fix() -> None:
    """Re-acquiring starts a new start-up heading at the fix that restarts the filter: the
    odometer's distance and the gyro's turn are counted from there (they had kept the counts
    of the first start-up, and a fix 24 m off passed as agreeing with the odometer)."""
    packets = [p for p in _drive(120.0, [(60.0, 120.0, 200.0)])
               if not (isinstance(p, GpsFix) and 40.0 <= p.t < 60.0)]
    road = RoadFilter(FusionConfig(), FRAME)
    for p in packets:
        road.apply(p)
        if isinstance(p, GpsFix) and road.state.gps is not None and \
                road.state.gps.reason.startswith("re-acquiring"):
            s = road.state
            assert s.first_fix is not None and s.first_fix[0] == p.t
            assert s.travelled_m == 0.0 and s.turned_rad == 0.0
            assert [f[0] for f in s.baseline_fixes] == [p.t]
            return
    raise AssertionError("the filter never re-acquired")


def test_steering_start_up_counts_the_turn_of_a_bend() -> None:
    """Steering and odometer, no gyro: the car pulls away into a left bend (radius 40 m at
    8 m/s, 11 degrees a second) and leaves it heading west. The bearing of fixes over a
    baseline through the bend is no heading (a steering drive started 49 degrees off); the
    turn the steering and odometer give is counted, so start-up waits for a straight
    baseline, and starts within 3 of its sigmas of the true heading."""
    still_s, speed, radius_m = 5.0, 8.0, 40.0
    arc_m = radius_m * math.pi / 2.0

    def truth(t: float) -> tuple[float, float, float]:
        """(east, north, heading clockwise from north) at ``t``."""
        s = max(t - still_s, 0.0) * speed
        phi = min(s, arc_m) / radius_m
        east, north = -radius_m + radius_m * math.cos(phi), radius_m * math.sin(phi)
        return east - max(s - arc_m, 0.0), north, -phi

    config = FusionConfig(sensors=SensorConfig.STEERING_ODOMETER)
    rng = np.random.default_rng(5)
    packets: list[Packet] = []
    for k in range(4000):
        t = k / 100.0
        moving = t > still_s
        in_bend = moving and (t - still_s) * speed < arc_m
        steer = math.atan(config.wheelbase_m / radius_m) if in_bend else 0.0
        packets.append(SteeringSample(t, angle_rad=steer + rng.normal(0.0, 0.001)))
        if k % 10 == 0:
            packets.append(OdometerSample(t, speed_mps=speed if moving else 0.0))
        if k % 100 == 0:
            east, north, _ = truth(t)
            lon, lat = FRAME.to_wgs84(east + rng.normal(0.0, 1.0), north + rng.normal(0.0, 1.0))
            packets.append(GpsFix(t, lat_deg=lat, lon_deg=lon, accuracy_m=1.0))
    start = _first_estimate(RoadFilter(config, FRAME), packets)
    error = math.remainder(start.heading_rad - truth(start.t)[2], 2.0 * math.pi)
    assert abs(error) < 3.0 * start.heading_sigma_rad, (start.t, math.degrees(error))


def _with_course(packets: list[Packet]) -> list[Packet]:
    """The drive's fixes with the receiver's course and speed (north, 10 m/s) once moving."""
    return [replace(p, speed_mps=SPEED_MPS, heading_rad=0.0)
            if isinstance(p, GpsFix) and p.t > STILL_S + 1.0 else p for p in packets]


def _heading_error_deg(road: RoadFilter) -> float:
    return abs(math.degrees(math.remainder(road.state.x[HEADING], 2.0 * math.pi)))


def test_a_refused_fix_still_gives_its_course_and_a_heading_far_off_takes_it() -> None:
    """A heading knocked 160 degrees off: every fix lies too far from where the estimate
    drove to pass the gate, and none would correct the heading. Their course and speed are
    still fused; refused in turn, they replace the heading within a few fixes, after which
    the fixes are taken again."""
    road = RoadFilter(FusionConfig(), FRAME)
    reasons, heading_errors = [], []
    for p in _with_course(_drive(90.0, [])):
        if isinstance(p, GpsFix) and p.t == 30.0:
            road.state.x[HEADING] += math.radians(160.0)
            road.state.tracking_since_t = None  # as just after start-up
        for e in road.apply(p):
            if isinstance(p, GpsFix) and p.t > 30.0 and e.gps is not None:
                reasons.append(e.gps.reason)
                heading_errors.append(_heading_error_deg(road))
    assert "down-weighted: innovation too large" in reasons[:3], reasons
    assert max(heading_errors[5:]) < 5.0, heading_errors
    assert all(r in ("accepted", "down-weighted") for r in reasons[15:]), reasons


def test_a_refused_jump_still_gives_its_course() -> None:
    """A non-line-of-sight run 50 m east of a settled track is refused as a jump; its
    course (the velocity is not moved by the reflection) still holds a heading knocked
    20 degrees off at the run's start, which dead reckoning alone would keep."""
    road = RoadFilter(FusionConfig(), FRAME)
    during = []
    for p in _with_course(_drive(100.0, [(60.0, 90.0, 50.0)])):
        if isinstance(p, GpsFix) and p.t == 60.0:
            road.state.x[HEADING] += math.radians(20.0)
        for e in road.apply(p):
            if isinstance(p, GpsFix) and 60.0 <= p.t < 90.0 and e.gps is not None:
                during.append((e.gps.reason, _heading_error_deg(road)))
    assert all(reason.startswith("refused: jumped") for reason, _ in during[2:]), during
    assert max(err for _, err in during[10:]) < 3.0, during


def test_a_heading_that_drifted_off_the_road_in_an_outage_is_doubted_when_the_fixes_return(
        ) -> None:
    """The gyro bias jumps by 0.3 deg/s as a 60 s outage begins: the estimate turns off its
    road, 100 m west by the end. The fixes return on the road and, after
    ``jump_map_after_s``, the map prefers them to the estimate's track: the filter follows
    them, and its heading variance is widened to explain the drift over the distance driven,
    so that its heading error lies within 3 sigmas (it was 19 degrees off with a sigma of 5,
    and still 10 off at the next fix)."""
    outage = (STILL_S + 20.0, STILL_S + 80.0)
    packets: list[Packet] = []
    for p in _drive(STILL_S + 100.0, []):
        if isinstance(p, GpsFix) and outage[0] <= p.t < outage[1]:
            continue
        if isinstance(p, ImuSample) and p.t >= outage[0]:
            p = replace(p, yaw_rate_rps=p.yaw_rate_rps + math.radians(0.3))
        packets.append(p)
    road = RoadFilter(FusionConfig(), FRAME, _north_road_distance)
    for p in packets:
        for e in road.apply(p):
            if isinstance(p, GpsFix) and e.gps is not None and \
                    e.gps.reason.startswith("re-acquired: the fixes lie on a road"):
                error = abs(math.remainder(e.heading_rad, 2.0 * math.pi))
                assert error < 3.0 * e.heading_sigma_rad, (math.degrees(error),
                                                           math.degrees(e.heading_sigma_rad))
                return
    raise AssertionError("the map never preferred the fixes")


def _corner_and_diagonal(x_m: float, y_m: float, heading_rad: float, radius_m: float,
                         max_bearing_diff_rad: float) -> float:
    """A map of a corner at the origin (a road north, one east) and a diagonal road, bearing
    45 degrees, through (-40, 0)."""
    def along(bearing_rad: float) -> bool:
        return abs(math.remainder(heading_rad - bearing_rad, math.pi)) <= max_bearing_diff_rad
    distances = [abs(x_m) if along(0.0) and y_m <= 0.0 else radius_m,
                 abs(y_m) if along(math.pi / 2.0) and x_m >= 0.0 else radius_m,
                 abs(x_m + 40.0 - y_m) / math.sqrt(2.0) if along(math.pi / 4.0) else radius_m]
    return min(min(distances), radius_m)


def test_a_car_half_way_round_a_corner_is_on_the_roads_for_the_jump_test() -> None:
    """Half-way round a corner (heading 45 degrees, turning) the estimate lies on both roads
    though its heading lies along neither: fixes that jumped 40 m west onto a diagonal road
    are not followed for lying along the heading while the track does not (a track fitted
    along its heading mid-corner was "off the roads": Monaco 536 of the tune split)."""
    road = RoadFilter(FusionConfig(), FRAME, _corner_and_diagonal)
    s = road.state
    s.initialized = True
    s.x[X_M], s.x[Y_M], s.x[HEADING], s.x[SPEED] = 0.0, 0.0, math.pi / 4.0, 6.0
    innovation = np.array([-40.0, 0.0])
    for corner_rate_rps, followed in ((0.3, False), (0.0, True)):
        s.x[HEADING_RATE] = corner_rate_rps
        s.jump_since_t, s.jump_paused_s, s.jump_test = 0.0, 0.0, JumpMapTest()
        verdicts = [road._map_prefers_jump(t, innovation) for t in (4.0, 5.0, 6.0)]
        assert verdicts == [False, False, followed], (corner_rate_rps, verdicts)


def _speed_swinging_mps(t: float) -> float:
    """Standing, then 10 m/s, then from 16 s swinging between 5 and 15 m/s."""
    return 0.0 if t < STILL_S else 10.0 + 5.0 * math.sin(max(t - 16.0, 0.0) / 3.0)


def _drive_swinging(fixes_until_s: float, odometer_scale: float = 1.0) -> list[Packet]:
    """North at :func:`_speed_swinging_mps` for 140 s, an odometer that reads
    ``odometer_scale`` times the speed, and 1 m fixes once a second until ``fixes_until_s``."""
    rng = np.random.default_rng(3)
    packets: list[Packet] = []
    north_m = 0.0
    for k in range(14000):
        t = k / 100.0
        north_m += _speed_swinging_mps(t) * 0.01
        packets.append(ImuSample(t, yaw_rate_rps=GYRO_BIAS_RPS + rng.normal(0.0, 0.002)))
        if k % 10 == 0:
            packets.append(OdometerSample(t, speed_mps=odometer_scale * _speed_swinging_mps(t)))
        if k % 100 == 0 and t < fixes_until_s:
            lon, lat = FRAME.to_wgs84(rng.normal(0.0, 1.0), north_m + rng.normal(0.0, 1.0))
            packets.append(GpsFix(t, lat_deg=lat, lon_deg=lon, accuracy_m=1.0))
    return packets


@pytest.mark.xfail(strict=True, reason="known: the odometer update moves the scale (see "
                   "RoadFilter._fuse_odometer for why it is left)")
def test_speeding_up_and_slowing_down_without_fixes_leaves_the_odometer_scale() -> None:
    """Four fixes after start-up, then 124 s without any while the car swings between 5 and
    15 m/s: the odometer tells scale x speed, never the scale alone, so the scale should
    stay where the fixes left it. Linearised at a changing speed, each update moves it up:
    by 0.058 here, two sigma, and by 8 % in a drive of the tune split."""
    road = RoadFilter(FusionConfig(), FRAME)
    scales = []
    for p in _drive_swinging(fixes_until_s=16.0):
        road.apply(p)
        if p.t >= 16.0:
            scales.append(road.state.x[ODO_SCALE])
    assert road.state.initialized
    assert max(scales) - min(scales) < 1e-3, (min(scales), max(scales))


def test_the_odometer_scale_stays_within_what_an_odometer_can_be_off_by() -> None:
    """An odometer reading 25 % fast beside right fixes: the scale the fixes teach is held
    at 1.1 (tyres are never that far off; GPS and the map in a street canyon taught 0.85 for
    0.96), and the speed still follows the fixes."""
    road = RoadFilter(FusionConfig(), FRAME)
    for p in _drive_swinging(fixes_until_s=140.0, odometer_scale=1.25):
        road.apply(p)
    assert road.state.x[ODO_SCALE] == pytest.approx(1.1)
    assert abs(road.state.x[SPEED] - _speed_swinging_mps(road.state.t or 0.0)) < 2.0
