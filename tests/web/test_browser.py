"""The map page in a real browser (Chromium), on a real server (uvicorn on 127.0.0.1): roads,
the fused track and the matched position drawn and moving as a simulated drive streams in;
the replay of a whole drive; API keys. What is drawn is read back from the page's Leaflet
layers (``navsvcView.drawn()``)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import httpx
import pytest
from websockets.sync.client import connect

from navsvc.sim.simulate import SENSOR_KINDS, DriveSpec, simulate_drive
from navsvc.wire.jsonl import write_records
from roadgraph import RoadGraph
from tests.api.server import Server, start_process, start_server
from tests.web.conftest import screenshot

TIMEOUT_MS = 30_000


def drawn(page: Any) -> dict[str, Any]:
    result: dict[str, Any] = page.evaluate("navsvcView.drawn()")
    return result


def wait_for(page: Any, condition: str) -> dict[str, Any]:
    """Wait until ``condition`` (JavaScript over ``d = navsvcView.drawn()``) holds."""
    page.wait_for_function(f"window.navsvcView && (d => {condition})(navsvcView.drawn())",
                           timeout=TIMEOUT_MS)
    return drawn(page)


def stream(ws_url: str, session_id: str, packets: list[dict[str, Any]]) -> int:
    """Send packets over the vehicle WebSocket; return the positions the replies held."""
    positions = 0
    with connect(f"{ws_url}/v1/sessions/{session_id}/stream") as ws:
        for i in range(0, len(packets), 100):
            ws.send(json.dumps(packets[i:i + 100]))
            reply = json.loads(ws.recv(timeout=30))
            assert reply["type"] == "result" and not reply["rejected"]
            positions += len(reply["positions"])
    return positions


@pytest.fixture(scope="module")
def live(sample_db: Path, tmp_path_factory: pytest.TempPathFactory) -> Any:
    folder = tmp_path_factory.mktemp("browser")
    db = folder / "monaco.db"
    db.write_bytes(sample_db.read_bytes())
    s = start_server(db, folder / "server.log")
    yield s
    s.stop()


def test_the_live_map_draws_roads_and_a_streamed_drive_as_it_arrives(
        page: Any, live: Server, sample_graph: RoadGraph, tmp_path: Path) -> None:
    page.goto(live.url + "/")
    start = wait_for(page, "d.roads > 0")
    assert start["roads"] == len(httpx.get(
        live.url + "/v1/maps/monaco/edges",
        params={"bbox": ",".join(map(str, sample_graph.info.bbox_wgs84))},
        timeout=30.0).json()["features"])
    assert start["fused"] == 0 and start["current"] is None and start["sessions"] == []

    kinds = set(SENSOR_KINDS["gyro_odometer"])
    drive = [r for r in simulate_drive(sample_graph, DriveSpec(duration_s=90.0, seed=2,
                                                               outages=((50.0, 12.0),)))
             if r["kind"] in kinds]
    sid = live.client().post("/sessions", json={"vehicle_id": "browser-car"}).json()["id"]
    # the page picks the new session by itself (the newest), and keeps its track from then on
    wait_for(page, f"d.selected === {sid!r}")
    first = [p for p in drive if p["t"] < 30.0]
    sent = stream(live.ws_url, sid, first)
    before = wait_for(page, f"d.selected === {sid!r} && d.fused >= {sent} && d.current")
    assert before["matched"] == before["fused"] == sent
    assert before["fixes"] == sum(p["kind"] == "gps" for p in first)

    rest = [p for p in drive if p["t"] >= 30.0]
    sent += stream(live.ws_url, sid, rest)
    after = wait_for(page, f"d.fused >= {sent}")
    assert after["fused"] == after["matched"] == sent
    assert after["fixes"] == sum(p["kind"] == "gps" for p in drive)
    assert after["current"] != before["current"]  # the matched position moved
    assert after["lastT"] > before["lastT"]
    assert after["outages"] == 1  # the 12 s without GPS, marked
    assert page.inner_text("#d-state") in ("on_road", "ambiguous", "off_road")
    assert "used: accepted" in page.inner_text("#d-gps-counts")
    assert "GPS outage from t=" in page.inner_text("#d-outages")
    page.wait_for_function(  # the session list is polled: it catches up within seconds
        "!document.getElementById('sessions').textContent.includes('no fix yet')",
        timeout=TIMEOUT_MS)
    screenshot(page, "live-map.png", tmp_path)


def test_a_replay_shows_the_whole_drive(page: Any, sample_db: Path, sample_graph: RoadGraph,
                                        tmp_path: Path) -> None:
    drive = simulate_drive(sample_graph, DriveSpec(duration_s=120.0, seed=2,
                                                   outages=((60.0, 20.0),)))
    path = tmp_path / "drive.jsonl"
    write_records(path, drive)
    s = start_process(lambda port: [
        sys.executable, "-m", "navsvc", "view", str(path), "--map", str(sample_db), "--truth",
        "--port", str(port), "--no-browser"], tmp_path / "view.log")
    try:
        replay = httpx.get(s.url + "/v1/view/replay", timeout=30.0).json()
        page.goto(s.url + "/")
        whole = wait_for(page, f"d.replay && d.fused === {len(replay['positions'])}")
        assert whole["roads"] > 0 and whole["current"] is not None
        assert whole["matched"] == len(replay["positions"]) > 100
        assert whole["fixes"] == len(replay["fixes"]) == sum(r["kind"] == "gps" for r in drive)
        assert whole["truth"] == sum(r["kind"] == "truth" for r in drive)
        assert whole["outages"] == 1
        screenshot(page, "replay.png", tmp_path)
        page.fill("#replay-time", "30")  # back in time: the track up to t = 30 s
        page.dispatch_event("#replay-time", "input")
        part = wait_for(page, "d.lastT !== null && d.lastT <= 30")
        assert 0 < part["fused"] < whole["fused"] and part["outages"] == 0
        page.click("#replay-all")
        assert wait_for(page, f"d.fused === {whole['fused']}")["outages"] == 1
    finally:
        s.stop()


def test_with_keys_the_page_asks_for_one_and_shows_only_its_sessions(
        page: Any, db: Path, tmp_path: Path) -> None:
    s = start_server(db, tmp_path / "server.log", env={"NAVSVC_API_KEYS": "key-one,key-two"})
    try:
        mine = s.client(headers={"X-API-Key": "key-one"}).post(
            "/sessions", json={"vehicle_id": "mine"}).json()["id"]
        s.client(headers={"X-API-Key": "key-two"}).post("/sessions",
                                                         json={"vehicle_id": "theirs"})
        page.goto(s.url + "/")
        assert wait_for(page, "d.keyForm")["roads"] == 0  # nothing shown without a key
        page.fill("#key-input", "wrong")
        page.click("#key-form button")
        page.wait_for_function("document.getElementById('key-error').textContent !== ''",
                               timeout=TIMEOUT_MS)
        assert page.inner_text("#key-error") == "that key was refused"
        page.fill("#key-input", "key-one")
        page.click("#key-form button")
        shown = wait_for(page, f"!d.keyForm && d.roads > 0 && d.selected === {mine!r}")
        assert shown["sessions"] == [mine]
        assert "theirs" not in page.inner_text("#sessions")
        assert "api_key=key-one" not in s.log.read_text()
    finally:
        s.stop()
