"""The strapdown sensor configuration through VehicleSession, on simulated 6-axis drives."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from navsvc.errors import ConfigError
from navsvc.fusion import FusionConfig, SensorConfig
from navsvc.fusion.gnss import RoadDistance
from navsvc.fusion.ins import dcm_to_euler
from navsvc.fusion.ins.strapdown import StrapdownFilter
from navsvc.fusion.road.measurements import RoadConstraint
from navsvc.session import VehicleSession, config_from_options
from navsvc.sim.evaluate import evaluate
from navsvc.sim.simulate import SENSOR_KINDS, DriveSpec, simulate_drive
from navsvc.types import FusedEstimate, GpsFix, ImuSample, OdometerSample
from navsvc.wire.positions import position_json
from roadgraph import LocalFrame, RoadGraph


@pytest.fixture(scope="module")
def drive(sample_graph: RoadGraph) -> list[dict]:
    return simulate_drive(sample_graph, DriveSpec(duration_s=300.0, seed=2, full_imu=True,
                                                  outages=((150.0, 30.0),),
                                                  tunnels_block_gps=False))


@pytest.mark.parametrize(("integration", "with_odometer"),
                         [("feedback", False), ("feedback", True), ("direct", True)])
def test_strapdown_session_follows_the_drive_through_an_outage(
        drive: list[dict], sample_graph: RoadGraph, integration: str,
        with_odometer: bool) -> None:
    kinds = set(SENSOR_KINDS["strapdown"]) - (set() if with_odometer else {"odometer"})
    packets = [r for r in drive if r["kind"] in kinds]
    session = VehicleSession(config_from_options(
        {"sensors": "strapdown", "ins_integration": integration}), sample_graph)
    result = session.add_records(packets)
    assert not result.rejections
    out = [position_json(p, sample_graph.frame) for p in result.positions]
    e = evaluate(drive, out)
    assert e.fused.rms_m < 1.2 * e.raw_gps.rms_m
    assert e.on_right_road_share >= 0.9
    (outage,) = [o for o in e.outages if o.start_s <= 151.0 <= o.end_s]
    assert outage.drift_pct < 5.0  # the non-holonomic constraint holds it


@pytest.mark.parametrize("with_odometer", [True, False])
def test_strapdown_aligns_from_the_fixes_track_when_the_receiver_sends_no_course(
        sample_graph: RoadGraph, with_odometer: bool) -> None:
    """A receiver without speed and course (urban single-point fixes): the heading comes from
    the fixes over a straight baseline, as sure as that baseline makes it; before this the
    INS never aligned and the drive had no output at all (9 of 30 held-out drives)."""
    drive = simulate_drive(sample_graph, DriveSpec(
        duration_s=120.0, seed=5, full_imu=True, gps_reports_velocity=False,
        tunnels_block_gps=False, start_standstill_s=10.0))
    kinds = set(SENSOR_KINDS["strapdown"]) - (set() if with_odometer else {"odometer"})
    # the simulator stamps a fix when it was measured, and the client says so (by default
    # the filters expect the 0.1 s of a receiver stamped when its fix is read)
    options = {"sensors": "strapdown", "profile": {"fusion.initial_gps_latency_s": 0.0}}
    session = VehicleSession(config_from_options(options), sample_graph)
    result = session.add_records([r for r in drive if r["kind"] in kinds])
    assert not result.rejections and result.positions
    start = next(i for i, p in enumerate(result.positions) if p.estimate.initialized)
    before = [p.estimate for p in result.positions[:start]]  # the fixes, no heading yet
    assert before and all(math.isnan(e.heading_rad) and math.isinf(e.heading_sigma_rad)
                          for e in before)
    first = result.positions[start].estimate
    assert first.gps is not None and first.gps.reason.endswith("heading from the fixes' track")
    truth = min((r for r in drive if r["kind"] == "truth"), key=lambda r: abs(r["t"] - first.t))
    heading_error = (math.degrees(first.heading_rad) - truth["heading_deg"] + 180.0) % 360.0 \
        - 180.0
    assert abs(heading_error) <= 3.0 * math.degrees(first.heading_sigma_rad)
    assert first.heading_sigma_rad < math.radians(15.0)
    # from the start (before it, the fixes themselves, matched by distance alone to one of
    # the roads at the intersection the car stood on)
    e = evaluate(drive, [position_json(p, sample_graph.frame)
                         for p in result.positions[start:]])
    # with fix positions alone (no velocity, no wheel speed) a MEMS INS does not beat them
    assert e.fused_to_raw_ratio < (1.0 if with_odometer else 1.5)
    assert e.on_right_road_share >= 0.9


def test_strapdown_needs_the_6_axis_imu(sample_graph: RoadGraph) -> None:
    session = VehicleSession(config_from_options({"sensors": "strapdown"}), sample_graph)
    result = session.add_records([{"t": 0.0, "kind": "imu", "yaw_rate_dps": 1.0},
                                  {"t": 0.1, "kind": "steering", "angle_deg": 1.0}])
    assert [(r.index, r.reason.code) for r in result.rejections] == [
        (0, "missing_field"), (1, "not_configured")]


def test_strapdown_refuses_what_it_cannot_do() -> None:
    with pytest.raises(ConfigError, match="fusion must be ekf"):
        config_from_options({"sensors": "strapdown", "fusion": "rules"})


def test_a_tilted_imu_on_a_moving_car_is_levelled_from_its_last_second() -> None:
    """An IMU pitched 3 degrees nose-up (its x axis reads 0.51 m/s^2 of gravity) on a car
    whose wheels say it moves from the start: no standstill to level from, so the mean of
    the last second's specific force levels it, not an assumed level mount; samples before
    any sensor spoke are no standstill's."""
    frame = LocalFrame.for_point(7.42, 43.73)
    ins = StrapdownFilter(FusionConfig(sensors=SensorConfig.STRAPDOWN), frame)
    pitch = math.radians(3.0)
    tilted = (9.81 * math.sin(pitch), 0.0, 9.81 * math.cos(pitch))  # FLU, at constant speed
    for k in range(100):
        t = 0.01 * k
        if k % 10 == 0:
            ins.apply(OdometerSample(t, speed_mps=10.0))
        ins.apply(ImuSample(t, gyro_rps=(0.0, 0.0, 0.0), accel_mps2=tilted))
    lon, lat = frame.to_wgs84(0.0, 0.0)
    ins.apply(GpsFix(1.0, lat_deg=lat, lon_deg=lon, accuracy_m=2.0, speed_mps=10.0,
                     heading_rad=0.0))
    assert ins.ins is not None
    _, pitch_now, _ = dcm_to_euler(ins.ins.state.c_bn)
    assert abs(abs(pitch_now) - pitch) < math.radians(0.1)


