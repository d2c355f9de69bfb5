"""NMEA 0183 sentences → GPS packets: GGA and RMC (position), VTG (velocity only).

The checksum (XOR of the characters between ``$`` and ``*``) must match when present. Any
talker id is accepted (GP, GN, GL, ...). Time comes from the packet's ``t``, not the sentence.
A sentence is ASCII text of at most ``MAX_SENTENCE_CHARS`` (the standard's limit is 82) and its
numbers must be finite.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import reduce

from navsvc.errors import PacketError, RejectReason
from navsvc.types import GpsFix, GpsFixType, GpsVelocity

KNOT_MPS = 1852.0 / 3600.0
MAX_SENTENCE_CHARS = 256
_GGA_QUALITY = {0: GpsFixType.NONE, 1: GpsFixType.FIX_3D, 2: GpsFixType.DGPS,
                4: GpsFixType.RTK, 5: GpsFixType.DGPS, 6: GpsFixType.NONE}


def checksum(body: str) -> int:
    """XOR of the characters of a sentence body (between ``$`` and ``*``)."""
    return reduce(lambda acc, ch: acc ^ ord(ch), body, 0)


def parse_sentence(sentence: str, t: float) -> GpsFix | GpsVelocity:
    """Parse one sentence; raise PacketError naming what is wrong."""
    if len(sentence) > MAX_SENTENCE_CHARS:
        raise PacketError(RejectReason.MALFORMED,
                          f"sentence is {len(sentence)} characters (at most {MAX_SENTENCE_CHARS})")
    if not sentence.isascii():
        raise PacketError(RejectReason.MALFORMED, "an NMEA sentence is ASCII text")
    text = sentence.strip()
    if not text.startswith(("$", "!")) or len(text) < 7:
        raise PacketError(RejectReason.MALFORMED, f"not an NMEA sentence: {text[:20]!r}")
    body, star, given = text[1:].partition("*")
    if star:
        try:
            expected = int(given[:2], 16)
        except ValueError:
            raise PacketError(RejectReason.BAD_CHECKSUM, f"checksum {given!r} is not hex") \
                from None
        if checksum(body) != expected:
            raise PacketError(RejectReason.BAD_CHECKSUM,
                              f"computed {checksum(body):02X}, sentence says {given[:2]}")
    fields = body.split(",")
    kind = fields[0][-3:]
    parser = _PARSERS.get(kind)
    if parser is None:
        raise PacketError(RejectReason.UNSUPPORTED_SENTENCE,
                          f"{fields[0]} (supported: GGA, RMC, VTG)")
    try:
        return parser(fields, t)
    except (ValueError, IndexError) as exc:
        raise PacketError(RejectReason.MALFORMED, f"{fields[0]}: {exc}") from None


def _coordinate(value: str, hemisphere: str, degree_digits: int) -> float:
    if not value:
        raise ValueError("empty latitude/longitude")
    degrees = float(value[:degree_digits]) + float(value[degree_digits:]) / 60.0
    if hemisphere in ("S", "W"):
        degrees = -degrees
    elif hemisphere not in ("N", "E"):
        raise ValueError(f"hemisphere {hemisphere!r}")
    limit = 90.0 if degree_digits == 2 else 180.0
    if not abs(degrees) <= limit:
        raise ValueError(f"coordinate {degrees} out of range")
    return degrees


def _optional(value: str) -> float | None:
    if not value:
        return None
    number = float(value)
    if not math.isfinite(number):
        raise ValueError(f"{value!r} is not a finite number")
    return number


def _gga(f: list[str], t: float) -> GpsFix:
    quality = int(f[6] or 0)
    fix = _GGA_QUALITY.get(quality, GpsFixType.FIX_3D)
    return GpsFix(
        t=t, lat_deg=_coordinate(f[2], f[3], 2), lon_deg=_coordinate(f[4], f[5], 3),
        alt_m=_optional(f[9]), hdop=_optional(f[8]),
        sats=int(f[7]) if f[7] else None, fix=fix, status_ok=quality > 0)


def _rmc(f: list[str], t: float) -> GpsFix:
    speed = _optional(f[7])
    course = _optional(f[8])
    return GpsFix(
        t=t, lat_deg=_coordinate(f[3], f[4], 2), lon_deg=_coordinate(f[5], f[6], 3),
        speed_mps=None if speed is None else speed * KNOT_MPS,
        heading_rad=None if course is None else math.radians(course % 360.0),
        status_ok=f[2] == "A")


def _vtg(f: list[str], t: float) -> GpsVelocity:
    course = _optional(f[1])
    knots, kmh = _optional(f[5]), _optional(f[7])
    if knots is None and kmh is None:
        raise ValueError("no speed")
    speed = knots * KNOT_MPS if knots is not None else (kmh or 0.0) / 3.6
    return GpsVelocity(t=t, speed_mps=speed,
                       heading_rad=None if course is None else math.radians(course % 360.0))


_PARSERS: dict[str, Callable[[list[str], float], GpsFix | GpsVelocity]] = {
    "GGA": _gga, "RMC": _rmc, "VTG": _vtg}
