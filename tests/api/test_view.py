"""The map view's server side: the page and its files, its configuration, the viewer
WebSocket (snapshot, updates, end, refusals), slow viewers, and the replay of a file."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import httpx
import pytest
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from navsvc.errors import TraceError
from navsvc.sim.simulate import SENSOR_KINDS, DriveSpec, simulate_drive
from navsvc.web.feed import ViewerHub, ViewerQueue, fixes_of
from navsvc.web.replay import load_replay
from navsvc.wire.jsonl import write_records
from roadgraph import RoadGraph
from tests.api.server import Server, start_server


def _packets(graph: RoadGraph, duration_s: float = 40.0, seed: int = 2) -> list[dict]:
    kinds = set(SENSOR_KINDS["gyro_odometer"])
    return [r for r in simulate_drive(graph, DriveSpec(duration_s=duration_s, seed=seed))
            if r["kind"] in kinds]


@pytest.mark.parametrize("path", ["/", "/map"])
def test_the_page_is_served_with_its_own_files(server: Server, path: str) -> None:
    page = httpx.get(server.url + path, timeout=10.0)
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    assert "<script src=\"/static/viewer.js\">" in page.text
    assert "http" not in page.text.replace("http-equiv", "")  # nothing from elsewhere
    for asset in ("/static/viewer.js", "/static/viewer.css", "/static/vendor/leaflet/leaflet.js",
                  "/static/vendor/leaflet/leaflet.css", "/static/vendor/leaflet/LICENSE"):
        assert httpx.get(server.url + asset, timeout=10.0).status_code == 200, asset


def test_view_config_names_the_map_and_says_no_key_is_needed(server: Server) -> None:
    config = httpx.get(server.url + "/v1/view/config", timeout=10.0).json()
    assert config["map"] == "monaco" and config["keys_required"] is False
    assert config["replay"] is False
    west, south, east, north = config["bbox"]
    assert west < 7.42 < east and south < 43.74 < north
    r = httpx.get(server.url + "/v1/view/replay", timeout=10.0)
    assert r.status_code == 404
    assert r.json()["error"]["message"] == ("this server replays no file (start one with "
                                            "navsvc view)")


def test_a_viewer_gets_a_snapshot_then_each_batch_then_the_end(
        server: Server, sample_graph: RoadGraph) -> None:
    packets = _packets(sample_graph)
    client = server.client()
    sid = client.post("/sessions", json={"vehicle_id": "viewed"}).json()["id"]
    half = len(packets) // 2
    for i in range(0, half, 500):
        assert client.post(f"/sessions/{sid}/packets",
                           json=packets[i:min(i + 500, half)]).status_code == 200
    with connect(f"{server.ws_url}/v1/sessions/{sid}/view") as viewer:
        first = json.loads(viewer.recv(timeout=10))
        # nobody watched before: the snapshot holds the latest position only
        assert first["type"] == "snapshot" and first["session"]["id"] == sid
        assert len(first["positions"]) == 1 and first["fixes"] == []
        sent_fixes, sent_positions = 0, 0
        for i in range(half, len(packets), 50):
            reply = client.post(f"/sessions/{sid}/packets", json=packets[i:i + 50]).json()
            chunk = packets[i:i + 50]
            sent_fixes += sum(p["kind"] == "gps" for p in chunk)
            sent_positions += len(reply["positions"])
        got_fixes, got_positions = 0, 0
        while got_fixes < sent_fixes or got_positions < sent_positions:
            update = json.loads(viewer.recv(timeout=10))
            assert update["type"] == "update" and "dropped" not in update
            got_fixes += len(update["fixes"])
            got_positions += len(update["positions"])
            assert all(set(f) == {"t", "lat", "lon", "accuracy_m", "hdop"}
                       for f in update["fixes"])
        assert (got_fixes, got_positions) == (sent_fixes, sent_positions) != (0, 0)
        # a second viewer (or a reload) gets what the first saw, as a snapshot
        with connect(f"{server.ws_url}/v1/sessions/{sid}/view") as second:
            snap = json.loads(second.recv(timeout=10))
            assert len(snap["fixes"]) == sent_fixes
            assert len(snap["positions"]) == sent_positions
        viewer.send(b"\xff binary")  # ignored, the viewer goes on
        viewer.send("not json")
        viewer.send(json.dumps({"type": "snapshot"}))  # asked for again
        assert json.loads(viewer.recv(timeout=10))["type"] == "snapshot"
        assert client.delete(f"/sessions/{sid}").status_code == 204
        assert json.loads(viewer.recv(timeout=10)) == {"type": "ended"}
        with pytest.raises(ConnectionClosed) as closed:
            viewer.recv(timeout=10)
        assert closed.value.rcvd is not None and closed.value.rcvd.code == 1000


def test_a_viewer_of_an_unknown_session_is_refused_with_4404(server: Server) -> None:
    with connect(f"{server.ws_url}/v1/sessions/nope/view") as ws:
        with pytest.raises(ConnectionClosed) as closed:
            ws.recv(timeout=10)
    assert closed.value.rcvd is not None
    assert (closed.value.rcvd.code, closed.value.rcvd.reason) == (4404, "no session 'nope'")


def test_with_keys_a_viewer_sees_only_its_keys_sessions(db: Path, tmp_path: Path) -> None:
    s = start_server(db, tmp_path / "server.log", env={"NAVSVC_API_KEYS": "k1,k2"})
    try:
        assert httpx.get(s.url + "/v1/view/config", timeout=10.0).json()["keys_required"]
        sid = s.client(headers={"X-API-Key": "k1"}).post(
            "/sessions", json={"vehicle_id": "k1-car"}).json()["id"]
        for query, code in (("", 4401), ("?api_key=bad", 4401), ("?api_key=k2", 4404)):
            with connect(f"{s.ws_url}/v1/sessions/{sid}/view{query}") as ws:
                with pytest.raises(ConnectionClosed) as closed:
                    ws.recv(timeout=10)
            assert closed.value.rcvd is not None and closed.value.rcvd.code == code, query
        with connect(f"{s.ws_url}/v1/sessions/{sid}/view?api_key=k1") as ws:
            assert json.loads(ws.recv(timeout=10))["type"] == "snapshot"
        assert "api_key=k1" not in s.log.read_text()
    finally:
        s.stop()


def test_a_slow_viewer_loses_the_oldest_updates_and_is_told() -> None:
    async def run() -> None:
        dropped: list[int] = []
        hub = ViewerHub(history_batches=3, queue_messages=2, on_drop=lambda: dropped.append(1))
        hub.publish("s", [{"t": 0.0, "kind": "gps", "lat": 1.0, "lon": 2.0}],
                    {"positions": [], "rejected": [], "accepted": 1})
        assert "s" not in hub  # nobody watched: nothing kept
        viewer = hub.subscribe("s")
        for i in range(5):
            hub.publish("s", [{"t": float(i), "kind": "gps", "lat": 1.0, "lon": 2.0}],
                        {"positions": [{"t": float(i)}], "rejected": [], "accepted": 1})
        first = await viewer.get()
        assert first["fixes"][0]["t"] == 3.0 and first["dropped"] == 3 and len(dropped) == 3
        assert "dropped" not in await viewer.get()
        snapshot = hub.snapshot("s", None)  # the last 3 batches are kept
        assert [f["t"] for f in snapshot["fixes"]] == [2.0, 3.0, 4.0]
        hub.unsubscribe("s", viewer)
        hub.end("s")
        assert "s" not in hub
    asyncio.run(run())


def test_viewer_queue_bounds_its_messages() -> None:
    async def run() -> None:
        queue = ViewerQueue(1)
        queue.put({"type": "update", "n": 1})
        queue.put({"type": "update", "n": 2})
        assert await queue.get() == {"type": "update", "n": 2, "dropped": 1}
    asyncio.run(run())


def test_fixes_of_decodes_nmea_and_skips_other_kinds() -> None:
    gga = "$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47"
    fixes = fixes_of([{"t": 1.0, "kind": "nmea", "sentence": gga},
                      {"t": 1.0, "kind": "imu", "yaw_rate_dps": 1.0},
                      {"t": 2.0, "kind": "gps", "lat": 48.1, "lon": 11.5, "hdop": 1.2}])
    assert [f["t"] for f in fixes] == [1.0, 2.0]
    assert fixes[0]["lat"] == pytest.approx(48.1173) and fixes[0]["hdop"] == 0.9
    assert fixes[1] == {"t": 2.0, "lat": 48.1, "lon": 11.5, "accuracy_m": None, "hdop": 1.2}


def test_replay_of_a_drive_and_of_its_run(sample_graph: RoadGraph, tmp_path: Path) -> None:
    drive = simulate_drive(sample_graph, DriveSpec(duration_s=40.0, seed=2,
                                                   outages=((15.0, 10.0),)))
    path = tmp_path / "drive.jsonl"
    write_records(path, drive)
    replay = load_replay(path, sample_graph, with_truth=True)
    assert replay["kind"] == "drive" and replay["source"] == "drive.jsonl"
    assert len(replay["fixes"]) == sum(r["kind"] == "gps" for r in drive)
    assert len(replay["positions"]) >= 35 and replay["rejected"] == 0
    assert len(replay["truth"]) == sum(r["kind"] == "truth" for r in drive)
    assert load_replay(path, sample_graph)["truth"] == []
    run = tmp_path / "out.jsonl"
    write_records(run, replay["positions"])
    as_run = load_replay(run, sample_graph)
    assert as_run["kind"] == "run" and as_run["positions"] == replay["positions"]


def test_replay_names_bad_lines_and_refuses_an_unusable_file(sample_graph: RoadGraph,
                                                             tmp_path: Path) -> None:
    path = tmp_path / "bad.jsonl"
    path.write_text('{"t": 0, "kind": "gps", "lat": 43.74, "lon": 7.42}\nnot json\n'
                    '{"t": 1, "kind": "gps", "lat": "x", "lon": 7.42}\n')
    replay = load_replay(path, sample_graph)
    assert replay["problems"] == [
        f"{path}:2: not JSON (Expecting value at column 1)",
        f"{path}:3: malformed: lat must be a number, got a string"]
    empty = tmp_path / "empty.jsonl"
    empty.write_text("\n")
    with pytest.raises(TraceError, match="empty.jsonl: no records"):
        load_replay(empty, sample_graph)
    junk = tmp_path / "junk.jsonl"
    junk.write_text('{"a": 1}\n')
    with pytest.raises(TraceError, match="neither sensor packets with a GPS fix nor matched"):
        load_replay(junk, sample_graph)