def test_no_alignment_from_implausible_wheels_or_fixes() -> None:
    """Fixes without a course 100 m apart while the wheels claim 1 km in a second, or two
    fixes at one instant 100 m apart without wheels: no car moves so, and no heading comes of
    it (an infinite speed had reached the INS's covariance as NaN)."""
    frame = LocalFrame.for_point(7.42, 43.73)
    for with_wheels in (True, False):
        ins = StrapdownFilter(FusionConfig(sensors=SensorConfig.STRAPDOWN), frame)
        ins.apply(ImuSample(0.0, gyro_rps=(0.0, 0.0, 0.0), accel_mps2=(0.0, 0.0, 9.81)))
        times = (0.0, 1.0) if with_wheels else (1.0, 1.0)
        for k, t in enumerate(times):
            if with_wheels:
                ins.apply(OdometerSample(t, distance_m=1000.0 * t))
            lon, lat = frame.to_wgs84(0.0, 100.0 * k)
            ins.apply(GpsFix(t, lat_deg=lat, lon_deg=lon, accuracy_m=2.0))
        assert ins.ins is None


def test_map_feedback_holds_the_strapdown_across_its_road() -> None:
    """The matched road, fed back, moves an INS 8 m off a north-south road onto it, across
    the road only, and leaves it no surer across the road than the map is (the same road
    again and again: its error does not average out)."""
    frame = LocalFrame.for_point(7.42, 43.73)
    ins = StrapdownFilter(FusionConfig(sensors=SensorConfig.STRAPDOWN), frame)
    lon, lat = frame.to_wgs84(8.0, 0.0)
    still = ImuSample(0.0, gyro_rps=(0.0, 0.0, 0.0), accel_mps2=(0.0, 0.0, 9.81))
    ins.apply(still)
    ins.apply(GpsFix(0.0, lat_deg=lat, lon_deg=lon, accuracy_m=10.0, speed_mps=10.0,
                     heading_rad=0.0))
    before = ins.estimate()
    assert before is not None
    road = RoadConstraint(0.0, before.y_m + 30.0, 0.0, 2.0, math.radians(5.0))
    for _ in range(5):
        assert ins.correct(road)
    after = ins.estimate()
    assert after is not None
    assert abs(after.x_m) < 1.0  # across: onto the road
    assert after.y_m == pytest.approx(before.y_m, abs=1.0)  # along: left alone
    assert after.position_cov_m2[0, 0] >= 2.0 ** 2 * 0.99


