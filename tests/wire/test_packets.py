import json
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from navsvc.errors import PacketError
from navsvc.types import GpsFix, GpsFixType, GpsVelocity, ImuSample, OdometerSample
from navsvc.wire.nmea import checksum, parse_sentence
from navsvc.wire.packets import MAX_TICKS, MAX_TIME_S, MODELS, parse, parse_record

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


# Faults found by hostile clients, one test (or table) each.

@pytest.mark.parametrize(("packet", "detail"), [
    ({"t": 1, "kind": "gps", "lat": "43.74", "lon": 7.42}, "lat must be a number, got a string"),
    ({"t": True, "kind": "imu", "yaw_rate_dps": 1.0}, "t must be a number, got a boolean"),
    ({"t": 1, "kind": "imu", "yaw_rate_dps": "1.5"},
     "yaw_rate_dps must be a number, got a string"),
    ({"t": 1, "kind": "imu", "gyro_dps": [0, "0", 1]},
     "gyro_dps[1] must be a number, got a string"),
    ({"t": 1, "kind": "imu", "accel_mps2": [0, 0, False]},
     "accel_mps2[2] must be a number, got a boolean"),
    ({"t": 1, "kind": "gps", "lat": 1, "lon": 1, "sats": True},
     "sats must be an integer, got a boolean"),
    ({"t": 1, "kind": "odometer", "ticks": "12"}, "ticks must be an integer, got a string"),
    ({"t": 1, "kind": "odometer", "ticks": 12.0}, "ticks must be an integer, got a float"),
    ({"t": "5", "kind": "nmea", "sentence": GGA}, "t must be a number, got a string"),
])
def test_silent_coercion_is_refused(packet: dict[str, object], detail: str) -> None:
    with pytest.raises(PacketError) as exc:
        parse(packet)
    assert exc.value.reason.code == "malformed" and exc.value.detail == detail


def test_silent_coercion_fix_keeps_ints_for_floats_and_arrays() -> None:
    p = parse({"t": 2, "kind": "imu", "gyro_dps": [0, 0, 10], "accel_mps2": [1, 2, 9]})
    assert isinstance(p, ImuSample) and p.t == 2.0 and p.accel_mps2 == (1.0, 2.0, 9.0)
    assert parse({"t": 0, "kind": "odometer", "ticks": 7}) == OdometerSample(t=0.0, ticks=7)


@pytest.mark.parametrize(("t", "code", "detail"), [
    (1e308, "out_of_range", "t=1e+308 (must be <= 4102444800.0)"),
    (1.7e12, "out_of_range",
     "t=1700000000000.0 (must be <= 4102444800.0; milliseconds sent as seconds?)"),
    (-0.5, "out_of_range", "t=-0.5 (must be >= 0.0)"),
    (float("inf"), "not_finite", "t must be finite"),
])
@pytest.mark.parametrize("rest", [
    {"kind": "imu", "yaw_rate_dps": 1.0},
    {"kind": "nmea", "sentence": GGA},
    {"kind": "oncore", "hex": "4040"},
])
def test_time_window(t: float, code: str, detail: str, rest: dict[str, object]) -> None:
    with pytest.raises(PacketError) as exc:
        parse({"t": t, **rest})
    assert exc.value.reason.code == code
    assert exc.value.detail == detail


def test_time_window_edges_are_accepted() -> None:
    assert MAX_TIME_S == 4_102_444_800.0
    for t in (0, MAX_TIME_S, 1_764_600_000.123):
        assert parse({"t": t, "kind": "steering", "angle_deg": 0}).t == t
        assert parse({"t": t, "kind": "nmea", "sentence": GGA}).t == t


@pytest.mark.parametrize(("packet", "detail"), [
    ({"t": 1, "kind": "odometer", "ticks": 10**400},
     "ticks=<integer of ~401 digits> (must be <= 1000000000000000)"),
    ({"t": 1, "kind": "odometer", "ticks": MAX_TICKS + 1},
     "ticks=1000000000000001 (must be <= 1000000000000000)"),
    ({"t": 1, "kind": "odometer", "distance_m": 1e300},
     "distance_m=1e+300 (must be <= 1000000000.0)"),
    ({"t": 1, "kind": "gps", "lat": 10**400, "lon": 0}, "lat=<integer of ~401 digits> (too large)"),
    ({"t": 10**400, "kind": "imu", "yaw_rate_dps": 0}, "t=<integer of ~401 digits> (too large)"),
    ({"t": 10**400, "kind": "nmea", "sentence": GGA}, "t=<integer of ~401 digits> (too large)"),
    ({"t": 1, "kind": "steering", "angle_deg": 10**300}, "angle_deg=<integer of ~301 digits> "
     "(must be <= 90.0)"),
])
def test_huge_numbers_are_out_of_range(packet: dict[str, object], detail: str) -> None:
    with pytest.raises(PacketError) as exc:
        parse(packet)
    assert exc.value.reason.code == "out_of_range" and exc.value.detail == detail


