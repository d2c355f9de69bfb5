"""Properties of packet parsing over generated JSON: anything is refused cleanly, and what is
accepted leaves a small canonical record that parses back to the same packet."""

import json
import math
from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st

from navsvc.errors import PacketError
from navsvc.wire.nmea import checksum
from navsvc.wire.packets import MAX_TIME_S, MODELS, parse, parse_record
from tests.wire.test_oncore import ba_frame

SURROGATES = st.sampled_from(["\ud800", "\udfff", "$GPGGA\udc00*00"])
HUGE = st.sampled_from([10**400, -(10**400), 2**1024, 10**15 + 1, 1e308, -1e308,
                        MAX_TIME_S * 1000.0, math.inf, -math.inf, math.nan])
scalars = (st.none() | st.booleans() | st.integers() | HUGE | st.floats()
           | st.text(st.characters(codec=None, exclude_categories=()), max_size=8) | SURROGATES)
json_values = st.recursive(
    scalars, lambda children: st.lists(children, max_size=4)
    | st.dictionaries(st.text(max_size=6), children, max_size=4), max_leaves=30)


def _nest(value: Any, in_lists: list[bool]) -> Any:
    for in_list in in_lists:
        value = [value] if in_list else {"k": value}
    return value


deep_values = st.builds(_nest, json_values, st.lists(st.booleans(), max_size=50))


def _number(lo: float, hi: float) -> st.SearchStrategy[float]:
    """Floats and integers in [lo, hi]: an integer is a valid float on the wire."""
    return st.floats(lo, hi) | st.integers(math.ceil(lo), math.floor(hi))


def _optional(**fields: st.SearchStrategy[Any]) -> st.SearchStrategy[dict[str, Any]]:
    return st.fixed_dictionaries({}, optional=fields)


def _packet(kind: str, required: dict[str, st.SearchStrategy[Any]],
            optional: dict[str, st.SearchStrategy[Any]]) -> st.SearchStrategy[dict[str, Any]]:
    return st.builds(lambda t, req, opt: {"t": t, "kind": kind, **req, **opt},
                     _number(0.0, MAX_TIME_S), st.fixed_dictionaries(required),
                     _optional(**optional))


RATE, ACCEL = _number(-1000.0, 1000.0), _number(-200.0, 200.0)
SENTENCES = [f"${b}*{checksum(b):02X}" for b in (
    "GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,",
    "GPRMC,123519,A,4807.038,S,01131.000,W,022.4,084.4,230394,003.1,W",
    "GPVTG,054.7,T,034.4,M,005.5,N,010.2,K")]
valid_packets = st.one_of(
    _packet("gps", {"lat": _number(-90.0, 90.0), "lon": _number(-180.0, 180.0)},
            {"alt_m": _number(-1000.0, 50_000.0), "speed_mps": _number(0.0, 100.0),
             "heading_deg": _number(0.0, 360.0), "hdop": _number(0.0, 100.0) | st.none(),
             "sats": st.integers(0, 200), "fix": st.sampled_from(["none", "2d", "3d", "rtk"]),
             "accuracy_m": st.floats(0.0, 10_000.0, exclude_min=True)}),
    _packet("imu", {}, {"yaw_rate_dps": RATE, "accel_fwd_mps2": ACCEL, "accel_left_mps2": ACCEL,
                        "gyro_dps": st.lists(RATE, min_size=3, max_size=3),
                        "accel_mps2": st.lists(ACCEL, min_size=3, max_size=3)}
            ).filter(lambda p: len(p) > 2),
    _packet("odometer", {}, {"distance_m": _number(0.0, 1e9), "ticks": st.integers(0, 10**15),
                             "speed_mps": _number(0.0, 100.0)}).filter(lambda p: len(p) > 2),
    _packet("steering", {"angle_deg": _number(-90.0, 90.0)}, {}),
    _packet("nmea", {"sentence": st.sampled_from(SENTENCES)}, {}),
    _packet("oncore", {"hex": st.builds(
        lambda lat, lon, status: ba_frame(lat, lon, status=status).hex(),
        st.floats(-89.9, 89.9), st.floats(-179.9, 179.9), st.integers(0, 255))}, {}))
KNOWN = {name for model in MODELS.values() for name in model.model_fields}
junk = st.dictionaries(st.text(max_size=8).filter(lambda k: k not in KNOWN), deep_values,
                       max_size=3)


@st.composite
def mutated_packets(draw: st.DrawFn) -> dict[str, Any]:
    """A valid packet with one field replaced by any JSON value, or dropped."""
    packet = draw(valid_packets)
    name = draw(st.sampled_from(sorted(packet)))
    if draw(st.booleans()):
        del packet[name]
    else:
        packet[name] = draw(st.one_of(HUGE, SURROGATES, json_values, deep_values))
    return packet


def _depth(value: Any) -> int:
    if isinstance(value, dict):
        return 1 + max(map(_depth, value.values()), default=0)
    if isinstance(value, list):
        return 1 + max(map(_depth, value), default=0)
    return 0


def _check_record(obj: Any) -> None:
    """parse_record refuses ``obj`` with a PacketError, or gives a record that keeps the
    trip log's guarantee."""
    try:
        packet, record = parse_record(obj)
    except PacketError as exc:
        assert exc.reason.code and str(exc).encode("utf-8")
        return
    text = json.dumps(record)
    assert parse(json.loads(text)) == packet
    assert _depth(record) <= 2 and len(text) <= 2000
    assert set(record) <= set(MODELS[record["kind"]].model_fields)


@settings(max_examples=400, deadline=None)
@given(json_values | deep_values | mutated_packets())
def test_anything_is_a_packet_or_a_packet_error(obj: Any) -> None:
    _check_record(obj)


@settings(max_examples=300, deadline=None)
@given(valid_packets, junk)
def test_valid_packets_leave_a_record_that_parses_back(obj: dict[str, Any],
                                                       extra: dict[str, Any]) -> None:
    packet, record = parse_record({**extra, **obj})
    assert record == obj
    _check_record({**extra, **obj})
    assert parse(json.loads(json.dumps(record))) == packet == parse(obj)