def test_imu_mounted_sideways_is_turned_back(drive: list[dict], sample_graph: RoadGraph) -> None:
    """The same drive with the IMU turned 90° (its x axis to the vehicle's right): declared,
    the mounting is undone; undeclared, the non-holonomic constraint holds the wrong axes.
    (A roll or pitch mounting the levelling absorbs by itself; a yaw one it cannot.)"""
    turned = []
    for r in drive:
        if r["kind"] == "imu":
            (gx, gy, gz), (ax, ay, az) = r["gyro_dps"], r["accel_mps2"]
            r = {**r, "gyro_dps": [-gy, gx, gz], "accel_mps2": [-ay, ax, az]}
        if r["kind"] in ("imu", "gps"):
            turned.append(r)
    rms = {}
    for mounting in ([0.0, 0.0, 0.0], [0.0, 0.0, 90.0]):
        config = config_from_options({"sensors": "strapdown", "imu_mounting_rpy_deg": mounting})
        result = VehicleSession(config, sample_graph).add_records(turned)
        e = evaluate(drive, [position_json(p, sample_graph.frame) for p in result.positions])
        rms[mounting[2]] = e.fused.rms_m
    raw = evaluate(drive, []).raw_gps.rms_m
    assert rms[90.0] < 1.2 * raw < rms[0.0]


@settings(max_examples=60, deadline=None)
@given(st.lists(st.fixed_dictionaries(
    {"t": st.floats(0.0, 30.0), "kind": st.sampled_from(["imu", "gps", "odometer"])},
    optional={"gyro_dps": st.lists(st.floats(-3000, 3000), min_size=3, max_size=3),
              "accel_mps2": st.lists(st.floats(-200, 200), min_size=3, max_size=3),
              "lat": st.floats(43.72, 43.75), "lon": st.floats(7.40, 7.44),
              "speed_mps": st.floats(0, 40), "heading_deg": st.floats(0, 359),
              "distance_m": st.floats(0, 1000)}), max_size=80))
def test_random_streams_never_break_the_strapdown_engine(stream: list[dict]) -> None:
    """A rejected packet changes nothing; the covariance stays symmetric and positive."""
    session = VehicleSession(config_from_options({"sensors": "strapdown"}))
    engine = session.engine.filter
    assert isinstance(engine, StrapdownFilter)
    for record in sorted(stream, key=lambda r: r["t"]):
        ins = engine.ins
        before = None if ins is None else (ins.state.copy(), ins.P.copy())
        result = session.add_records([record])
        if result.rejections and before is not None:
            assert engine.ins is not None
            assert np.array_equal(engine.ins.P, before[1])
            assert engine.ins.state.t == before[0].t
        if engine.ins is not None:
            p = engine.ins.P
            assert np.allclose(p, p.T) and np.linalg.eigvalsh(p).min() > 0.0


def _drive_north(seconds: float, fix_east_m: Callable[[float], float],
                 road_distance: RoadDistance | None = None
                 ) -> Iterator[tuple[StrapdownFilter, float, float, list[FusedEstimate]]]:
    """A car driving north at 10 m/s on a level road (IMU 100 Hz, wheel speed 10 Hz), a fix
    a second to 1 m with its course, ``fix_east_m(t)`` east of the truth: after each fix,
    the INS, the fix's time and east offset, and the estimates it gave."""
    frame = LocalFrame.for_point(7.42, 43.73)
    ins = StrapdownFilter(FusionConfig(sensors=SensorConfig.STRAPDOWN), frame,
                          road_distance=road_distance)
    for k in range(int(100 * seconds)):
        t = k / 100.0
        ins.apply(ImuSample(t, gyro_rps=(0.0, 0.0, 0.0), accel_mps2=(0.0, 0.0, 9.81)))
        if k % 10 == 0:
            ins.apply(OdometerSample(t, speed_mps=10.0))
        if k % 100 == 0:
            east = fix_east_m(t)
            lon, lat = frame.to_wgs84(east, 10.0 * t)
            out = ins.apply(GpsFix(t, lat_deg=lat, lon_deg=lon, accuracy_m=1.0,
                                   speed_mps=10.0, heading_rad=0.0))
            yield ins, t, east, out


