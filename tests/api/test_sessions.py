"""The REST API through a real server: sessions, packets, positions, maps, operations."""

from __future__ import annotations

import math

import httpx
import pytest

from roadgraph import RoadGraph
from tests.api.server import Server

GPS = {"t": 0.0, "kind": "gps", "lat": 43.7384, "lon": 7.4246, "speed_mps": 0.0}


@pytest.fixture
def client(server: Server) -> httpx.Client:
    return server.client()


def new_session(client: httpx.Client, **options: object) -> dict:
    r = client.post("/sessions", json={"vehicle_id": "car-1", **options})
    assert r.status_code == 201, r.text
    return r.json()


def test_create_get_list_delete(client: httpx.Client) -> None:
    s = new_session(client, sensors="gyro_odometer", fusion="fuzzy", map_feedback=True)
    assert s["options"] == {"sensors": "gyro_odometer", "fusion": "fuzzy", "map_feedback": True}
    assert s["map"] == "monaco" and s["packets_accepted"] == 0 and s["position"] is None
    assert client.get(f"/sessions/{s['id']}").json()["id"] == s["id"]
    assert s["id"] in {x["id"] for x in client.get("/sessions").json()["sessions"]}
    assert client.delete(f"/sessions/{s['id']}").status_code == 204
    r = client.get(f"/sessions/{s['id']}")
    assert r.status_code == 404
    assert r.json() == {"error": {"code": "not_found", "message": f"no session '{s['id']}'"}}


def test_invalid_session_request_names_the_fields(client: httpx.Client) -> None:
    r = client.post("/sessions", json={"vehicle_id": "", "sensors": "sonar", "extra": 1})
    assert r.status_code == 422
    fields = {f["field"] for f in r.json()["error"]["fields"]}
    assert fields == {"body.vehicle_id", "body.sensors", "body.extra"}
    assert r.json()["error"]["code"] == "invalid_request"


def test_impossible_configuration_is_refused(client: httpx.Client) -> None:
    r = client.post("/sessions", json={"vehicle_id": "x", "sensors": "gps_only",
                                       "fusion": "rules"})
    assert r.status_code == 422
    assert "gps_only" in r.json()["error"]["message"]


def test_batch_rejects_bad_packets_one_by_one(client: httpx.Client) -> None:
    s = new_session(client)
    batch = [GPS, {"t": 0.01, "kind": "imu"}, {"t": 0.02, "kind": "gps", "lat": 91, "lon": 7},
             "not an object", {"t": 0.03, "kind": "warp"},
             {"t": 0.04, "kind": "imu", "yaw_rate_dps": 0.5}]
    r = client.post(f"/sessions/{s['id']}/packets", json=batch)
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["accepted"] == 2
    assert [(x["index"], x["code"]) for x in body["rejected"]] == [
        (1, "missing_field"), (2, "out_of_range"), (3, "malformed"), (4, "unknown_kind")]
    info = client.get(f"/sessions/{s['id']}").json()
    assert (info["packets_accepted"], info["packets_rejected"]) == (2, 4)


def test_position_before_and_after_the_first_fix(client: httpx.Client) -> None:
    s = new_session(client, sensors="gps_only")
    r = client.get(f"/sessions/{s['id']}/position")
    assert r.status_code == 404 and "no position yet" in r.json()["error"]["message"]
    fixes = [{**GPS, "t": float(i), "lat": 43.7384 + 1e-4 * i, "speed_mps": 11.0,
              "heading_deg": 0.0} for i in range(5)]
    out = client.post(f"/sessions/{s['id']}/packets", json=fixes).json()
    assert out["accepted"] == 5 and out["positions"]
    p = client.get(f"/sessions/{s['id']}/position").json()
    assert p == out["positions"][-1]
    assert {"t", "lat", "lon", "fused_lat", "fused_lon", "state", "edge", "gps"} <= set(p)


