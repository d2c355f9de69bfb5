"""Sensor packets from JSON (interfaces.md): validate, convert degrees to radians.

``parse(obj)`` returns a :mod:`navsvc.types` packet or raises :class:`PacketError` naming the
field and the limit; ``parse_record(obj)`` also returns the canonical record to log. Numbers
must be JSON numbers (no strings, no booleans; an integer is fine for a float) and every one
has a finite range; text fields have a maximum length. Unknown extra fields are ignored and
left out of the record.
"""

from __future__ import annotations

import math
from abc import abstractmethod
from typing import Annotated, Any, Literal, TypeVar

from pydantic import BaseModel, ConfigDict, Field, Strict, ValidationError

from navsvc.errors import PacketError, RejectReason
from navsvc.types import GpsFix, GpsFixType, ImuSample, OdometerSample, Packet, SteeringSample
from navsvc.wire import nmea, oncore

MAX_TIME_S = 4_102_444_800.0  # 2100-01-01 as Unix seconds; t is Unix or drive-relative seconds
MAX_SPEED_MPS = 100.0
MAX_RATE_DPS = 1000.0
MAX_ACCEL_MPS2 = 200.0
MAX_DISTANCE_M = 1e9  # cumulative odometer distance
MAX_TICKS = 10**15  # cumulative odometer ticks
# ranges of a GPS fix, whichever format it came in (JSON, NMEA, Oncore)
FIX_RANGES: dict[str, tuple[float, float]] = {
    "speed_mps": (0.0, MAX_SPEED_MPS), "alt_m": (-1000.0, 50_000.0), "hdop": (0.0, 100.0),
    "sats": (0, 200)}

Time = Annotated[float, Strict(), Field(ge=0.0, le=MAX_TIME_S, allow_inf_nan=False)]
Rate = Annotated[float, Strict(), Field(ge=-MAX_RATE_DPS, le=MAX_RATE_DPS, allow_inf_nan=False)]
Accel = Annotated[float, Strict(),
                  Field(ge=-MAX_ACCEL_MPS2, le=MAX_ACCEL_MPS2, allow_inf_nan=False)]
Speed = Annotated[float, Strict(), Field(ge=0.0, le=MAX_SPEED_MPS, allow_inf_nan=False)]


class _Packet(BaseModel):
    model_config = ConfigDict(extra="ignore", frozen=True)
    t: Time

    @abstractmethod
    def core(self) -> Packet:
        """The core packet this wire packet stands for."""


class GpsPacket(_Packet):
    kind: Literal["gps"] = "gps"
    lat: Annotated[float, Strict(), Field(ge=-90.0, le=90.0, allow_inf_nan=False)]
    lon: Annotated[float, Strict(), Field(ge=-180.0, le=180.0, allow_inf_nan=False)]
    alt_m: Annotated[float, Strict(), Field(ge=FIX_RANGES["alt_m"][0],
                                            le=FIX_RANGES["alt_m"][1], allow_inf_nan=False)] \
        | None = None
    speed_mps: Speed | None = None
    heading_deg: Annotated[float, Strict(), Field(ge=0.0, le=360.0, allow_inf_nan=False)] \
        | None = None
    hdop: Annotated[float, Strict(), Field(ge=FIX_RANGES["hdop"][0], le=FIX_RANGES["hdop"][1],
                                           allow_inf_nan=False)] | None = None
    sats: Annotated[int, Strict(), Field(ge=FIX_RANGES["sats"][0],
                                         le=FIX_RANGES["sats"][1])] | None = None
    fix: Literal["none", "2d", "3d", "dgps", "rtk"] | None = None
    accuracy_m: Annotated[float, Strict(), Field(gt=0.0, le=10_000.0, allow_inf_nan=False)] \
        | None = None

    def core(self) -> GpsFix:
        return GpsFix(
            t=self.t, lat_deg=self.lat, lon_deg=self.lon, alt_m=self.alt_m,
            speed_mps=self.speed_mps,
            heading_rad=None if self.heading_deg is None else
            math.radians(self.heading_deg % 360.0),
            hdop=self.hdop, sats=self.sats, fix=None if self.fix is None else GpsFixType(self.fix),
            accuracy_m=self.accuracy_m)


