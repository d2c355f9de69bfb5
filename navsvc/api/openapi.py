"""The OpenAPI document as the server behaves, and the offline ``/docs`` and ``/redoc``.

FastAPI builds the document from the routes; this module completes it (docs/interfaces.md is
the contract it follows):

- sensor packets as a typed union discriminated by ``kind``, drawn from the packet models of
  :mod:`navsvc.wire.packets`. Only the *schema* comes from them: ``POST .../packets`` still
  takes a bare array and each item goes through :func:`navsvc.wire.packets.parse_record`, so a
  bad packet rejects only itself with its exact message, at the same speed as before;
- matched positions typed (schema-only models below: replies are built as plain dicts, as
  :func:`navsvc.session.batch_reply` explains);
- an example on every operation, errors as ``ErrorBody`` (FastAPI's default 422 body is not
  what the server sends), 400 for bodies that are not JSON, 401 only when keys are required;
- the two WebSockets, which OpenAPI cannot describe as operations, in the description.

``/docs`` (Swagger UI) and ``/redoc`` load their scripts from ``/static/docs``: the files of
the ``fastapi-offline`` package (swagger-ui-dist, Apache-2.0; ReDoc, MIT), not a CDN.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

import fastapi_offline
from fastapi import APIRouter, FastAPI
from fastapi.openapi.docs import get_redoc_html, get_swagger_ui_html
from fastapi.openapi.utils import get_openapi
from fastapi.responses import HTMLResponse
from pydantic import BaseModel, Field, TypeAdapter

from navsvc.wire.packets import (
    MODELS,
    GpsPacket,
    ImuPacket,
    NmeaPacket,
    OdometerPacket,
    OncorePacket,
    SteeringPacket,
)

DOCS_STATIC_DIR = Path(fastapi_offline.__file__).resolve().parent / "static"
DOCS_STATIC_URL = "/static/docs"

DESCRIPTION = """\
Map-matching navigation: vehicles stream sensor packets; the service fuses them (an EKF per
vehicle) and matches the fused position onto the road graph of its map.

The wire contract (packets, matched positions, sessions, errors, limits, WebSocket messages
and close codes) is `docs/interfaces.md` in the repository; this schema follows it.
The live map of the sessions is at `/` (and `/map`).

## WebSocket `/v1/sessions/{session_id}/stream` (a vehicle)

Send one packet, an array of packets, a numbered batch
`{"type": "batch", "seq": N, "packets": [...]}` (a resend of a number already applied is
answered with its first reply, `"duplicate": true`, and not applied again), or
`{"type": "ping"}`. Each message gets one reply, in order:
`{"type": "result", "accepted", "rejected": [{"index", "code", "message"}], "positions": [...]}`
(the reply of `POST .../packets`, with `"seq"` for a numbered batch),
`{"type": "error", "code", "message"}` when the message itself cannot be used (codes
`malformed`, `too_many_packets`, `session_not_found`, `batch_already_applied`, `unavailable`,
`internal`), or `{"type": "pong"}`. Replies wait in a queue of `NAVSVC_WS_QUEUE` (64); a
client that reads too slowly loses the oldest, and the next reply says `"dropped": n`.

## WebSocket `/v1/sessions/{session_id}/view` (a map viewer)

The server sends `{"type": "snapshot", "session", "fixes", "positions"}` first, then
`{"type": "update", "fixes", "positions", "accepted", "rejected"}` after each batch of the
session, and `{"type": "ended"}` when it ends (then closes with 1000). A fix is
`{"t", "lat", "lon", "accuracy_m", "hdop"}`. A viewer may send `{"type": "snapshot"}` to get
the whole recent track again (after `"dropped": n`). Viewers never slow the vehicles: each has
a bounded queue that drops its oldest update.

## Keys and close codes

