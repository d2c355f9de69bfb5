"""Motorola Oncore ``@@Ba`` binary messages → GPS fixes (seed thesis, appendix C).

The 68-byte ``@@Ba`` message (Oncore User's Guide 1996), big-endian::

    @@Ba                        4  message id
    m d yy h m s                7  date (yy: 2 bytes) and time
    ffff                        4  fractional second [ns]
    aaaa oooo                   8  latitude, longitude [milliarcseconds, signed]
    hhhh mmmm                   8  height over the ellipsoid and over MSL [cm, signed]
    vv hh                       4  speed [cm/s], heading [0.1 deg]
    dd t                        3  DOP [0.1], DOP type (0: PDOP in 3D, 1: HDOP in 2D); PDOP
                                   is an upper bound of HDOP, so either is used as HDOP
    n t                         2  satellites visible, tracked
    6 x (i m s d)              24  per channel: id, mode, signal, status
    s                           1  receiver status byte
    C                           1  checksum: XOR of every byte from ``B`` up to before ``C``
    CR LF                       2

Receiver status bits: 7 propagate mode, 6 poor geometry (DOP > 20), 5 3D fix, 4 2D fix
(altitude hold), 3 acquiring, 2 differential, 1 fewer than 3 satellites visible, 0 bad almanac.
The seed's rule: a fix is bad if bit 0, 1 or 6 is set, or if bit 4 or 5 is clear.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from functools import reduce

from navsvc.errors import PacketError, RejectReason
from navsvc.types import GpsFix, GpsFixType

MESSAGE_LENGTH = 68
MAX_HEX_CHARS = 1024  # of the hex text, which may space its bytes
_BODY = struct.Struct(">BBHBBBIiiiiHHHBBB24sB")  # from month to the status byte
_MAS_PER_DEG = 3_600_000.0

BAD_STATUS_BITS = 0x43  # bad almanac, too few satellites, poor geometry
REQUIRED_STATUS_BITS = 0x30  # 2D and 3D fix (the seed requires both)


@dataclass(frozen=True)
class OncoreStatus:
    """The receiver status byte, decoded."""

    byte: int

    @property
    def ok(self) -> bool:
        return not (self.byte & BAD_STATUS_BITS) and \
            (self.byte & REQUIRED_STATUS_BITS) == REQUIRED_STATUS_BITS

    @property
    def fix(self) -> GpsFixType:
        if self.byte & 0x04 and self.byte & 0x20:
            return GpsFixType.DGPS
        if self.byte & 0x20:
            return GpsFixType.FIX_3D
        return GpsFixType.FIX_2D if self.byte & 0x10 else GpsFixType.NONE


def checksum(payload: bytes) -> int:
    """XOR of the bytes from the message id letter ``B`` up to the checksum."""
    return reduce(lambda acc, b: acc ^ b, payload, 0)


def parse_ba(hex_text: str, t: float) -> GpsFix:
    """Decode one hex-encoded ``@@Ba`` message; raise PacketError naming what is wrong."""
    if len(hex_text) > MAX_HEX_CHARS:
        raise PacketError(RejectReason.MALFORMED,
                          f"hex is {len(hex_text)} characters (at most {MAX_HEX_CHARS})")
    try:
        raw = bytes.fromhex(hex_text.strip())
    except ValueError:
        raise PacketError(RejectReason.MALFORMED, "hex: not a hexadecimal string") from None
    if len(raw) >= 4 and raw[:4] != b"@@Ba":
        raise PacketError(RejectReason.UNSUPPORTED_SENTENCE,
                          f"expected an @@Ba message, got {raw[:4]!r}")
    if len(raw) < MESSAGE_LENGTH:
        raise PacketError(RejectReason.MALFORMED, f"Oncore @@Ba message too short: "
                          f"{len(raw)} bytes, needs {MESSAGE_LENGTH}")
    if len(raw) > MESSAGE_LENGTH:
        raise PacketError(RejectReason.MALFORMED,
                          f"@@Ba is {MESSAGE_LENGTH} bytes, got {len(raw)}")
    if raw[-2:] != b"\r\n":
        raise PacketError(RejectReason.MALFORMED, "@@Ba must end with CR LF")
    expected = checksum(raw[2:-3])
    if raw[-3] != expected:
        raise PacketError(RejectReason.BAD_CHECKSUM,
                          f"computed {expected:02X}, message says {raw[-3]:02X}")
    (_month, _day, _year, _h, _m, _s, _ns, lat_mas, lon_mas, _h_ell_cm, h_msl_cm, speed_cms,
     heading_ddeg, dop_tenths, _dop_type, _visible, tracked, _channels, status_byte) = \
        _BODY.unpack(raw[4:-3])
    lat, lon = lat_mas / _MAS_PER_DEG, lon_mas / _MAS_PER_DEG
    if abs(lat) > 90.0 or abs(lon) > 180.0 or heading_ddeg > 3599 or speed_cms > 51_400:
        raise PacketError(RejectReason.OUT_OF_RANGE,
                          f"lat={lat:.6f} lon={lon:.6f} heading={heading_ddeg / 10:g} deg "
                          f"speed={speed_cms / 100:g} m/s (beyond the @@Ba limits)")
    status = OncoreStatus(status_byte)
    return GpsFix(t=t, lat_deg=lat, lon_deg=lon, alt_m=h_msl_cm / 100.0,
                  speed_mps=speed_cms / 100.0, heading_rad=math.radians(heading_ddeg / 10.0),
                  hdop=dop_tenths / 10.0, sats=tracked,
                  fix=status.fix, status_ok=status.ok)