def test_a_fix_past_the_gate_widens_the_reported_sigma_not_the_ins() -> None:
    """At 30 s the fixes leap 50 m east for 10 s. The INS refuses the leap (a jump); the
    estimate it reports may be off by the leap, so its sigma holds half of it along the leap
    from the first refused fix, while the INS's own covariance stays that of a filter with
    good fixes, and the doubt fades afterwards."""
    reported: dict[float, tuple[float, float]] = {}
    for ins, t, _, out in _drive_north(120.0, lambda t: 50.0 if 30.0 <= t < 40.0 else 0.0):
        for e in out:
            assert ins.ins is not None
            own = ins.ins.position_cov_ned_m2()
            reported[t] = (e.position_sigma_m, math.sqrt((own[0, 0] + own[1, 1]) / 2.0))
    before, first_refused, late = reported[29.0], reported[30.0], reported[119.0]
    assert before[0] < 3.0 and first_refused[1] < 3.0
    # half the leap along it, the mean of two axes (the innovation: the leap, less what
    # the INS moved toward the last good fix)
    assert first_refused[0] >= 0.95 * 50.0 / 2.0 / math.sqrt(2.0)
    assert late[0] < 0.5 * first_refused[0]


def test_a_run_of_fixes_that_leapt_from_the_track_is_refused_not_followed() -> None:
    """At 30 s the fixes leap 50 m east for 40 s (a non-line-of-sight run) and come back.
    The INS kept up with them for 30 s: dead reckoning does not leap, so the run is refused
    whole and the estimate stays on the truth. Its soft gate had taken them inflated after
    three refusals, and the INS drifted toward the run and back (Andorra 2 of the tune
    split: 70 m for 56 s, 39 m rms; now 6.6 m)."""
    off: dict[float, tuple[float, str]] = {}
    for ins, t, _, out in _drive_north(90.0, lambda t: 50.0 if 30.0 <= t < 70.0 else 0.0):
        assert ins.state.gps is not None and out
        off[t] = (math.hypot(out[-1].x_m, out[-1].y_m - 10.0 * t), ins.state.gps.reason)
    assert all(off[t][1].startswith("refused: jumped") for t in range(30, 70)), off
    assert max(off[t][0] for t in range(25, 90)) < 3.0, off
    assert all(off[t][1] == "accepted" for t in range(71, 90)), off


def test_a_refused_jump_onto_the_road_is_followed() -> None:
    """A start inside a non-line-of-sight run: the fixes lie 40 m east of the truth, off the
    road (the line east = 0), for the first 40 s, and the INS aligned and settled there.
    When the true fixes return they are the "jump". Tested against the map (the road
    filter's two tracks: the estimate's 40 m from any road, the jumped one on it), the jump
    is followed within a few seconds; without a map it is refused."""
    def road(east: float, north: float, heading: float, radius: float,
             max_bearing: float) -> float:
        return min(abs(east), radius)

    for road_distance, back_by_s in ((road, 46), (None, None)):
        off: dict[float, float] = {}
        for _, t, _, out in _drive_north(60.0, lambda t: 40.0 if t < 40.0 else 0.0,
                                         road_distance):
            if out and t >= 40.0:
                off[t] = math.hypot(out[-1].x_m, out[-1].y_m - 10.0 * t)
        if back_by_s is None:
            assert min(off.values()) > 30.0, off
        else:
            assert all(off[t] < 3.0 for t in range(back_by_s, 60)), off


def test_an_ins_far_from_fixes_that_agree_aligns_again_from_them() -> None:
    """Fixes that lie 300 m from the INS, farther than any non-line-of-sight error, for
    two seconds: the INS is lost, not they (a long outage on a wrong heading leaves it so).
    It starts over and aligns from them; its soft gate had taken them a metre a fix."""
    off: dict[float, tuple[float, str]] = {}
    for ins, t, east, out in _drive_north(45.0, lambda t: 300.0 if t >= 30.0 else 0.0):
        assert ins.state.gps is not None
        distance = math.inf if not out else math.hypot(out[-1].x_m - east,
                                                       out[-1].y_m - 10.0 * t)
        off[t] = (distance, ins.state.gps.reason)
    assert off[29.0][0] < 3.0
    assert any(reason.startswith("lost") for _, reason in (off[t] for t in (31.0, 32.0, 33.0)))
    assert all(off[t][0] < 3.0 for t in range(36, 45)), off


