"""Oncore @@Ba frames built byte by byte from the layout in the seed's appendix C."""

import json
import math
import struct
from functools import reduce

import pytest
from hypothesis import given
from hypothesis import strategies as st

from navsvc.errors import PacketError
from navsvc.types import GpsFix, GpsFixType
from navsvc.wire.packets import parse, parse_record

GOOD_STATUS = 0x30  # 2D and 3D fix, nothing bad


def ba_frame(lat_deg: float = 43.7384, lon_deg: float = 7.4246, speed_mps: float = 12.34,
             heading_deg: float = 271.5, dop: float = 1.3, tracked: int = 6,
             status: int = GOOD_STATUS, height_msl_m: float = 52.0) -> bytes:
    body = bytes([11, 23]) + struct.pack(">H", 1998) + bytes([14, 5, 59])
    body += struct.pack(">I", 250_000_000)
    body += struct.pack(">ii", round(lat_deg * 3_600_000), round(lon_deg * 3_600_000))
    body += struct.pack(">ii", round((height_msl_m + 48.0) * 100), round(height_msl_m * 100))
    body += struct.pack(">HH", round(speed_mps * 100), round(heading_deg * 10))
    body += struct.pack(">H", round(dop * 10)) + bytes([0, 8, tracked])
    body += bytes([5, 8, 180, 0x80]) * 6 + bytes([status])
    payload = b"Ba" + body
    check = reduce(lambda a, b: a ^ b, payload, 0)
    return b"@@" + payload + bytes([check]) + b"\r\n"


def test_frame_layout_is_68_bytes() -> None:
    assert len(ba_frame()) == 68


def test_decodes_position_velocity_and_status() -> None:
    p = parse({"t": 7.0, "kind": "oncore", "hex": ba_frame().hex()})
    assert isinstance(p, GpsFix)
    assert p.t == 7.0
    assert p.lat_deg == pytest.approx(43.7384, abs=1e-6)
    assert p.lon_deg == pytest.approx(7.4246, abs=1e-6)
    assert p.speed_mps == pytest.approx(12.34)
    assert p.heading_rad == pytest.approx(math.radians(271.5))
    assert p.hdop == pytest.approx(1.3) and p.sats == 6 and p.alt_m == pytest.approx(52.0)
    assert p.status_ok and p.fix == GpsFixType.FIX_3D


@pytest.mark.parametrize(("status", "ok"), [
    (0x30, True), (0x34, True), (0x31, False), (0x32, False), (0x70, False),
    (0x20, False), (0x10, False), (0x00, False), (0xB0, True),
])
def test_seed_status_rule(status: int, ok: bool) -> None:
    p = parse({"t": 0, "kind": "oncore", "hex": ba_frame(status=status).hex()})
    assert isinstance(p, GpsFix) and p.status_ok is ok


def test_differential_bit_means_dgps() -> None:
    p = parse({"t": 0, "kind": "oncore", "hex": ba_frame(status=0x34).hex()})
    assert isinstance(p, GpsFix) and p.fix == GpsFixType.DGPS


@pytest.mark.parametrize(("frame", "code", "fragment"), [
    (ba_frame()[:-3] + bytes([ba_frame()[-3] ^ 1]) + b"\r\n", "bad_checksum", "computed"),
    (ba_frame()[:40], "malformed", "Oncore @@Ba message too short: 40 bytes, needs 68"),
    (ba_frame() + b"\0", "malformed", "@@Ba is 68 bytes, got 69"),
    (b"@@Ea" + ba_frame()[4:], "unsupported_sentence", "@@Ba"),
    (ba_frame(heading_deg=400.0), "out_of_range", "heading"),
])
def test_bad_frames_are_rejected(frame: bytes, code: str, fragment: str) -> None:
    with pytest.raises(PacketError) as info:
        parse({"t": 0, "kind": "oncore", "hex": frame.hex()})
    assert info.value.reason.code == code and fragment in str(info.value)


def test_not_hex_and_missing_field() -> None:
    with pytest.raises(PacketError, match="hexadecimal"):
        parse({"t": 0, "kind": "oncore", "hex": "zz"})
    with pytest.raises(PacketError, match="hex is required"):
        parse({"t": 0, "kind": "oncore"})


@given(st.binary(min_size=0, max_size=80))
def test_random_bytes_never_crash(data: bytes) -> None:
    try:
        parse({"t": 0, "kind": "oncore", "hex": (b"@@Ba" + data).hex()})
    except PacketError:
        pass


@given(st.floats(-89.9, 89.9), st.floats(-179.9, 179.9), st.floats(0, 100),
       st.floats(0, 359.9))
def test_round_trip(lat: float, lon: float, speed: float, heading: float) -> None:
    p = parse({"t": 0, "kind": "oncore",
               "hex": ba_frame(lat, lon, speed_mps=speed, heading_deg=heading).hex()})
    assert isinstance(p, GpsFix)
    assert p.lat_deg == pytest.approx(lat, abs=1e-6) and p.lon_deg == pytest.approx(lon, abs=1e-6)
    assert p.speed_mps == pytest.approx(speed, abs=0.006)


def test_speeds_are_held_to_the_json_packets_range() -> None:
    """@@Ba can say up to 514 m/s; a car's fix above the JSON packet's 100 m/s is refused."""
    with pytest.raises(PacketError, match="speed_mps"):
        parse({"t": 0, "kind": "oncore", "hex": ba_frame(speed_mps=150.0).hex()})


@pytest.mark.parametrize(("hex_text", "n"), [("", 0), ("40", 1), ("404042", 3)])
def test_too_short_message_is_not_an_unsupported_sentence(hex_text: str, n: int) -> None:
    with pytest.raises(PacketError) as info:
        parse({"t": 0, "kind": "oncore", "hex": hex_text})
    assert info.value.reason.code == "malformed"
    assert info.value.detail == f"Oncore @@Ba message too short: {n} bytes, needs 68"


def test_spaced_hex_is_read() -> None:
    spaced = " ".join(f"{b:02x}" for b in ba_frame())
    assert len(spaced) <= 1024
    assert parse({"t": 0, "kind": "oncore", "hex": spaced}) == \
        parse({"t": 0, "kind": "oncore", "hex": ba_frame().hex()})


def test_parse_record_of_oncore_is_t_kind_hex() -> None:
    obj = {"t": 2, "kind": "oncore", "hex": ba_frame().hex(), "channel": [[1]]}
    packet, record = parse_record(obj)
    assert record == {"t": 2, "kind": "oncore", "hex": ba_frame().hex()}
    assert parse(json.loads(json.dumps(record))) == packet
