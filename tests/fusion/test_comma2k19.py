"""Real data: the comma2k19 segment (tests/data/comma2k19, MIT) through the fusion engine."""

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
