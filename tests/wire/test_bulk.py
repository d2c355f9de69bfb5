"""Bulk validation (msgspec) against the careful parser (pydantic): what the fast path takes,
the careful one takes too, as the same packet; and the valid packets of the four kinds it
knows do take the fast path."""

from __future__ import annotations

import json
from typing import Any

from hypothesis import assume, given, settings
from hypothesis import strategies as st

from navsvc.errors import PacketError
from navsvc.session import MAX_CLIENT_SEQ
from navsvc.wire import bulk
from navsvc.wire.packets import parse, parse_record
from tests.wire.test_packet_properties import (
    deep_values,
    json_values,
    junk,
    mutated_packets,
    valid_packets,
)

BULK_KINDS = {"gps", "imu", "odometer", "steering"}


def _careful(obj: Any) -> Any:
    try:
        return parse(obj)
    except PacketError as exc:
        return exc


@settings(max_examples=500, deadline=None)
@given(json_values | deep_values | mutated_packets() | valid_packets)
def test_what_bulk_accepts_the_careful_parser_accepts_as_the_same_packet(obj: Any) -> None:
    fast = bulk.validate_one(obj)
    if fast is None:
        return
    assert bulk.core(fast) == _careful(obj)
    assert bulk.validate_all([obj, obj]) == [fast, fast]


def _bulk_kinds(packets: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The packets of the kinds bulk knows (a filter inside the list strategy discarded so
    many draws that Hypothesis's health check failed)."""
    kept = [p for p in packets if p["kind"] in BULK_KINDS]
    assume(kept)
    return kept


@settings(max_examples=300, deadline=None)
@given(st.lists(valid_packets, min_size=1, max_size=12))
def test_valid_packets_take_the_fast_path_with_their_own_text(
        drawn: list[dict[str, Any]]) -> None:
    packets = _bulk_kinds(drawn)
    assert bulk.validate_all(packets) is not None
    text = json.dumps({"type": "batch", "seq": 7, "packets": packets, "note": "ignored"})
    decoded = bulk.decode_batch(text, MAX_CLIENT_SEQ)
    assert decoded is not None
    seq, batch = decoded
    assert seq == 7 and len(batch) == len(packets)
    assert [bulk.core(p) for p in batch.packets] == [parse(p) for p in packets]
    assert batch.records() == packets == [parse_record(p)[1] for p in packets]
    bare = bulk.decode_message(json.dumps(packets).encode(), MAX_CLIENT_SEQ)
    assert bare is not None and bare[0] is None and bare[1].packets == batch.packets
    assert json.loads(bare[1].text) == packets


@settings(max_examples=200, deadline=None)
@given(st.lists(valid_packets, min_size=1, max_size=5), mutated_packets() | json_values,
       junk.filter(bool))
def test_a_bad_packet_or_an_unknown_field_sends_the_message_the_careful_way(
        drawn: list[dict[str, Any]], bad: Any, extra: dict[str, Any]) -> None:
    """One packet the careful parser refuses, or one with a field it would drop, and the
    message is not taken whole (the careful path says why, or logs the canonical record)."""
    packets = _bulk_kinds(drawn)
    if bulk.validate_one(bad) is None:
        assert bulk.validate_all([*packets, bad]) is None
        assert bulk.decode_batch(json.dumps({"type": "batch", "seq": 1,
                                             "packets": [*packets, bad]}), 10) is None
    assert bulk.validate_all([*packets[:-1], {**extra, **packets[-1]}]) is None


def test_only_numbered_batches_within_the_limit_are_decoded_fast() -> None:
    packets = [{"t": 1.0, "kind": "imu", "yaw_rate_dps": 0.5}]
    assert bulk.decode_batch(json.dumps({"type": "batch", "seq": 3, "packets": packets}),
                             3) is not None
    for message in ({"type": "batch", "seq": 4, "packets": packets},
                    {"type": "batch", "seq": -1, "packets": packets},
                    {"type": "batch", "seq": True, "packets": packets},
                    {"type": "ping"}, packets, packets[0]):
        assert bulk.decode_batch(json.dumps(message), 3) is None
    assert bulk.decode_message(json.dumps(packets), 3) == (None, bulk.Batch(
        [bulk.Imu(t=1.0, yaw_rate_dps=0.5)], json.dumps(packets)))
    assert bulk.decode_message(json.dumps(packets[0]), 3) is None
    assert bulk.decode_message("[1]", 3) is None
    assert bulk.decode_batch(b"\xff\xfe", 3) is None
    assert bulk.decode_batch('{"type": "batch", "seq": 1, "packets": [{"t": NaN, '
                             '"kind": "imu", "yaw_rate_dps": 1}]}', 3) is None
