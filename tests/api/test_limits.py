"""API keys and request limits, configured by environment variables."""

from __future__ import annotations

import json
import shutil
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from tests.api.server import Server, start_server

ENV = {"NAVSVC_API_KEYS": "key-a, key-b", "NAVSVC_MAX_SESSIONS_PER_KEY": "2",
       "NAVSVC_MAX_BATCH_PACKETS": "5", "NAVSVC_MAX_BODY_BYTES": "2000",
       "NAVSVC_MAX_TRACE_POINTS": "3"}
GPS = {"t": 0.0, "kind": "gps", "lat": 43.7384, "lon": 7.4246}


@pytest.fixture(scope="module")
def keyed(sample_db: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    folder = tmp_path_factory.mktemp("keyed")
    shutil.copy(sample_db, folder / "monaco.db")
    server = start_server(folder / "monaco.db", folder / "server.log", env=ENV)
    yield server
    server.stop()


def as_key(server: Server, key: str | None) -> httpx.Client:
    return server.client(headers={"X-API-Key": key} if key else {})


def test_keys_are_required_and_sessions_private(keyed: Server) -> None:
    r = as_key(keyed, None).post("/sessions", json={"vehicle_id": "x"})
    assert r.status_code == 401 and "API key" in r.json()["error"]["message"]
    assert as_key(keyed, "wrong").get("/maps").status_code == 401
    a, b = as_key(keyed, "key-a"), as_key(keyed, "key-b")
    sid = a.post("/sessions", json={"vehicle_id": "a1"}).json()["id"]
    assert a.get(f"/sessions/{sid}").status_code == 200
    assert b.get(f"/sessions/{sid}").status_code == 404
    assert b.post(f"/sessions/{sid}/packets", json=[GPS]).status_code == 404
    assert b.delete(f"/sessions/{sid}").status_code == 404
    assert sid not in {s["id"] for s in b.get("/sessions").json()["sessions"]}
    assert as_key(keyed, None).get("/healthz").status_code == 200  # operations stay open


def test_sessions_per_key(keyed: Server) -> None:
    b = as_key(keyed, "key-b")
    for s in b.get("/sessions").json()["sessions"]:
        b.delete(f"/sessions/{s['id']}")
    assert b.post("/sessions", json={"vehicle_id": "1"}).status_code == 201
    assert b.post("/sessions", json={"vehicle_id": "2"}).status_code == 201
    r = b.post("/sessions", json={"vehicle_id": "3"})
    assert r.status_code == 429 and "the limit is 2" in r.json()["error"]["message"]


def test_batch_body_and_trace_limits(keyed: Server) -> None:
    a = as_key(keyed, "key-a")
    sid = a.get("/sessions").json()["sessions"][0]["id"]
    r = a.post(f"/sessions/{sid}/packets", json=[GPS] * 6)
    assert r.status_code == 413 and "the limit is 5" in r.json()["error"]["message"]
    big = [{**GPS, "pad": "x" * 500}] * 5
    r = a.post(f"/sessions/{sid}/packets", json=big)
    assert r.status_code == 413 and "over 2000 bytes" in r.json()["error"]["message"]
    assert a.get(f"/sessions/{sid}").json()["packets_accepted"] == 0  # nothing applied
    points = [{"lat": 43.7384, "lon": 7.4246 + 1e-4 * i} for i in range(4)]
    r = a.post("/match", json={"points": points})
    assert r.status_code == 413 and "the limit is 3" in r.json()["error"]["message"]


def test_websocket_key_and_batch_limit(keyed: Server) -> None:
    a = as_key(keyed, "key-a")
    sid = a.get("/sessions").json()["sessions"][0]["id"]
    with connect(f"{keyed.ws_url}/v1/sessions/{sid}/stream") as ws:
        with pytest.raises(ConnectionClosed) as closed:
            ws.recv(timeout=10)
    assert closed.value.rcvd is not None and closed.value.rcvd.code == 4401
    with connect(f"{keyed.ws_url}/v1/sessions/{sid}/stream?api_key=key-b") as ws:
        with pytest.raises(ConnectionClosed) as closed:
            ws.recv(timeout=10)
    assert closed.value.rcvd is not None and closed.value.rcvd.code == 4404
    with connect(f"{keyed.ws_url}/v1/sessions/{sid}/stream",
                 additional_headers={"X-API-Key": "key-a"}) as ws:
        ws.send(json.dumps([GPS] * 6))
        reply = json.loads(ws.recv(timeout=10))
        assert reply == {"type": "error", "code": "too_many_packets",
                         "message": "6 packets in one batch; the limit is 5"}