class ImuPacket(_Packet):
    kind: Literal["imu"] = "imu"
    yaw_rate_dps: Rate | None = None
    accel_fwd_mps2: Accel | None = None
    accel_left_mps2: Accel | None = None
    gyro_dps: tuple[Rate, Rate, Rate] | None = None  # a JSON array: the tuple itself is lax
    accel_mps2: tuple[Accel, Accel, Accel] | None = None

    def core(self) -> ImuSample:
        """The z-up rate and the planar accelerations from their own fields, else from the
        6-axis ones."""
        gyro, accel = self.gyro_dps, self.accel_mps2
        yaw = self.yaw_rate_dps if self.yaw_rate_dps is not None else \
            None if gyro is None else gyro[2]
        fwd = self.accel_fwd_mps2 if self.accel_fwd_mps2 is not None else \
            None if accel is None else accel[0]
        left = self.accel_left_mps2 if self.accel_left_mps2 is not None else \
            None if accel is None else accel[1]
        if yaw is None and fwd is None and left is None:  # so no 6-axis field either
            raise PacketError(RejectReason.MISSING_FIELD,
                              "imu needs yaw_rate_dps, accel_fwd_mps2, accel_left_mps2, "
                              "gyro_dps or accel_mps2")
        return ImuSample(
            t=self.t, yaw_rate_rps=None if yaw is None else math.radians(yaw),
            accel_fwd_mps2=fwd, accel_left_mps2=left,
            gyro_rps=None if gyro is None else
            (math.radians(gyro[0]), math.radians(gyro[1]), math.radians(gyro[2])),
            accel_mps2=accel)


class OdometerPacket(_Packet):
    kind: Literal["odometer"] = "odometer"
    distance_m: Annotated[float, Strict(), Field(ge=0.0, le=MAX_DISTANCE_M, allow_inf_nan=False)] \
        | None = None
    ticks: Annotated[int, Strict(), Field(ge=0, le=MAX_TICKS)] | None = None
    speed_mps: Speed | None = None

    def core(self) -> OdometerSample:
        if self.distance_m is None and self.ticks is None and self.speed_mps is None:
            raise PacketError(RejectReason.MISSING_FIELD,
                              "odometer needs distance_m, ticks or speed_mps")
        return OdometerSample(t=self.t, distance_m=self.distance_m, ticks=self.ticks,
                              speed_mps=self.speed_mps)


class SteeringPacket(_Packet):
    kind: Literal["steering"] = "steering"
    angle_deg: Annotated[float, Strict(), Field(ge=-90.0, le=90.0, allow_inf_nan=False)]

    def core(self) -> SteeringSample:
        return SteeringSample(t=self.t, angle_rad=math.radians(self.angle_deg))


class NmeaPacket(_Packet):
    kind: Literal["nmea"] = "nmea"
    sentence: Annotated[str, Strict()]  # at most nmea.MAX_SENTENCE_CHARS, checked there

    def core(self) -> Packet:
        return in_json_ranges(nmea.parse_sentence(self.sentence, self.t))


class OncorePacket(_Packet):
    kind: Literal["oncore"] = "oncore"
    hex: Annotated[str, Strict()]  # at most oncore.MAX_HEX_CHARS, checked there

    def core(self) -> GpsFix:
        return in_json_ranges(oncore.parse_ba(self.hex, self.t))


PacketT = TypeVar("PacketT", bound=Packet)


def in_json_ranges(packet: PacketT) -> PacketT:
    """A fix decoded from NMEA or Oncore, held to the ranges of the JSON ``gps`` packet (an
    RMC speed of 1e308 knots was accepted, and turned the filter's state to NaN)."""
    for name, (low, high) in FIX_RANGES.items():
        value = getattr(packet, name, None)
        if value is not None and not low <= value <= high:
            raise PacketError(RejectReason.OUT_OF_RANGE,
                              f"{name}={_show(value)} (must be from {low:g} to {high:g})")
    return packet


