"""Request and response bodies of the HTTP API (pydantic; they also make the OpenAPI schema).

Sensor packets are not modelled here: each is parsed by :func:`navsvc.wire.packets.parse`, so
that one bad packet rejects only itself (interfaces.md has their fields).
"""

from __future__ import annotations

from typing import Any, Literal, Self

from pydantic import BaseModel, ConfigDict, Field, model_validator

from navsvc.fusion import GpsMode, Integration, Mechanisation, SensorConfig


class SessionCreate(BaseModel):
    """A vehicle's sensors and how to fuse them."""

    model_config = ConfigDict(extra="forbid")

    vehicle_id: str = Field(min_length=1, max_length=128, examples=["car-17"])
    sensors: SensorConfig = Field(SensorConfig.GYRO_ODOMETER, description="sensor configuration")
    fusion: GpsMode = Field(GpsMode.EKF, description="how GPS is fused: ekf, rules or fuzzy")
    map_feedback: bool | None = Field(
        None, description="feed confident matches back into the filter as a road constraint "
        "(bounds drift in GPS outages); default: on wherever the sensor configuration allows "
        "it (all but strapdown)")
    ticks_per_m: float | None = Field(None, gt=0, le=10_000,
                                      description="odometer ticks per metre")
    wheelbase_m: float | None = Field(None, gt=0.5, le=20, description="for steering sensors")
    gps_uere_m: float | None = Field(None, gt=0, le=100,
                                     description="GPS error per unit of HDOP, metres")
    ins_integration: Integration | None = Field(
        None, description="strapdown: feedback (default), feedforward or direct "
                          "(the paper's three EKF integrations)")
    ins_mechanisation: Mechanisation | None = Field(
        None, description="strapdown: first_order (default) or rk4")
    imu_mounting_rpy_deg: tuple[float, float, float] | None = Field(
        None, description="strapdown: roll, pitch, yaw of the IMU axes in the vehicle, "
                          "degrees")
    gps_lever_arm_m: tuple[float, float, float] | None = Field(
        None, description="strapdown: GPS antenna from the IMU, forward/right/down, metres")
    profile: dict[str, Any] | str | None = Field(
        None, description="tuned parameters (`navsvc tune`): a profile inline (the document, "
        "or its 'parameters' object of dotted names to values), or the name of a profile the "
        "server was started with (`navsvc serve --profiles DIR`: the file's stem)")

    def options(self) -> dict[str, Any]:
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