def test_before_alignment_the_sigma_reaches_the_nearest_road() -> None:
    """A fix of 1 m, 12 m east of the only road, before the INS has a heading: the car is
    on a road, so with the map the fix's sigma is at least that distance
    (:func:`navsvc.fusion.gnss.nearest_road_var_m2`), without one it is its own."""
    frame = LocalFrame.for_point(7.42, 43.73)

    def road_12_m_west(x_m: float, y_m: float, heading_rad: float, radius_m: float,
                       max_bearing_diff_rad: float) -> float:
        return min(abs(x_m + 12.0), radius_m)

    lon, lat = frame.to_wgs84(0.0, 0.0)
    fix = GpsFix(0.0, lat_deg=lat, lon_deg=lon, accuracy_m=1.0)
    config = FusionConfig(sensors=SensorConfig.STRAPDOWN)
    (blind,) = StrapdownFilter(config, frame).apply(fix)
    (seen,) = StrapdownFilter(config, frame, road_distance=road_12_m_west).apply(fix)
    assert not seen.initialized and math.isnan(seen.heading_rad)
    assert blind.position_sigma_m == pytest.approx(1.0)
    assert seen.position_sigma_m == pytest.approx(12.0)


def test_without_fixes_the_sigma_along_the_drive_holds_the_wheels_scale() -> None:
    """Wheels never calibrated (a receiver that sends no speed) may be several percent
    off, an error the INS takes as motion: after 60 s at 10 m/s without fixes the reported
    sigma along the drive (north) holds ``initial_odo_scale_sigma`` of the 600 m driven
    (the INS's own: under a metre). Calibrated by the fixes' speed, the scale's sigma
    shrinks, and so does that share."""
    def sigma_along_at_end_of_gap(receiver_speed: bool) -> tuple[float, float]:
        frame = LocalFrame.for_point(7.42, 43.73)
        ins = StrapdownFilter(FusionConfig(sensors=SensorConfig.STRAPDOWN), frame)
        last: list[FusedEstimate] = []
        for k in range(100 * 90):
            t = k / 100.0
            last = ins.apply(ImuSample(t, gyro_rps=(0.0, 0.0, 0.0),
                                       accel_mps2=(0.0, 0.0, 9.81))) or last
            if k % 10 == 0:
                ins.apply(OdometerSample(t, speed_mps=10.0))
            if k % 100 == 0 and t < 30.0:
                lon, lat = frame.to_wgs84(0.0, 10.0 * t)
                speed, course = (10.0, 0.0) if receiver_speed else (None, None)
                ins.apply(GpsFix(t, lat_deg=lat, lon_deg=lon, accuracy_m=1.0,
                                 speed_mps=speed, heading_rad=course))
        (e,) = last
        driven_m = 10.0 * (e.t - 29.0)  # since the last fix (the wheels' last speed: e.t)
        return math.sqrt(e.position_cov_m2[1, 1]), driven_m

    along, driven_m = sigma_along_at_end_of_gap(receiver_speed=False)
    assert along >= 0.98 * FusionConfig().initial_odo_scale_sigma * driven_m > 25.0
    calibrated_along, _ = sigma_along_at_end_of_gap(receiver_speed=True)
    assert calibrated_along < 0.5 * along


@pytest.mark.parametrize("speed_mps", [4.0, 15.0])
def test_a_heading_from_the_gps_course_is_as_sure_as_a_course_at_that_speed(
        speed_mps: float) -> None:
    """The INS aligns from a course with the road filter's sigma for a course at that speed
    (the receiver's velocity error across the track over the speed, at least 2 degrees), not
    a fixed 10 degrees: too wide on the highway, too narrow at walking pace."""
    frame = LocalFrame.for_point(7.42, 43.73)
    ins = StrapdownFilter(FusionConfig(sensors=SensorConfig.STRAPDOWN), frame)
    ins.apply(ImuSample(0.0, gyro_rps=(0.0, 0.0, 0.0), accel_mps2=(0.0, 0.0, 9.81)))
    lon, lat = frame.to_wgs84(0.0, 0.0)
    out = ins.apply(GpsFix(0.0, lat_deg=lat, lon_deg=lon, accuracy_m=2.0, speed_mps=speed_mps,
                           heading_rad=0.0))
    assert out and out[0].initialized
    expected = max(math.radians(2.0), math.atan2(0.5, speed_mps))
    assert out[0].heading_sigma_rad == pytest.approx(expected, rel=1e-6)


