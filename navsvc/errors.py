"""Errors of the navsvc package, and the one table of reasons a packet is rejected.

::

    NavsvcError                anything navsvc refuses to do
    ├── PacketError            one packet cannot be used (carries a RejectReason)
    ├── ConfigError            impossible parameters (refused in constructors)
    ├── TraceError             a trace file or request that cannot be matched
    ├── SessionNotFound        no such session, or not visible with this API key
    ├── BatchAlreadyApplied    a resent numbered batch whose reply is no longer kept
    ├── LimitExceeded          a configured limit (sessions per key, ...) would be passed
    └── TripLogInUse           another server has the trip log open (navsvc.triplog)

A rejected packet never changes any state; the caller reports ``Rejection(index, reason,
detail)`` and carries on with the next packet.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass


class RejectReason(enum.Enum):
    """Why a packet was refused: (code, message, HTTP status)."""

    MALFORMED = ("malformed", "packet is not a JSON object with the fields of its kind", 422)
    UNKNOWN_KIND = ("unknown_kind", "unknown packet kind", 422)
    MISSING_FIELD = ("missing_field", "a required field is missing", 422)
    OUT_OF_RANGE = ("out_of_range", "a value is out of range", 422)
    NOT_FINITE = ("not_finite", "a value is NaN or infinite", 422)
    TIME_BACKWARDS = ("time_backwards", "packet is older than the reorder window allows", 409)
    BAD_CHECKSUM = ("bad_checksum", "sentence or message checksum does not match", 422)
    UNSUPPORTED_SENTENCE = ("unsupported_sentence", "NMEA sentence type not supported", 422)
    NOT_CONFIGURED = ("not_configured", "sensor not used by this session's configuration", 422)
    UNUSABLE = ("unusable", "the filter could not use this packet (it was not applied)", 422)

    def __init__(self, code: str, message: str, http_status: int) -> None:
        self.code = code
        self.message = message
        self.http_status = http_status


@dataclass(frozen=True)
class Rejection:
    """One packet refused: its index in the request, the reason, and what exactly was wrong."""

    index: int
    reason: RejectReason
    detail: str

    def to_json(self) -> dict[str, object]:
        return {"index": self.index, "code": self.reason.code,
                "message": f"{self.reason.message}: {self.detail}"}


class NavsvcError(Exception):
    """Base of every error navsvc raises."""


class PacketError(NavsvcError):
    """A packet that cannot be used."""

    def __init__(self, reason: RejectReason, detail: str) -> None:
        super().__init__(f"{reason.message}: {detail}")
        self.reason = reason
        self.detail = detail


class ConfigError(NavsvcError):
    """Impossible configuration parameters."""


class TraceError(NavsvcError):
    """A trace that cannot be read or matched."""


class SessionNotFound(NavsvcError):
    """No session with this id is visible to the caller."""


class BatchAlreadyApplied(NavsvcError):
    """A numbered batch at or below the session's last number, too old to answer again."""


class LimitExceeded(NavsvcError):
    """A request would pass a configured limit."""


class TripLogInUse(NavsvcError):
    """Another server has this trip log open."""
