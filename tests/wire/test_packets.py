import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from navsvc.errors import PacketError
from navsvc.types import GpsFix, GpsFixType, GpsVelocity, ImuSample
from navsvc.wire.nmea import checksum, parse_sentence
from navsvc.wire.packets import parse

GGA = "$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47"


def test_gps_packet_degrees_to_radians() -> None:
    p = parse({"t": 1.5, "kind": "gps", "lat": 43.7, "lon": 7.42, "heading_deg": 90,
               "speed_mps": 5, "fix": "rtk", "extra": "ignored"})
    assert isinstance(p, GpsFix)
    assert p.heading_rad == pytest.approx(math.pi / 2) and p.fix == GpsFixType.RTK


def test_imu_six_axis_gives_yaw_rate() -> None:
    p = parse({"t": 0, "kind": "imu", "gyro_dps": [0, 0, 10], "accel_mps2": [1, 2, 9.8]})
    assert isinstance(p, ImuSample)
    assert p.yaw_rate_rps == pytest.approx(math.radians(10))
    assert (p.accel_fwd_mps2, p.accel_left_mps2) == (1, 2)


@pytest.mark.parametrize(("packet", "code", "message"), [
    ({"t": 1, "kind": "gps", "lat": 95, "lon": 0}, "out_of_range",
     "a value is out of range: lat=95 (must be <= 90.0)"),
    ({"t": 1, "kind": "gps", "lon": 0}, "missing_field",
     "a required field is missing: lat is required"),
    ({"t": float("nan"), "kind": "imu", "yaw_rate_dps": 1}, "not_finite",
     "a value is NaN or infinite: t must be finite"),
    ({"t": 1, "kind": "gps", "lat": 1, "lon": 1, "speed_mps": -1}, "out_of_range",
     "a value is out of range: speed_mps=-1 (must be >= 0.0)"),
    ({"t": 1, "kind": "teleport"}, "unknown_kind",
     "unknown packet kind: kind 'teleport' (known: gps, imu, odometer, steering, nmea, oncore)"),
    ([1, 2], "malformed",
     "packet is not a JSON object with the fields of its kind: expected a JSON object, "
     "got an array"),
    ({"t": 1, "kind": "imu"}, "missing_field",
     "a required field is missing: imu needs yaw_rate_dps, accel_fwd_mps2, accel_left_mps2, "
     "gyro_dps or accel_mps2"),
    ({"t": 1, "kind": "nmea", "sentence": GGA[:-2] + "48"}, "bad_checksum",
     "sentence or message checksum does not match: computed 47, sentence says 48"),
    ({"t": 1, "kind": "nmea", "sentence": "$GPGSV,1,1,00*79"}, "unsupported_sentence",
     "NMEA sentence type not supported: GPGSV (supported: GGA, RMC, VTG)"),
])
def test_rejections_exact(packet: object, code: str, message: str) -> None:
    with pytest.raises(PacketError) as exc:
        parse(packet)
    assert exc.value.reason.code == code
    assert str(exc.value) == message


def test_nmea_gga_rmc_vtg() -> None:
    gga = parse_sentence(GGA, 1.0)
    assert isinstance(gga, GpsFix)
    assert (gga.lat_deg, gga.lon_deg) == pytest.approx((48.1173, 11.516666667))
    assert (gga.sats, gga.hdop, gga.alt_m) == (8, 0.9, 545.4)
    body = "GPRMC,123519,A,4807.038,S,01131.000,W,022.4,084.4,230394,003.1,W"
    rmc = parse_sentence(f"${body}*{checksum(body):02X}", 2.0)
    assert isinstance(rmc, GpsFix)
    assert rmc.lat_deg < 0 and rmc.lon_deg < 0
    assert rmc.speed_mps == pytest.approx(22.4 * 1852 / 3600)
    assert rmc.heading_rad == pytest.approx(math.radians(84.4))
    body = "GPVTG,054.7,T,034.4,M,005.5,N,010.2,K"
    vtg = parse_sentence(f"${body}*{checksum(body):02X}", 3.0)
    assert isinstance(vtg, GpsVelocity) and vtg.speed_mps == pytest.approx(5.5 * 1852 / 3600)


def test_nmea_void_fix_is_not_ok() -> None:
    body = "GPRMC,123519,V,4807.038,N,01131.000,E,,,230394,,"
    assert not parse_sentence(f"${body}*{checksum(body):02X}", 0.0).status_ok


json_values = st.recursive(
    st.none() | st.booleans() | st.floats() | st.integers() | st.text(max_size=5),
    lambda children: st.lists(children, max_size=3)
    | st.dictionaries(st.text(max_size=5), children, max_size=3), max_leaves=8)


@settings(deadline=None)
@given(st.dictionaries(st.sampled_from(["t", "kind", "lat", "lon", "speed_mps", "sentence",
                                        "yaw_rate_dps", "distance_m", "angle_deg"]),
                       json_values | st.sampled_from(["gps", "imu", "nmea", "odometer"])))
def test_random_objects_parse_or_reject_cleanly(obj: dict[str, object]) -> None:
    try:
        parse(obj)
    except PacketError as exc:
        assert exc.reason.code and str(exc)