def test_the_gyro_bias_is_taken_from_the_standstill_before_alignment() -> None:
    """A car stands 5 s with a gyro that reads 0.8 deg/s of yaw rate (a MEMS gyro's turn-on
    bias can be a degree a second; the INS's prior sigma is half that), then drives north
    with a GPS course: the INS starts with that bias, surely, and its heading does not turn
    in the 10 s that follow without fixes. Starting from a zero bias, the heading turned 8
    degrees in those 10 s. The half second in which it turns at 30 deg/s before the wheels
    say it moves (their speed comes over a window) is no standstill's."""
    frame = LocalFrame.for_point(7.42, 43.73)
    ins = StrapdownFilter(FusionConfig(sensors=SensorConfig.STRAPDOWN), frame)
    bias_rps = math.radians(0.8)
    gyro = (0.0, 0.0, bias_rps)  # FLU: turning left, as a car does not
    level = (0.0, 0.0, 9.81)
    estimates: list[FusedEstimate] = []
    for k in range(1501):
        t = 0.01 * k
        if k % 10 == 0:
            ins.apply(OdometerSample(t, speed_mps=0.0 if t < 5.0 else 10.0))
        if k == 510:
            lon, lat = frame.to_wgs84(0.0, 0.0)
            ins.apply(GpsFix(t, lat_deg=lat, lon_deg=lon, accuracy_m=2.0, speed_mps=10.0,
                             heading_rad=0.0))
            assert ins.ins is not None
            started = ins.ins.state.gyro_bias_rps.copy(), math.sqrt(ins.ins.P[11, 11])
        turning = (0.0, 0.0, bias_rps + math.radians(30.0)) if 4.5 <= t < 5.0 else gyro
        estimates += ins.apply(ImuSample(t, gyro_rps=turning, accel_mps2=level))
    bias, sigma = started
    assert abs(-bias[2] - bias_rps) < math.radians(0.02) and sigma < math.radians(0.05)
    headings = [math.degrees(e.heading_rad) for e in estimates if e.initialized]
    assert max(abs((h + 180.0) % 360.0 - 180.0) for h in headings) < 1.0, headings


def test_the_constraint_on_a_fresh_alignment_does_not_make_its_heading_surer() -> None:
    """The INS starts with its velocity along the heading it was given, so the velocity's
    direction is as unsure as that heading and errs with it. The non-holonomic constraint (no
    sideways motion) then says nothing of the heading: a heading from a short baseline of
    fixes keeps its sigma for the two seconds without fixes that follow. With the velocity
    taken as independent of the heading, the constraint read the velocity's 0.5 m/s sigma as
    the heading's (12 degrees went to 3 within a second, with no fix in between)."""
    frame = LocalFrame.for_point(7.42, 43.73)
    ins = StrapdownFilter(FusionConfig(sensors=SensorConfig.STRAPDOWN), frame)
    level = (0.0, 0.0, 9.81)  # FLU, at constant speed
    estimates: list[FusedEstimate] = []
    for k in range(601):  # north at 10 m/s; a fix a second without course or speed
        t = 0.01 * k
        if k % 10 == 0:
            ins.apply(OdometerSample(t, speed_mps=10.0))
        if k % 100 == 0 and ins.ins is None:
            lon, lat = frame.to_wgs84(0.0, 10.0 * t)
            estimates += ins.apply(GpsFix(t, lat_deg=lat, lon_deg=lon, accuracy_m=3.0))
        estimates += ins.apply(ImuSample(t, gyro_rps=(0.0, 0.0, 0.0), accel_mps2=level))
    aligned = [e for e in estimates if e.initialized]
    assert len(aligned) >= 3
    assert aligned[0].heading_sigma_rad > math.radians(5.0)  # a short baseline's
    assert all(e.heading_sigma_rad > 0.9 * aligned[0].heading_sigma_rad for e in aligned), \
        [math.degrees(e.heading_sigma_rad) for e in aligned]