def test_a_fix_of_a_car_standing_gives_a_position_before_the_heading_is_known(
        client: httpx.Client) -> None:
    """The first fix already gives a position (the contract: 404 only before it): the car
    stands, so no heading is known yet (null), and the wheels say 0 m/s. The position is
    the fix's given that the car is on a road: within its 2.45-sigma circle of the fix,
    and nearer the matched road than the fix is."""
    s = new_session(client)
    packets = [{"t": 0.0, "kind": "odometer", "speed_mps": 0.0},
               {**GPS, "t": 0.1, "hdop": 1.0}]
    out = client.post(f"/sessions/{s['id']}/packets", json=packets).json()
    assert out["accepted"] == 2 and len(out["positions"]) == 1
    p = client.get(f"/sessions/{s['id']}/position").json()
    assert p == out["positions"][0]
    assert p["state"] == "initializing" and p["heading_deg"] is None and p["speed_mps"] == 0.0
    assert p["position_sigma_m"] > 0.0 and p["gps"]["reason"].startswith("initialising")
    fused, fix, road = ((p["fused_lat"], p["fused_lon"]), (GPS["lat"], GPS["lon"]),
                        (p["lat"], p["lon"]))
    assert _metres(fused, fix) <= 2.45 * p["position_sigma_m"]
    assert _metres(fused, road) < _metres(fix, road)


def _metres(a: tuple[float, float], b: tuple[float, float]) -> float:
    """Distance between two (lat, lon) a few tens of metres apart."""
    north = math.radians(a[0] - b[0]) * 6_371_000.0
    east = math.radians(a[1] - b[1]) * 6_371_000.0 * math.cos(math.radians(a[0]))
    return math.hypot(north, east)


def test_body_that_is_not_an_array(client: httpx.Client) -> None:
    s = new_session(client)
    r = client.post(f"/sessions/{s['id']}/packets", json={"t": 0, "kind": "gps"})
    assert r.status_code == 422
    r = client.post(f"/sessions/{s['id']}/packets", content=b"[{",
                    headers={"content-type": "application/json"})
    assert r.status_code == 400 and "JSON" in r.json()["error"]["message"]


def test_unknown_session(client: httpx.Client) -> None:
    r = client.post("/sessions/nope/packets", json=[GPS])
    assert r.status_code == 404 and r.json()["error"]["message"] == "no session 'nope'"


def test_match_points_and_trace_text(client: httpx.Client, sample_graph: RoadGraph) -> None:
    edge = max(sample_graph.edges, key=lambda e: e.length_m)  # points along one real road
    points = [{"lat": float(lat), "lon": float(lon), "t": float(i)}
              for i, (lon, lat) in enumerate(edge.lonlat)]
    r = client.post("/match", json={"points": points})
    assert r.status_code == 200, r.text
    route = r.json()
    (segment,) = route["segments"]
    assert set(edge.osm_way_ids) <= set(segment["osm_way_ids"])
    csv = "t,lat,lon\n" + "\n".join(f"{p['t']},{p['lat']},{p['lon']}" for p in points)
    r2 = client.post("/match", json={"trace": csv, "format": "csv"})
    assert r2.status_code == 200 and r2.json()["segments"] == route["segments"]


def test_match_bad_requests(client: httpx.Client) -> None:
    r = client.post("/match", json={"points": [{"lat": 0, "lon": 0}, {"lat": 0.001, "lon": 0}]})
    assert r.status_code == 422
    assert "no point of the trace is within 30 m" in r.json()["error"]["message"]
    r = client.post("/match", json={"trace": "lat,lon\n1,2"})
    assert r.status_code == 422 and "format is required" in r.json()["error"]["message"]
    r = client.post("/match", json={"trace": "<gpx", "format": "gpx"})
    assert r.status_code == 422 and r.json()["error"]["message"].startswith("trace")
    r = client.post("/match", json={"points": []})
    assert r.status_code == 422 and "no points" in r.json()["error"]["message"]


