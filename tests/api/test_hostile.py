"""Hostile and careless clients against a real server: each numbered fault of the reliability
issue, reproduced as it was found, and what the server now does instead."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from tests.api.server import Server, free_port, start_server

KEY = "s3cret-key-for-the-log-test"
GPS = [{"t": float(i), "kind": "gps", "lat": 43.7384 + 1e-4 * i, "lon": 7.4246,
        "speed_mps": 11.0, "heading_deg": 0.0} for i in range(6)]


@pytest.fixture()
def keyed(db: Path, tmp_path: Path) -> Iterator[Server]:
    server = start_server(db, tmp_path / "server.log", env={"NAVSVC_API_KEYS": KEY})
    yield server
    server.stop()


def _session(server: Server, key: str | None = KEY, **options: object) -> str:
    headers = {"X-API-Key": key} if key else {}
    r = server.client(headers=headers).post("/sessions", json={"vehicle_id": "v", **options})
    assert r.status_code == 201, r.text
    session_id: str = r.json()["id"]
    return session_id


def _ws(server: Server, sid: str, key: str = KEY) -> object:
    return connect(f"{server.ws_url}/v1/sessions/{sid}/stream",
                   additional_headers={"X-API-Key": key}, max_size=None)


def test_1_a_deeply_nested_extra_field_cannot_stop_the_next_start(
        db: Path, tmp_path: Path) -> None:
    server = start_server(db, tmp_path / "server.log")
    sid = _session(server, key=None)
    replies = []
    with connect(f"{server.ws_url}/v1/sessions/{sid}/stream", max_size=None) as ws:
        for t, depth in ((0.0, 500), (1.0, 963), (2.0, 5000)):
            nested = "[" * depth + "0" + "]" * depth
            ws.send(f'{{"t": {t}, "kind": "gps", "lat": 43.7384, "lon": 7.4246, "x": {nested}}}')
            replies.append(json.loads(ws.recv(timeout=30)))
    assert replies[0]["type"] == "result" and replies[0]["accepted"] == 1
    assert replies[2] == {"type": "error", "code": "malformed", "message": replies[2]["message"]}
    accepted = sum(r.get("accepted", 0) for r in replies)
    server.kill()
    again = start_server(db, tmp_path / "server.log")  # raised RecursionError at start-up
    try:
        assert again.client().get(f"/sessions/{sid}").json()["packets_accepted"] == accepted
    finally:
        again.stop()


def test_2_a_huge_number_is_refused_alone_and_the_good_packets_survive_a_restart(
        db: Path, tmp_path: Path) -> None:
    server = start_server(db, tmp_path / "server.log")
    sid = _session(server, key=None)
    body = json.dumps([GPS[0], {"t": 0.5, "kind": "odometer", "ticks": 10**400},
                       {"t": 0.6, "kind": "odometer", "distance_m": 1e300}, GPS[1]])
    r = server.client().post(f"/sessions/{sid}/packets", content=body,
                             headers={"content-type": "application/json"})
    assert r.status_code == 200, r.text
    assert r.json()["accepted"] == 2
    assert [x["code"] for x in r.json()["rejected"]] == ["out_of_range", "out_of_range"]
    server.kill()
    again = start_server(db, tmp_path / "server.log")
    try:
        info = again.client().get(f"/sessions/{sid}").json()
        assert (info["packets_accepted"], info["packets_rejected"]) == (2, 2)
    finally:
        again.stop()


@pytest.mark.parametrize("t", [1e308, 1.7e12, 7200.0])
def test_3_one_timestamp_cannot_brick_a_session(keyed: Server, t: float) -> None:
    sid = _session(keyed)
    client = keyed.client(headers={"X-API-Key": KEY})
    r = client.post(f"/sessions/{sid}/packets",
                    json=[GPS[0], {"t": t, "kind": "imu", "yaw_rate_dps": 0.0}])
    assert r.json()["rejected"][0]["code"] == "out_of_range"
    r = client.post(f"/sessions/{sid}/packets", json=GPS[1:])
    assert r.json()["accepted"] == 5 and r.json()["rejected"] == []


def test_4_websocket_keys_never_reach_the_log(keyed: Server) -> None:
    sid = _session(keyed)
    for key in (KEY, "a-wrong-key-1234"):
        with connect(f"{keyed.ws_url}/v1/sessions/{sid}/stream?api_key={key}&x=1") as ws:
            try:
                ws.send(json.dumps({"type": "ping"}))
                ws.recv(timeout=10)
            except ConnectionClosed:
                pass
    keyed.client().get(f"/sessions?api_key={KEY}")  # REST too, wherever it is put
    keyed.stop()
    text = keyed.log.read_text()
    assert "api_key=[redacted]" in text
    assert KEY not in text and "a-wrong-key-1234" not in text


def test_5_a_non_ascii_key_is_refused_cleanly(keyed: Server) -> None:
    r = keyed.client().get("/sessions", headers={"X-API-Key": "clé".encode()})
    assert r.status_code == 401 and r.json()["error"]["code"] == "unauthorized"
    sid = _session(keyed)
    with connect(f"{keyed.ws_url}/v1/sessions/{sid}/stream?api_key=cl%C3%A9%ED%A0%80") as ws:
        with pytest.raises(ConnectionClosed) as closed:
            ws.recv(timeout=10)
    assert closed.value.rcvd is not None and closed.value.rcvd.code == 4401


def test_6_messages_json_cannot_decode_get_an_error_reply(keyed: Server) -> None:
    sid = _session(keyed)
    with _ws(keyed, sid) as ws:  # type: ignore[attr-defined]
        sent: list[tuple[str | bytes, str]] = [
            ("[" + "1" * 5000 + "]", "error"), ("[" * 5000 + "]" * 5000, "error"),
            (b"\xff\xfe", "error"), (b'[{"t": 0, "kind": "imu", "yaw_rate_dps": 1}]', "result")]
        for message, expected in sent:
            ws.send(message)
            reply = json.loads(ws.recv(timeout=30))
            assert reply["type"] == expected, reply
        ws.send(json.dumps({"type": "ping"}))
        assert json.loads(ws.recv(timeout=10)) == {"type": "pong"}


def test_7_a_lone_surrogate_in_a_trace_is_a_clear_422(keyed: Server) -> None:
    body = b'{"trace": "<gpx><trk><trkseg>\\ud800</trkseg></trk></gpx>", "format": "gpx"}'
    r = keyed.client().post("/match", content=body, headers={
        "X-API-Key": KEY, "content-type": "application/json"})
    assert r.status_code == 422 and "Unicode" in r.json()["error"]["message"]


def test_8_a_resent_batch_is_applied_once(keyed: Server) -> None:
    sid = _session(keyed, sensors="gps_only")
    client = keyed.client(headers={"X-API-Key": KEY})
    first = client.post(f"/sessions/{sid}/packets?batch_seq=0", json=GPS[:3]).json()
    resent = client.post(f"/sessions/{sid}/packets?batch_seq=0", json=GPS[:3]).json()
    assert resent == {**first, "duplicate": True}
    with _ws(keyed, sid) as ws:  # type: ignore[attr-defined]
        for _ in range(2):
            ws.send(json.dumps({"type": "batch", "seq": 1, "packets": GPS[3:]}))
            reply = json.loads(ws.recv(timeout=30))
            assert reply["type"] == "result" and reply["seq"] == 1
        assert reply["duplicate"] is True
        ws.send(json.dumps({"type": "batch", "seq": "1", "packets": GPS[3:]}))
        assert json.loads(ws.recv(timeout=30))["code"] == "malformed"
    assert client.get(f"/sessions/{sid}").json()["packets_accepted"] == 6
    assert client.post(f"/sessions/{sid}/packets?batch_seq=0", json=GPS[:1]).json() == resent
    client.post(f"/sessions/{sid}/packets?batch_seq=10", json=[])
    r = client.post(f"/sessions/{sid}/packets?batch_seq=7", json=GPS[:1])  # never sent
    assert r.status_code == 409 and r.json()["error"]["code"] == "conflict"


def test_9_error_bodies_openapi_options_and_coercion(keyed: Server) -> None:
    client = keyed.client(headers={"X-API-Key": KEY})
    sid = _session(keyed)
    for body in (b"[{", b"[" + b"9" * 5000 + b"]"):
        r = client.post(f"/sessions/{sid}/packets", content=body,
                        headers={"content-type": "application/json"})
        assert r.status_code == 400 and set(r.json()) == {"error"}, r.text
    operation = httpx.get(keyed.url + "/openapi.json").json()["paths"][
        "/v1/sessions/{session_id}/packets"]["post"]
    assert {"400", "401"} <= set(operation["responses"])
    r = client.request("OPTIONS", f"/sessions/{sid}/packets")
    assert r.status_code == 405 and r.headers["allow"] == "POST"
    r = client.post(f"/sessions/{sid}/packets", json=[
        {"t": 0.0, "kind": "gps", "lat": "43.74", "lon": 7.42},
        {"t": True, "kind": "imu", "yaw_rate_dps": 1.0}])
    assert r.json()["accepted"] == 0 and len(r.json()["rejected"]) == 2


def test_9_an_open_server_declares_no_key_scheme(db: Path, tmp_path: Path) -> None:
    server = start_server(db, tmp_path / "server.log")
    try:
        schema = httpx.get(server.url + "/openapi.json").json()
        assert "securitySchemes" not in schema.get("components", {})
        assert all("security" not in op and "401" not in op["responses"]
                   for path in schema["paths"].values() for op in path.values())
    finally:
        server.stop()


def test_a_second_server_on_the_same_trip_log_refuses_to_start(
        keyed: Server, db: Path) -> None:
    port = free_port()
    second = subprocess.run(
        [sys.executable, "-m", "navsvc", "serve", "--map", str(db), "--host", "127.0.0.1",
         "--port", str(port)], capture_output=True, text=True, timeout=60)
    assert second.returncode != 0
    assert "in use by another navsvc server" in second.stderr
    with pytest.raises(httpx.TransportError):
        httpx.get(f"http://127.0.0.1:{port}/v1/healthz", timeout=2.0)
    assert keyed.client().get("/healthz").status_code == 200  # the first one serves on
