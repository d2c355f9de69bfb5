"""Sensor packets validated in bulk: a whole message in one compiled call (msgspec).

The fast twin of :mod:`navsvc.wire.packets`: the same kinds (``gps``, ``imu``, ``odometer``,
``steering``), the same ranges (its constants), the same strictness (JSON numbers only, no
booleans, an integer fine for a float). It never explains a refusal: when any packet of a
message is not perfectly valid, or has a field the kind does not know, or is of another kind
(``nmea``, ``oncore``), the bulk check fails as a whole and the caller validates that
message packet by packet with :mod:`navsvc.wire.packets`, whose messages (reason, field,
limit) are the service's. So what this module accepts is a subset of what ``packets``
accepts, with equal values (``tests/wire/test_bulk.py`` checks both).

msgspec, not orjson: measured on a message of 10 IMU packets of a simulated drive
(``{"type": "batch", ...}``), decoding the envelope, then the packets straight into typed,
range-checked structs takes 0.7 µs a packet; orjson's ``loads`` then msgspec's ``convert`` of
the dicts 1.6 µs (msgspec's own untyped decode then ``convert``, the same); the standard
library's ``json`` and the pydantic models about 9 µs. msgspec also hands over the packets'
own JSON text (``msgspec.Raw``; for a bare array, the message itself), which the trip log
stores as it came. :func:`decode_message` takes a WebSocket message, :func:`validate_all` a
list of JSON values already parsed (``POST /packets``, the trip log's replay).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Any, Literal

import msgspec

from navsvc.types import Packet as CorePacket
from navsvc.wire import packets
from navsvc.wire.packets import (
    FIX_RANGES,
    MAX_ACCEL_MPS2,
    MAX_DISTANCE_M,
    MAX_RATE_DPS,
    MAX_SPEED_MPS,
    MAX_TICKS,
    MAX_TIME_S,
)

Time = Annotated[float, msgspec.Meta(ge=0.0, le=MAX_TIME_S)]
Rate = Annotated[float, msgspec.Meta(ge=-MAX_RATE_DPS, le=MAX_RATE_DPS)]
Accel = Annotated[float, msgspec.Meta(ge=-MAX_ACCEL_MPS2, le=MAX_ACCEL_MPS2)]
Speed = Annotated[float, msgspec.Meta(ge=0.0, le=MAX_SPEED_MPS)]


def _range(name: str) -> msgspec.Meta:
    low, high = FIX_RANGES[name]
    return msgspec.Meta(ge=low, le=high)


class _Packet(msgspec.Struct, tag_field="kind", forbid_unknown_fields=True):
    t: Time


class Imu(_Packet, tag="imu"):
    yaw_rate_dps: Rate | None = None
    accel_fwd_mps2: Accel | None = None
    accel_left_mps2: Accel | None = None
    gyro_dps: tuple[Rate, Rate, Rate] | None = None
    accel_mps2: tuple[Accel, Accel, Accel] | None = None

    def __post_init__(self) -> None:
        if self.yaw_rate_dps is None and self.accel_fwd_mps2 is None and \
                self.accel_left_mps2 is None and self.gyro_dps is None and \
                self.accel_mps2 is None:
            raise ValueError("no imu field")  # packets.py says which (missing_field)


class Odometer(_Packet, tag="odometer"):
    distance_m: Annotated[float, msgspec.Meta(ge=0.0, le=MAX_DISTANCE_M)] | None = None
    ticks: Annotated[int, msgspec.Meta(ge=0, le=MAX_TICKS)] | None = None
    speed_mps: Speed | None = None

    def __post_init__(self) -> None:
        if self.distance_m is None and self.ticks is None and self.speed_mps is None:
            raise ValueError("no odometer field")


class Steering(_Packet, tag="steering"):
    angle_deg: Annotated[float, msgspec.Meta(ge=-90.0, le=90.0)]


class Gps(_Packet, tag="gps"):
    lat: Annotated[float, msgspec.Meta(ge=-90.0, le=90.0)]
    lon: Annotated[float, msgspec.Meta(ge=-180.0, le=180.0)]
    alt_m: Annotated[float, _range("alt_m")] | None = None
    speed_mps: Speed | None = None
    heading_deg: Annotated[float, msgspec.Meta(ge=0.0, le=360.0)] | None = None
    hdop: Annotated[float, _range("hdop")] | None = None
    sats: Annotated[int, _range("sats")] | None = None
    fix: Literal["none", "2d", "3d", "dgps", "rtk"] | None = None
    accuracy_m: Annotated[float, msgspec.Meta(gt=0.0, le=10_000.0)] | None = None


Packet = Imu | Odometer | Steering | Gps
_MODELS: dict[type, type[packets._Packet]] = {
    Imu: packets.ImuPacket, Odometer: packets.OdometerPacket, Steering: packets.SteeringPacket,
    Gps: packets.GpsPacket}


def core(packet: Packet) -> CorePacket:
    """The core packet (:mod:`navsvc.types`) a valid packet stands for, made by the careful
    parser's own ``core`` (without validating it again)."""
    model = _MODELS[type(packet)]
    return model.model_construct(**msgspec.structs.asdict(packet)).core()


class _Batch(msgspec.Struct):
    """The WebSocket's numbered batch; other fields are ignored, as the route does."""

    type: Literal["batch"]
    seq: Annotated[int, msgspec.Meta(ge=0)]
    packets: msgspec.Raw


_BATCH = msgspec.json.Decoder(_Batch)
_PACKETS = msgspec.json.Decoder(list[Packet])
_ANY = msgspec.json.Decoder()


@dataclass(frozen=True)
class Batch:
    """A message's packets, all valid, with their JSON text as received."""

    packets: list[Packet]
    text: str  # the JSON array of the packets

    def __len__(self) -> int:
        return len(self.packets)

    def records(self) -> list[dict[str, Any]]:
        """The packets as JSON objects (the form the trip log replays)."""
        records: list[dict[str, Any]] = _ANY.decode(self.text)
        return records


def decode_message(text: str | bytes, max_seq: int) -> tuple[int | None, Batch] | None:
    """A WebSocket message of valid packets: a numbered batch ``{"type": "batch", "seq": N,
    "packets": [...]}`` (its number and packets) or an array of packets (None and them);
    None for anything else (the caller's careful path says what is wrong)."""
    try:
        if text[:1] in ("[", b"["):
            raw = text if isinstance(text, str) else text.decode()
            return None, Batch(_PACKETS.decode(raw), raw)
        message = _BATCH.decode(text)
        if message.seq > max_seq:
            return None
        packets = bytes(message.packets)
        return message.seq, Batch(_PACKETS.decode(packets), packets.decode())
    except Exception:  # noqa: BLE001 (anything it cannot take: the careful path says what)
        return None


def decode_batch(text: str | bytes, max_seq: int) -> tuple[int, Batch] | None:
    """:func:`decode_message` of a numbered batch only."""
    decoded = decode_message(text, max_seq)
    if decoded is None or decoded[0] is None:
        return None
    return decoded[0], decoded[1]


def validate_all(records: list[Any]) -> list[Packet] | None:
    """Every record valid, as packets; None when any is not (or is of another kind)."""
    try:
        packets: list[Packet] = msgspec.convert(records, list[Packet])
    except Exception:  # noqa: BLE001 (a ValidationError, or e.g. a lone surrogate in a text)
        return None
    return packets


def validate_one(record: Any) -> Packet | None:
    """A valid record as a packet; None when it is not (or is of another kind)."""
    try:
        packet: Packet = msgspec.convert(record, Packet)
    except Exception:  # noqa: BLE001
        return None
    return packet