VALID = {"gps": {"t": 1, "kind": "gps", "lat": 1, "lon": 1},
         "imu": {"t": 1, "kind": "imu", "yaw_rate_dps": 1},
         "odometer": {"t": 1, "kind": "odometer", "speed_mps": 1},
         "steering": {"t": 1, "kind": "steering", "angle_deg": 1},
         "nmea": {"t": 1, "kind": "nmea", "sentence": GGA},
         "oncore": {"t": 1, "kind": "oncore", "hex": "4040"}}
NUMERIC = [(kind, name) for kind, model in MODELS.items() for name in model.model_fields
           if name not in ("kind", "fix", "sentence", "hex")]


@pytest.mark.parametrize(("kind", "name"), NUMERIC)
@pytest.mark.parametrize("huge", [10**300, -(10**300), 10**400, -(10**400)])
def test_huge_numbers_every_numeric_field_has_a_finite_range(kind: str, name: str,
                                                             huge: int) -> None:
    value = [huge, 0, 0] if name in ("gyro_dps", "accel_mps2") else huge
    with pytest.raises(PacketError) as exc:
        parse({**VALID[kind], name: value})
    assert exc.value.reason.code == "out_of_range"


@pytest.mark.parametrize(("packet", "detail"), [
    ({"t": 1, "kind": "nmea", "sentence": "$" + "A" * 256},
     "sentence is 257 characters (at most 256)"),
    ({"t": 1, "kind": "oncore", "hex": "40" * 513}, "hex is 1026 characters (at most 1024)"),
    ({"t": 1, "kind": "nmea", "sentence": GGA[:10] + "\ud800" + GGA[10:]},
     "an NMEA sentence is ASCII text"),
    ({"t": 1, "kind": "oncore", "hex": "4040\ud800"}, "hex: not a hexadecimal string"),
])
def test_string_fields_are_bounded(packet: dict[str, object], detail: str) -> None:
    with pytest.raises(PacketError) as exc:
        parse(packet)
    assert exc.value.reason.code == "malformed" and exc.value.detail == detail
    str(exc.value).encode("utf-8")  # fit for a JSON reply


def test_string_fields_limit_is_inclusive() -> None:
    with pytest.raises(PacketError) as exc:
        parse({"t": 1, "kind": "nmea", "sentence": "$GPXXX," + "1" * 249})
    assert exc.value.reason.code == "unsupported_sentence"


def test_nmea_numbers_must_be_finite() -> None:
    body = "GPRMC,123519,A,4807.038,N,01131.000,E,nan,084.4,230394,003.1,W"
    with pytest.raises(PacketError) as exc:
        parse_sentence(f"${body}*{checksum(body):02X}", 0.0)
    assert exc.value.detail == "GPRMC: 'nan' is not a finite number"


def test_parse_record_keeps_known_fields_as_received() -> None:
    deep: object = []
    for _ in range(963):
        deep = [deep]
    obj = {"t": 3, "kind": "imu", "gyro_dps": [0, 0, 10], "note": "x", "deep": deep,
           "accel_fwd_mps2": None}
    packet, record = parse_record(obj)
    assert record == {"t": 3, "kind": "imu", "gyro_dps": [0, 0, 10], "accel_fwd_mps2": None}
    assert packet == parse(obj) == parse(json.loads(json.dumps(record)))


def test_parse_record_of_nmea_is_t_kind_sentence() -> None:
    packet, record = parse_record({"t": 1.25, "kind": "nmea", "sentence": GGA, "x": {"a": [1]}})
    assert record == {"t": 1.25, "kind": "nmea", "sentence": GGA}
    assert parse(json.loads(json.dumps(record))) == packet


def test_parse_record_of_every_kind_round_trips() -> None:
    for kind, obj in VALID.items():
        if kind == "oncore":
            continue
        packet, record = parse_record({**obj, "unknown": [[{"x": 1}]]})
        assert record == obj and parse(json.loads(json.dumps(record))) == packet


@pytest.mark.parametrize("sentence", [
    "$GPVTG,054.7,T,034.4,M,1e308,N,010.2,K",  # found by the WebSocket fuzzer
    "$GPRMC,123519,A,4807.038,N,01131.000,E,1000000,084.4,230394,003.1,W",
    "$GPGGA,123519,4807.038,N,01131.000,E,1,08,900.0,545.4,M,46.9,M,,",  # HDOP 900
    "$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,99999.0,M,46.9,M,,",  # 100 km up
])
def test_nmea_fixes_are_held_to_the_json_packets_ranges(sentence: str) -> None:
    body = sentence[1:]
    checksum = 0
    for ch in body:
        checksum ^= ord(ch)
    with pytest.raises(PacketError) as info:
        parse({"t": 1.0, "kind": "nmea", "sentence": f"{sentence}*{checksum:02X}"})
    assert info.value.reason.code == "out_of_range"
