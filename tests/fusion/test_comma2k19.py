"""Real data: the comma2k19 segment (tests/data/comma2k19, MIT) through the fusion engine."""

import math

import numpy as np
import pytest

from navsvc.fusion import FusionConfig, SensorConfig
from navsvc.session import SessionConfig, VehicleSession
from navsvc.sim.comma2k19 import WHEELBASE_M, Gnss, read_segment
from navsvc.sim.evaluate import evaluate
from navsvc.wire.positions import position_json
from tests.conftest import DATA

KINDS = {SensorConfig.GYRO_ODOMETER: {"imu", "odometer", "gps"},
         SensorConfig.STEERING_ODOMETER: {"steering", "odometer", "gps"}}


def test_segment_converts_to_valid_packets() -> None:
    drive = read_segment(DATA / "comma2k19")
    kinds = {r["kind"] for r in drive}
    assert kinds == {"truth", "gps", "imu", "odometer", "steering"}
    session = VehicleSession()
    result = session.add_records(drive)
    assert not result.rejections


@pytest.mark.parametrize("sensors", list(KINDS))
def test_twenty_second_outage_on_real_data(sensors: SensorConfig) -> None:
    drive = read_segment(DATA / "comma2k19", Gnss(1.0, outage=(20.0, 20.0)))
    session = VehicleSession(SessionConfig(FusionConfig(sensors=sensors,
                                                        wheelbase_m=WHEELBASE_M)))
    result = session.add_records([r for r in drive if r["kind"] in KINDS[sensors]])
    assert session.frame is not None
    e = evaluate(drive, [position_json(p, session.frame) for p in result.positions])
    (outage,) = e.outages
    assert outage.distance_m > 300  # about 20 m/s on the highway
    assert outage.drift_pct < 3.0
    assert e.fused.rms_m < 2.5 * e.raw_gps.rms_m
    assert e.heading_rms_deg < 1.0


def test_strapdown_on_the_phone_imu_needs_wheel_speed_through_an_outage() -> None:
    drive = read_segment(DATA / "comma2k19", Gnss(1.0, outage=(20.0, 20.0)))
    drift = {}
    for kinds in ({"imu", "gps"}, {"imu", "odometer", "gps"}):
        session = VehicleSession(SessionConfig(FusionConfig(sensors=SensorConfig.STRAPDOWN)))
        result = session.add_records([r for r in drive if r["kind"] in kinds])
        assert not result.rejections
        assert session.frame is not None
        e = evaluate(drive, [position_json(p, session.frame) for p in result.positions])
        drift["odometer" in kinds] = e.outages[0].drift_pct
    assert drift[True] < 3.0  # wheel speed holds it (1.8 % measured)
    assert drift[False] > 3.0 * drift[True]  # a phone IMU alone drifts (22 % measured)


def _pitch_of_the_track_in_the_camera_deg() -> float:
    """How far the car's velocity points below the camera's forward axis (median over the
    segment), from the truth's velocity and attitude: the phone's mount pitch."""
    q = np.load(DATA / "comma2k19/global_pose/frame_orientations")
    v_ecef = np.load(DATA / "comma2k19/global_pose/frame_velocities")
    pitches = []
    for (w, x, y, z), v in zip(q, v_ecef):
        r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                      [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                      [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
        forward, _, down = r.T @ v
        pitches.append(math.degrees(math.atan2(-down, forward)))
    return float(np.median(pitches))


def test_strapdown_learns_how_the_phone_is_pitched_in_the_car() -> None:
    """The phone's IMU is pitched about 4 degrees in the car; the INS learns it from the
    non-holonomic constraint (which holds for the car's axes), and with it the phone IMU alone
    beats the 1 Hz fixes. Taken as level, the constraint pitched the attitude until gravity
    leaked into the velocity: 4.07 m against the fixes' 1.52 m."""
    drive = read_segment(DATA / "comma2k19", Gnss(1.0))
    session = VehicleSession(SessionConfig(FusionConfig(sensors=SensorConfig.STRAPDOWN)))
    result = session.add_records([r for r in drive if r["kind"] in {"imu", "gps"}])
    assert session.frame is not None
    e = evaluate(drive, [position_json(p, session.frame) for p in result.positions])
    assert e.fused.rms_m < e.raw_gps.rms_m
    ins = session.engine.filter.state.ins
    truth_deg = _pitch_of_the_track_in_the_camera_deg()
    assert 3.0 < truth_deg < 5.0
    assert abs(math.degrees(ins.state.mount_pitch_rad) - truth_deg) < 1.0


def test_strapdown_weighs_the_cars_wheel_speed_as_one_a_second() -> None:
    """The CAN wheel speed comes at 89 Hz and its error changes slowly; taken as 89
    independent speeds a second it made the INS with wheel speed worse than the 1 Hz fixes
    (1.59 m against 1.52 m), and worse than without it (0.91 m)."""
    drive = read_segment(DATA / "comma2k19", Gnss(1.0))
    session = VehicleSession(SessionConfig(FusionConfig(sensors=SensorConfig.STRAPDOWN)))
    result = session.add_records([r for r in drive if r["kind"] in {"imu", "odometer", "gps"}])
    assert not result.rejections and session.frame is not None
    e = evaluate(drive, [position_json(p, session.frame) for p in result.positions])
    assert e.fused.rms_m < e.raw_gps.rms_m