MODELS: dict[str, type[_Packet]] = {
    "gps": GpsPacket, "imu": ImuPacket, "odometer": OdometerPacket, "steering": SteeringPacket,
    "nmea": NmeaPacket, "oncore": OncorePacket}
_FIELDS = {kind: frozenset(model.model_fields) for kind, model in MODELS.items()}


def parse(obj: Any) -> Packet:
    """One JSON value → a packet; raises PacketError saying what is wrong."""
    return _validate(obj).core()


def parse_record(obj: Any) -> tuple[Packet, dict[str, Any]]:
    """One JSON value → the packet and its canonical record for the trip log.

    The record holds ``t``, ``kind`` and the other known fields of the kind present in
    ``obj``, with their values as received, and nothing else: JSON of depth at most 2 and
    bounded size, which parses back to an equal packet.
    """
    packet = _validate(obj).core()
    known = _FIELDS[obj["kind"]]
    if known.issuperset(obj):  # the usual case, and the fast one
        return packet, dict(obj)
    return packet, {name: value for name, value in obj.items() if name in known}


def _validate(obj: Any) -> _Packet:
    if not isinstance(obj, dict):
        raise PacketError(RejectReason.MALFORMED, f"expected a JSON object, got {_type(obj)}")
    kind = obj.get("kind")
    model = MODELS.get(kind) if isinstance(kind, str) else None
    if model is None:
        raise PacketError(RejectReason.UNKNOWN_KIND,
                          f"kind {_show(kind)} (known: {', '.join(MODELS)})")
    try:
        packet: _Packet = model.__pydantic_validator__.validate_python(obj)
    except ValidationError as exc:
        raise _packet_error(exc) from None
    return packet


_EXPECTED = {"float_type": "a number", "int_type": "an integer", "string_type": "a string",
             "tuple_type": "an array"}
_OPS = {"ge": ">=", "le": "<=", "gt": ">", "lt": "<"}


def _packet_error(exc: ValidationError) -> PacketError:
    err = exc.errors(include_url=False)[0]
    where = "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in err["loc"])[1:] \
        or "packet"
    kind, value = err["type"], err["input"]
    if kind == "missing":
        return PacketError(RejectReason.MISSING_FIELD, f"{where} is required")
    if kind == "finite_number":
        return PacketError(RejectReason.NOT_FINITE, f"{where} must be finite")
    if kind == "float_type" and _is_int(value):  # beyond the largest float
        return PacketError(RejectReason.OUT_OF_RANGE, f"{where}={_show(value)} (too large)")
    if kind in _EXPECTED:
        return PacketError(RejectReason.MALFORMED,
                           f"{where} must be {_EXPECTED[kind]}, got {_type(value)}")
    if kind in ("greater_than_equal", "less_than_equal", "greater_than", "less_than"):
        bound = ", ".join(f"{_OPS[k]} {v}" for k, v in err["ctx"].items())
        if where == "t" and MAX_TIME_S < value <= MAX_TIME_S * 1000.0:
            bound += "; milliseconds sent as seconds?"
        return PacketError(RejectReason.OUT_OF_RANGE, f"{where}={_show(value)} (must be {bound})")
    return PacketError(RejectReason.MALFORMED, f"{where}: {err['msg']}")


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _show(value: Any) -> str:
    """A value as a message shows it: a number or text (cut), else its type; an enormous
    integer by its size."""
    if _is_int(value) and value.bit_length() > 64:
        return f"<integer of ~{int(value.bit_length() * math.log10(2)) + 1} digits>"
    if isinstance(value, str):
        return repr(value) if len(value) <= 40 else f"{value[:40]!r}..."
    return repr(value) if isinstance(value, (int, float)) else f"<{_type(value)}>"


def _type(obj: Any) -> str:
    names = {list: "an array", dict: "an object", str: "a string", bool: "a boolean",
             int: "an integer", float: "a float", type(None): "null"}
    return names.get(type(obj), type(obj).__name__)