With `NAVSVC_API_KEYS` set, requests need `X-API-Key`; a WebSocket takes the header or
`?api_key=` (never logged). Each session is visible only to the key that created it. A
WebSocket closes with **4401** for a missing or unknown key and **4404** for an unknown
session, the reason saying which.
"""


# --- matched positions, for the schema only -----------------------------------------------

class PositionEdge(BaseModel):
    u: int = Field(description="node the road leaves")
    v: int = Field(description="node the road enters")
    key: int = Field(description="which of the roads between u and v")
    osm_way_ids: list[int]
    name: str | None
    offset_m: float | None = Field(None, description="along the road from u")
    length_m: float | None = None


class Candidate(BaseModel):
    edge: PositionEdge
    probability: float = Field(ge=0, le=1, description="the candidates' sum to 1")


class GpsUse(BaseModel):
    used: bool = Field(description="the last fix went into the filter")
    weight: float | None = Field(description="1: fully trusted; less: down-weighted; 0: not used")
    reason: str = Field(description='e.g. "accepted", "initialised from GPS", "gated: ..."')
    nis: float | None = Field(None, description="normalised innovation squared of the fix")


class MatchedPosition(BaseModel):
    """One matched position (docs/interfaces.md): at each GPS epoch, and each second in an
    outage. Every number is finite or null."""

    t: float | None = Field(description="time of the estimate, seconds (as the packets' t)")
    lat: float | None = Field(description="matched position: on the road when matched, "
                                          "else the fused estimate")
    lon: float | None
    fused_lat: float | None = Field(description="the fusion's unconstrained estimate")
    fused_lon: float | None
    heading_deg: float | None = Field(description="clockwise from north, 0-360; null while "
                                      "initializing (not yet known)")
    speed_mps: float | None = Field(description="null while initializing without a measured "
                                    "speed")
    position_sigma_m: float | None = Field(description="1-sigma horizontal uncertainty")
    state: Literal["initializing", "on_road", "ambiguous", "off_road", "lost"]
    edge: PositionEdge | None
    distance_to_road_m: float | None
    candidates: list[Candidate] = Field(description="while ambiguous: the roads it may be on")
    next_node: int | None = Field(description="the intersection ahead")
    distance_to_next_node_m: float | None
    gps: GpsUse | None = Field(description="how the last GPS fix was used; null before one")


POSITION_EXAMPLE: dict[str, Any] = {
    "t": 30.0, "lat": 43.7404772, "lon": 7.4220339, "fused_lat": 43.740495,
    "fused_lon": 7.4220156, "heading_deg": 52.66, "speed_mps": 3.412, "position_sigma_m": 2.67,
    "state": "on_road",
    "edge": {"u": 223, "v": 221, "key": 0, "osm_way_ids": [157719669], "name": "Rue des Roses",
             "offset_m": 2.72, "length_m": 71.33},
    "distance_to_road_m": 2.46, "candidates": [], "next_node": 221,
    "distance_to_next_node_m": 68.62,
    "gps": {"used": True, "weight": 1.0, "reason": "accepted", "nis": 1.829}}

# --- sensor packets -------------------------------------------------------------------------

PACKET_DOCS: dict[str, str] = {
    "gps": "A GPS fix (WGS84 degrees).", "imu": "Inertial sample: the z-up yaw rate and "
    "planar accelerations, or a full 6-axis IMU (body frame: x forward, y left, z up).",
    "odometer": "Wheel odometry: cumulative distance or ticks, or speed.",
    "steering": "Front-wheel angle (steering_odometer configuration).",
    "nmea": "One NMEA 0183 sentence (GGA, RMC, VTG).",
    "oncore": "One Motorola Oncore @@Ba binary message, hex-encoded."}
FIELD_DOCS: dict[str, str] = {
    "t": "seconds, Unix time or since the drive's start, 0 to 4102444800; at most 3600 s "
         "after the vehicle's latest packet",
    "kind": "the packet's kind", "lat": "degrees", "lon": "degrees", "alt_m": "metres",
    "speed_mps": "metres per second", "heading_deg": "course over ground, clockwise from "
    "north", "hdop": "horizontal dilution of precision", "sats": "satellites used",
    "fix": "receiver fix type", "accuracy_m": "1-sigma horizontal accuracy, metres",
    "yaw_rate_dps": "degrees per second, z up (positive turning left)",
    "accel_fwd_mps2": "m/s², forward", "accel_left_mps2": "m/s², to the left",
    "gyro_dps": "[x, y, z] degrees per second", "accel_mps2": "[x, y, z] m/s²",
    "distance_m": "cumulative metres", "ticks": "cumulative count (the session gives "
    "ticks_per_m)", "angle_deg": "front-wheel angle, positive left",
    "sentence": "at most 256 characters, with its checksum",
    "hex": "at most 1024 hex digits"}
PACKET_EXAMPLES = [
    {"t": 0.0, "kind": "gps", "lat": 43.7384, "lon": 7.4246, "speed_mps": 8.3,
     "heading_deg": 52.0, "hdop": 0.9, "sats": 9, "fix": "3d"},
    {"t": 0.01, "kind": "imu", "yaw_rate_dps": 1.5, "accel_fwd_mps2": 0.2},
    {"t": 0.02, "kind": "odometer", "distance_m": 12.48},
    {"t": 0.02, "kind": "steering", "angle_deg": -2.5},
    {"t": 1.0, "kind": "nmea",
     "sentence": "$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47"},
]

PacketUnion = Annotated[GpsPacket | ImuPacket | OdometerPacket | SteeringPacket | NmeaPacket
                        | OncorePacket, Field(discriminator="kind")]


def packet_schemas() -> tuple[dict[str, Any], dict[str, Any]]:
    """The schema of one packet (a oneOf by ``kind``) and the component schemas it refers
    to, named ``GpsPacket`` ... ``OncorePacket``."""
    schema = TypeAdapter(PacketUnion).json_schema(ref_template="#/components/schemas/{model}")
    components: dict[str, Any] = schema.pop("$defs")
    for kind, model in MODELS.items():
        component = components[model.__name__]
        component["description"] = PACKET_DOCS[kind]
        component["required"] = ["t", "kind", *[r for r in component.get("required", [])
                                                if r not in ("t", "kind")]]
        for name, prop in component["properties"].items():
            if name in FIELD_DOCS:
                prop["description"] = FIELD_DOCS[name]
        component["additionalProperties"] = True  # unknown fields are ignored
    return schema, components


# --- examples of every operation ------------------------------------------------------------

SESSION_EXAMPLE: dict[str, Any] = {
    "id": "3f2a9c0d1b7e4a55", "vehicle_id": "car-17", "map": "monaco",
    "options": {"sensors": "gyro_odometer", "fusion": "ekf"},
    "created_unix": 1764619200.0, "packets_accepted": 4400, "packets_rejected": 0,
    "position": POSITION_EXAMPLE}
BATCH_REPLY_EXAMPLE: dict[str, Any] = {
    "accepted": 4, "rejected": [{"index": 4, "code": "out_of_range", "message":
                                 "a value is out of range: lat=91.0 (must be <= 90.0)"}],
    "positions": [POSITION_EXAMPLE], "duplicate": False}
MATCH_REPLY_EXAMPLE: dict[str, Any] = {
    "map": "monaco", "points_in": 4, "trace_length_m": 15.01, "length_m": 9.8,
    "segments": [{"edges": [{"u": 34, "v": 214, "key": 0, "osm_way_ids": [164338241],
                             "name": "Avenue de Roqueville", "length_m": 38.19}],
                  "osm_way_ids": [164338241], "streets": ["Avenue de Roqueville"],
                  "length_m": 9.8, "geometry": {"type": "LineString", "coordinates": [
                      [7.4218378, 43.7398537], [7.4217483, 43.7399135]]}}],
    "points": [{"index": 0, "t": 0.0, "lat": 43.7398259, "lon": 7.4217981,
                "matched": {"lat": 43.7398537, "lon": 7.4218378,
                            "edge": {"u": 34, "v": 214, "key": 0}, "distance_m": 4.45,
                            "segment": 0}}]}
MAP_EXAMPLE: dict[str, Any] = {
    "map_id": "monaco", "path": "maps/monaco.db", "epsg": 32632,
    "bbox_wgs84": [7.4043415, 43.7217714, 7.439278, 43.7519628], "node_count": 276,
    "edge_count": 566, "total_length_m": 85439.6, "longest_edge_m": 951.78,
    "network": "drive", "consolidate_m": 8.0, "source_name": "monaco.osm.gz"}
EDGES_EXAMPLE: dict[str, Any] = {"type": "FeatureCollection", "features": [{
    "type": "Feature", "geometry": {"type": "LineString", "coordinates": [
        [7.4218378, 43.7398537], [7.4217483, 43.7399135]]},
    "properties": {"u": 34, "v": 214, "key": 0, "osm_way_ids": [164338241],
                   "name": "Avenue de Roqueville", "highway": "secondary", "oneway": False,
                   "maxspeed": "50", "lanes": None, "tunnel": False, "bridge": False,
                   "length_m": 38.19}}]}

# (method, path) -> (request body example or None, {status: response example})
EXAMPLES: dict[tuple[str, str], tuple[Any, dict[str, Any]]] = {
    ("post", "/v1/sessions"): (
        {"vehicle_id": "car-17", "sensors": "gyro_odometer", "fusion": "ekf"},
        {"201": {**SESSION_EXAMPLE, "packets_accepted": 0, "position": None}}),
    ("get", "/v1/sessions"): (None, {"200": {"sessions": [SESSION_EXAMPLE]}}),
    ("get", "/v1/sessions/{session_id}"): (None, {"200": SESSION_EXAMPLE}),
    ("delete", "/v1/sessions/{session_id}"): (None, {}),
    ("post", "/v1/sessions/{session_id}/packets"): (
        [*PACKET_EXAMPLES[:3], {"t": 1.0, "kind": "gps", "lat": 43.73845, "lon": 7.42468},
         {"t": 1.0, "kind": "gps", "lat": 91.0, "lon": 7.42}], {"200": BATCH_REPLY_EXAMPLE}),
    ("get", "/v1/sessions/{session_id}/position"): (None, {"200": POSITION_EXAMPLE}),
    ("post", "/v1/match"): (
        {"points": [{"lat": 43.7398259, "lon": 7.4217981, "t": 0.0},
                    {"lat": 43.7398583, "lon": 7.4218158, "t": 1.0},
                    {"lat": 43.7398697, "lon": 7.4217338, "t": 2.0},
                    {"lat": 43.7399089, "lon": 7.4217425, "t": 3.0}], "sigma_m": 10.0},
        {"200": MATCH_REPLY_EXAMPLE}),
    ("get", "/v1/maps"): (None, {"200": {"maps": [MAP_EXAMPLE]}}),
    ("get", "/v1/maps/{map_id}"): (None, {"200": MAP_EXAMPLE}),
    ("get", "/v1/maps/{map_id}/edges"): (None, {"200": EDGES_EXAMPLE}),
    ("get", "/v1/healthz"): (None, {"200": {"status": "ok", "map": "monaco", "sessions": 3}}),
    ("get", "/v1/metrics"): (None, {"200": "# HELP navsvc_packets_accepted_total Sensor "
                                           "packets accepted\n# TYPE navsvc_packets_accepted_"
                                           "total counter\nnavsvc_packets_accepted_total "
                                           "4400.0\n"}),
}
ERROR_EXAMPLES = {
    "400": "request body is not valid JSON: Expecting value",
    "401": "missing or unknown API key (header X-API-Key)",
    "404": "no session '3f2a9c0d1b7e4a55'",
    "405": "Method Not Allowed",
    "409": "batch 3 is not after the session's last numbered batch (70): ...",
    "413": "1200 packets in one batch; the limit is 1000",
    "422": "invalid request: body.vehicle_id: Field required",
    "429": "this API key already has 10000 sessions; the limit is 10000"}
ERROR_CODES = {"400": "bad_request", "401": "unauthorized", "404": "not_found",
               "405": "method_not_allowed", "409": "conflict", "413": "too_large",
               "422": "invalid_request", "429": "limit_exceeded"}


def build_openapi(app: FastAPI, keys_required: bool, max_batch_packets: int) -> dict[str, Any]:
    """The OpenAPI document of ``app`` (cached on it)."""
    if app.openapi_schema is not None:
        return app.openapi_schema
    schema = get_openapi(title=app.title, version=app.version, description=DESCRIPTION,
                         routes=app.routes)
    components = schema.setdefault("components", {}).setdefault("schemas", {})
    packet, packet_components = packet_schemas()
    components.update(packet_components)
    components.update(TypeAdapter(MatchedPosition).json_schema(
        ref_template="#/components/schemas/{model}").pop("$defs"))
    components["MatchedPosition"] = TypeAdapter(MatchedPosition).json_schema(
        ref_template="#/components/schemas/{model}")
    components["MatchedPosition"].pop("$defs", None)
    position_ref = {"$ref": "#/components/schemas/MatchedPosition"}
    components["BatchReply"]["properties"]["positions"]["items"] = position_ref
    components["SessionInfo"]["properties"]["position"] = {
        "anyOf": [position_ref, {"type": "null"}],
        "description": "latest matched position, null before the first fix"}
    for name in ("HTTPValidationError", "ValidationError"):
        components.pop(name, None)
    for path, operations in schema["paths"].items():
        for method, operation in operations.items():
            _complete(operation, method, path, keys_required)
    body = schema["paths"]["/v1/sessions/{session_id}/packets"]["post"]["requestBody"]
    body["content"]["application/json"]["schema"] = {
        "type": "array", "items": packet, "maxItems": max_batch_packets,
        "description": "sensor packets, oldest first (at most NAVSVC_MAX_BATCH_PACKETS); "
                       "each is checked alone: a bad one is rejected with its index and "
                       "the rest applied"}
    schema["paths"]["/v1/sessions/{session_id}/position"]["get"]["responses"]["200"][
        "content"] = {"application/json": {"schema": position_ref,
                                           "example": POSITION_EXAMPLE}}
    if not keys_required:
        components.pop("securitySchemes", None)
        schema["components"].pop("securitySchemes", None)
    app.openapi_schema = schema
    return schema


def _complete(operation: dict[str, Any], method: str, path: str, keys_required: bool) -> None:
    """Examples, error bodies as the server sends them, and 400/401 where they apply."""
    request, responses = EXAMPLES.get((method, path), (None, {}))
    if request is not None and "requestBody" in operation:
        operation["requestBody"]["content"]["application/json"]["example"] = request
    answers = operation.setdefault("responses", {})
    for status, example in responses.items():
        content = answers.setdefault(status, {"description": "OK"}).setdefault(
            "content", {"application/json": {}})
        for media in content.values():
            media["example"] = example
    error = {"$ref": "#/components/schemas/ErrorBody"}
    if "requestBody" in operation:
        answers.setdefault("400", {"description": "body is not JSON"})
    if not keys_required:
        operation.pop("security", None)
        answers.pop("401", None)
    elif "security" in operation:
        answers.setdefault("401", {"description": "missing or unknown API key"})
    for status, answer in answers.items():
        if status in ERROR_CODES:
            answer["content"] = {"application/json": {"schema": error, "example": {
                "error": {"code": ERROR_CODES[status], "message": ERROR_EXAMPLES[status]}}}}


def docs_router(app: FastAPI) -> APIRouter:
    """``/docs`` and ``/redoc`` with their scripts served by this server."""
    router = APIRouter(include_in_schema=False)
    openapi_url = app.openapi_url or "/openapi.json"

    @router.get("/docs")
    def swagger() -> HTMLResponse:
        return get_swagger_ui_html(
            openapi_url=openapi_url, title=f"{app.title}: API docs",
            swagger_js_url=f"{DOCS_STATIC_URL}/swagger-ui-bundle.js",
            swagger_css_url=f"{DOCS_STATIC_URL}/swagger-ui.css",
            swagger_favicon_url=f"{DOCS_STATIC_URL}/favicon.png")

    @router.get("/redoc")
    def redoc() -> HTMLResponse:
        return get_redoc_html(openapi_url=openapi_url, title=f"{app.title}: API reference",
                              redoc_js_url=f"{DOCS_STATIC_URL}/redoc.standalone.js",
                              redoc_favicon_url=f"{DOCS_STATIC_URL}/favicon.png",
                              with_google_fonts=False)

    return router