def test_maps(client: httpx.Client) -> None:
    (info,) = client.get("/maps").json()["maps"]
    assert info["map_id"] == "monaco" and info["node_count"] > 100
    assert client.get("/maps/monaco").json() == info
    assert client.get("/maps/atlantis").status_code == 404
    west, south, east, north = info["bbox_wgs84"]
    box = f"{west},{south},{(west + east) / 2},{(south + north) / 2}"
    edges = client.get("/maps/monaco/edges", params={"bbox": box}).json()
    assert edges["type"] == "FeatureCollection" and edges["features"]
    assert all(f["geometry"]["type"] == "LineString" for f in edges["features"])
    r = client.get("/maps/monaco/edges", params={"bbox": "1,2,3"})
    assert r.status_code == 422 and "four numbers" in r.json()["error"]["message"]


def test_healthz_metrics_openapi(client: httpx.Client, server: Server) -> None:
    s = new_session(client)
    client.post(f"/sessions/{s['id']}/packets", json=[GPS, {"t": 1, "kind": "imu"}])
    assert client.get("/healthz").json()["status"] == "ok"
    text = client.get("/metrics").text
    assert 'navsvc_packets_rejected_total{reason="missing_field"}' in text
    assert "navsvc_packets_accepted_total" in text and "navsvc_sessions " in text
    assert "navsvc_batch_seconds_bucket" in text
    schema = httpx.get(server.url + "/openapi.json").json()
    assert "/v1/sessions/{session_id}/packets" in schema["paths"]
    assert "SessionCreate" in schema["components"]["schemas"]


def test_fix_far_outside_the_map_is_refused(client: httpx.Client) -> None:
    s = new_session(client)
    r = client.post(f"/sessions/{s['id']}/packets",
                    json=[{"t": 0, "kind": "gps", "lat": -89.9, "lon": 100.0}])
    (rejected,) = r.json()["rejected"]
    assert rejected["code"] == "out_of_range"
    assert "is outside the map 'monaco'" in rejected["message"]


def test_strapdown_session_takes_6_axis_imu(client: httpx.Client) -> None:
    s = new_session(client, sensors="strapdown", ins_integration="feedforward",
                    ins_mechanisation="rk4", imu_mounting_rpy_deg=[180.0, 0.0, 0.0],
                    gps_lever_arm_m=[0.5, 0.0, -1.2])
    assert s["options"]["ins_mechanisation"] == "rk4"
    imu = {"t": 0.01, "kind": "imu", "gyro_dps": [0.0, 0.0, 1.0], "accel_mps2": [0.1, 0.0, 9.8]}
    r = client.post(f"/sessions/{s['id']}/packets",
                    json=[GPS, imu, {"t": 0.02, "kind": "imu", "yaw_rate_dps": 1.0}])
    body = r.json()
    assert body["accepted"] == 2
    assert [(x["index"], x["code"]) for x in body["rejected"]] == [(2, "missing_field")]
    r = client.post("/sessions", json={"vehicle_id": "x", "sensors": "strapdown",
                                       "map_feedback": True})
    assert r.status_code == 201 and r.json()["options"]["map_feedback"] is True


@pytest.mark.parametrize("path", ["/v1", "/v1/"])
def test_the_api_root_says_where_to_go(server: Server, path: str) -> None:
    """`make run` prints the server's address; /v1 and /v1/ answered 404."""
    r = httpx.get(server.url + path, timeout=10.0)
    assert r.status_code == 200
    body = r.json()
    assert body["service"] == "navsvc" and body["map"] == "monaco"
    assert body["links"]["map_view"] == "/" and body["links"]["docs"] == "/docs"


def test_unknown_routes_and_methods_say_what_is_wrong(server: Server) -> None:
    r = httpx.get(server.url + "/v2/sessions", timeout=10.0)
    assert r.status_code == 404 and r.json() == {"error": {
        "code": "not_found", "message": "no route GET /v2/sessions: the API is under /v1 "
                                        "(see /docs), the map view at /"}}
    r = httpx.put(server.url + "/v1/sessions", timeout=10.0)
    assert r.status_code == 405 and r.headers["allow"] == "GET, POST"
    assert r.json() == {"error": {"code": "method_not_allowed", "message":
                                  "PUT is not allowed on /v1/sessions (allowed: GET, POST)"}}
