"""Sensor packets from JSON (interfaces.md): validate, convert degrees to radians.

``parse(obj)`` returns a :mod:`navsvc.types` packet or raises :class:`PacketError` naming the
field and the limit. Unknown extra fields are ignored.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from navsvc.errors import PacketError, RejectReason
from navsvc.types import GpsFix, GpsFixType, ImuSample, OdometerSample, Packet, SteeringSample
from navsvc.wire import nmea, oncore

MAX_SPEED_MPS = 100.0
MAX_RATE_DPS = 1000.0
MAX_ACCEL_MPS2 = 200.0

Time = Annotated[float, Field(ge=0.0, allow_inf_nan=False)]
Finite = Annotated[float, Field(allow_inf_nan=False)]


class _Packet(BaseModel):
    model_config = ConfigDict(extra="ignore", frozen=True)
    t: Time


class GpsPacket(_Packet):
    kind: Literal["gps"] = "gps"
    lat: Annotated[float, Field(ge=-90.0, le=90.0, allow_inf_nan=False)]
    lon: Annotated[float, Field(ge=-180.0, le=180.0, allow_inf_nan=False)]
    alt_m: Annotated[float, Field(ge=-1000.0, le=50_000.0, allow_inf_nan=False)] | None = None
    speed_mps: Annotated[float, Field(ge=0.0, le=MAX_SPEED_MPS, allow_inf_nan=False)] | None \
        = None
    heading_deg: Annotated[float, Field(ge=0.0, le=360.0, allow_inf_nan=False)] | None = None
    hdop: Annotated[float, Field(ge=0.0, le=100.0, allow_inf_nan=False)] | None = None
    sats: Annotated[int, Field(ge=0, le=200)] | None = None
    fix: Literal["none", "2d", "3d", "dgps", "rtk"] | None = None
    accuracy_m: Annotated[float, Field(gt=0.0, le=10_000.0, allow_inf_nan=False)] | None = None


Rate = Annotated[float, Field(ge=-MAX_RATE_DPS, le=MAX_RATE_DPS, allow_inf_nan=False)]
Accel = Annotated[float, Field(ge=-MAX_ACCEL_MPS2, le=MAX_ACCEL_MPS2, allow_inf_nan=False)]


class ImuPacket(_Packet):
    kind: Literal["imu"] = "imu"
    yaw_rate_dps: Rate | None = None
    accel_fwd_mps2: Accel | None = None
    accel_left_mps2: Accel | None = None
    gyro_dps: tuple[Rate, Rate, Rate] | None = None
    accel_mps2: tuple[Accel, Accel, Accel] | None = None


class OdometerPacket(_Packet):
    kind: Literal["odometer"] = "odometer"
    distance_m: Annotated[float, Field(ge=0.0, allow_inf_nan=False)] | None = None
    ticks: Annotated[int, Field(ge=0)] | None = None
    speed_mps: Annotated[float, Field(ge=0.0, le=MAX_SPEED_MPS, allow_inf_nan=False)] | None \
        = None


class SteeringPacket(_Packet):
    kind: Literal["steering"] = "steering"
    angle_deg: Annotated[float, Field(ge=-90.0, le=90.0, allow_inf_nan=False)]


MODELS: dict[str, type[_Packet]] = {"gps": GpsPacket, "imu": ImuPacket,
                                    "odometer": OdometerPacket, "steering": SteeringPacket}


def parse(obj: Any) -> Packet:
    """One JSON object → a packet; raises PacketError saying what is wrong."""
    if not isinstance(obj, dict):
        raise PacketError(RejectReason.MALFORMED, f"expected a JSON object, got {_type(obj)}")
    kind = obj.get("kind")
    if kind in ("nmea", "oncore"):
        return _parse_text(obj, kind)
    model = MODELS.get(kind) if isinstance(kind, str) else None
    if model is None:
        known = ", ".join([*MODELS, "nmea", "oncore"])
        raise PacketError(RejectReason.UNKNOWN_KIND, f"kind {kind!r} (known: {known})")
    try:
        packet = model.__pydantic_validator__.validate_python(obj)
    except ValidationError as exc:
        raise _packet_error(exc) from None
    return _to_core(packet)


def _parse_text(obj: dict[str, Any], kind: str) -> Packet:
    """An ``nmea`` sentence or an ``oncore`` hex message, with its ``t``."""
    t = obj.get("t")
    if t is None:
        raise PacketError(RejectReason.MISSING_FIELD, "t is required")
    if not isinstance(t, (int, float)) or isinstance(t, bool) or not math.isfinite(t) or t < 0:
        raise PacketError(RejectReason.OUT_OF_RANGE, f"t={t!r} (must be a finite number >= 0)")
    field_name = "sentence" if kind == "nmea" else "hex"
    text = obj.get(field_name)
    if not isinstance(text, str):
        raise PacketError(RejectReason.MISSING_FIELD, f"{field_name} is required (a string)")
    if kind == "nmea":
        return nmea.parse_sentence(text, float(t))
    return oncore.parse_ba(text, float(t))


def _packet_error(exc: ValidationError) -> PacketError:
    err = exc.errors()[0]
    where = ".".join(str(p) for p in err["loc"]) or "packet"
    kind = err["type"]
    if kind == "missing":
        return PacketError(RejectReason.MISSING_FIELD, f"{where} is required")
    if kind == "finite_number":
        return PacketError(RejectReason.NOT_FINITE, f"{where} must be finite")
    if kind in ("greater_than_equal", "less_than_equal", "greater_than", "less_than"):
        limit = err.get("ctx", {})
        ops = {"ge": ">=", "le": "<=", "gt": ">", "lt": "<"}
        bound = ", ".join(f"{ops.get(k, k)} {v}" for k, v in limit.items())
        return PacketError(RejectReason.OUT_OF_RANGE,
                           f"{where}={err.get('input')!r} (must be {bound})")
    return PacketError(RejectReason.MALFORMED, f"{where}: {err['msg']}")


def _to_core(p: _Packet) -> Packet:
    if isinstance(p, ImuPacket):  # the most frequent first
        return _imu_to_core(p)
    if isinstance(p, GpsPacket):
        return GpsFix(
            t=p.t, lat_deg=p.lat, lon_deg=p.lon, alt_m=p.alt_m, speed_mps=p.speed_mps,
            heading_rad=None if p.heading_deg is None else math.radians(p.heading_deg % 360.0),
            hdop=p.hdop, sats=p.sats, fix=None if p.fix is None else GpsFixType(p.fix),
            accuracy_m=p.accuracy_m)
    if isinstance(p, OdometerPacket):
        if p.distance_m is None and p.ticks is None and p.speed_mps is None:
            raise PacketError(RejectReason.MISSING_FIELD,
                              "odometer needs distance_m, ticks or speed_mps")
        return OdometerSample(t=p.t, distance_m=p.distance_m, ticks=p.ticks,
                              speed_mps=p.speed_mps)
    assert isinstance(p, SteeringPacket)
    return SteeringSample(t=p.t, angle_rad=math.radians(p.angle_deg))


def _imu_to_core(p: ImuPacket) -> ImuSample:
    """The z-up rate and the planar accelerations from their own fields, else from the
    6-axis ones."""
    gyro, accel = p.gyro_dps, p.accel_mps2
    yaw = p.yaw_rate_dps if p.yaw_rate_dps is not None else None if gyro is None else gyro[2]
    fwd = p.accel_fwd_mps2 if p.accel_fwd_mps2 is not None else \
        None if accel is None else accel[0]
    left = p.accel_left_mps2 if p.accel_left_mps2 is not None else \
        None if accel is None else accel[1]
    if yaw is None and fwd is None and left is None:  # so no 6-axis field either
        raise PacketError(RejectReason.MISSING_FIELD,
                          "imu needs yaw_rate_dps, accel_fwd_mps2, accel_left_mps2, "
                          "gyro_dps or accel_mps2")
    return ImuSample(
        t=p.t, yaw_rate_rps=None if yaw is None else math.radians(yaw), accel_fwd_mps2=fwd,
        accel_left_mps2=left,
        gyro_rps=None if gyro is None else
        (math.radians(gyro[0]), math.radians(gyro[1]), math.radians(gyro[2])),
        accel_mps2=accel)


def _type(obj: Any) -> str:
    names = {list: "an array", str: "a string", type(None): "null"}
    return names.get(type(obj), type(obj).__name__)
