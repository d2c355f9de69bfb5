"""Request and response bodies of the HTTP API (pydantic; they also make the OpenAPI schema).

Sensor packets are not modelled here: each is parsed by :func:`navsvc.wire.packets.parse`, so
that one bad packet rejects only itself (interfaces.md has their fields).
"""

from __future__ import annotations

from typing import Any, Literal, Self

from pydantic import BaseModel, ConfigDict, Field, model_validator

from navsvc.session import SessionOptions


class SessionCreate(SessionOptions):
    """A vehicle's sensors and how to fuse them: :class:`navsvc.session.SessionOptions` and
    the vehicle's id; the profile may also name one the server was started with."""

    vehicle_id: str = Field(min_length=1, max_length=128, examples=["car-17"])
    profile: dict[str, Any] | str | None = Field(  # type: ignore[assignment]
        None, description="tuned parameters (`navsvc tune`): a profile inline (the document, "
        "or its 'parameters' object of dotted names to values), or the name of a profile the "
        "server was started with (`navsvc serve --profiles DIR`: the file's stem)")

    def options(self) -> dict[str, Any]:
        """The session's options as the trip log keeps them (a named profile still named)."""
        return self.model_dump(mode="json", exclude={"vehicle_id"}, exclude_none=True)


class SessionInfo(BaseModel):
    id: str
    vehicle_id: str
    map: str
    options: dict[str, Any]
    created_unix: float
    packets_accepted: int
    packets_rejected: int
    position: dict[str, Any] | None = Field(
        None, description="latest matched position (interfaces.md), null before the first fix")


class SessionList(BaseModel):
    sessions: list[SessionInfo]
    workers_unreachable: list[int] = Field(
        default_factory=list, description="behind the balancer: workers that did not answer, "
        "whose sessions are missing from the list (one restarting after a crash, say)")


class RejectedPacket(BaseModel):
    index: int = Field(description="position of the packet in the batch (from 0)")
    code: str = Field(description="reason code, e.g. missing_field, out_of_range")
    message: str


class BatchReply(BaseModel):
    accepted: int
    rejected: list[RejectedPacket]
    positions: list[dict[str, Any]] = Field(
        description="matched positions produced by the batch (interfaces.md), oldest first")
    duplicate: bool = Field(
        False, description="true when this numbered batch had been applied already: the reply "
                          "is its first one, and nothing was applied again")


class TracePoint(BaseModel):
    lat: float = Field(ge=-90, le=90)
    lon: float = Field(ge=-180, le=180)
    t: float | None = Field(None, description="seconds; default: the point's index")


class MatchRequest(BaseModel):
    """A whole trace: either ``points``, or the text of a trace file with its ``format``."""

    model_config = ConfigDict(extra="forbid")

    points: list[TracePoint] | None = None
    trace: str | None = Field(None, description="GPX, GeoJSON, CSV or JSON Lines text")
    format: Literal["gpx", "geojson", "csv", "jsonl"] | None = None
    sigma_m: float = Field(10.0, gt=0, le=500, description="GPS error, metres")

    @model_validator(mode="after")
    def _one_source(self) -> Self:
        if (self.points is None) == (self.trace is None):
            raise ValueError("give exactly one of points or trace")
        if self.trace is not None and self.format is None:
            raise ValueError("format is required with trace")
        return self


class ErrorDetail(BaseModel):
    code: str
    message: str
    fields: list[dict[str, Any]] | None = None


class ErrorBody(BaseModel):
    error: ErrorDetail
