"""The WebSocket stream end to end: a simulated drive streamed to a real server."""

from __future__ import annotations

import asyncio
import json

import pytest
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from navsvc.api.routes.stream import ReplyQueue
from navsvc.session import SessionConfig, VehicleSession
from navsvc.sim.evaluate import evaluate
from navsvc.sim.simulate import SENSOR_KINDS, DriveSpec, simulate_drive
from navsvc.wire.positions import position_json
from roadgraph import RoadGraph
from tests.api.server import Server

BATCH = 100


def test_drive_streamed_over_websocket_matches_offline_replay_and_truth(
        server: Server, sample_graph: RoadGraph) -> None:
    drive = simulate_drive(sample_graph, DriveSpec(duration_s=300.0, seed=3,
                                                   outages=((150.0, 30.0),)))
    kinds = set(SENSOR_KINDS["gyro_odometer"])
    packets = [r for r in drive if r["kind"] in kinds]
    session = server.client().post("/sessions", json={"vehicle_id": "sim-3"}).json()
    positions = []
    with connect(f"{server.ws_url}/v1/sessions/{session['id']}/stream") as ws:
        for i in range(0, len(packets), BATCH):
            ws.send(json.dumps(packets[i:i + BATCH]))
            reply = json.loads(ws.recv(timeout=30))
            assert reply["type"] == "result" and not reply["rejected"]
            assert "dropped" not in reply
            positions += reply["positions"]
    # the same packets replayed offline (navsvc run's path) give the same positions
    offline = VehicleSession(SessionConfig(), sample_graph)
    expected = [position_json(p, sample_graph.frame)
                for p in offline.add_records(packets).positions]
    assert positions == expected
    result = evaluate(drive, positions)
    assert result.on_right_road_share >= 0.9
    assert result.intersections_correct >= 0.9 * result.intersections_total
    info = server.client().get(f"/sessions/{session['id']}").json()
    assert info["packets_accepted"] == len(packets)


def test_websocket_messages_ping_errors_and_single_packets(server: Server) -> None:
    session = server.client().post("/sessions", json={"vehicle_id": "ws"}).json()
    with connect(f"{server.ws_url}/v1/sessions/{session['id']}/stream") as ws:
        ws.send(json.dumps({"type": "ping"}))
        assert json.loads(ws.recv(timeout=10)) == {"type": "pong"}
        ws.send("{not json")
        error = json.loads(ws.recv(timeout=10))
        assert error["type"] == "error" and error["code"] == "malformed"
        ws.send(json.dumps({"t": 0, "kind": "gps", "lat": 43.7384, "lon": 7.4246}))
        reply = json.loads(ws.recv(timeout=10))
        assert reply["type"] == "result" and reply["accepted"] == 1
        ws.send(json.dumps({"t": 1, "kind": "gps", "lat": 95, "lon": 7.4246}))
        reply = json.loads(ws.recv(timeout=10))
        assert reply["accepted"] == 0 and reply["rejected"][0]["code"] == "out_of_range"


def test_websocket_to_unknown_session_is_closed_with_4404(server: Server) -> None:
    with connect(f"{server.ws_url}/v1/sessions/nope/stream") as ws:
        with pytest.raises(ConnectionClosed) as closed:
            ws.recv(timeout=10)
    assert closed.value.rcvd is not None
    assert (closed.value.rcvd.code, closed.value.rcvd.reason) == (4404, "no session 'nope'")


def test_reply_queue_drops_oldest_when_the_client_does_not_read() -> None:
    class Counter:
        def __init__(self) -> None:
            self.n = 0

        def inc(self, k: int = 1) -> None:
            self.n += k

    class Metrics:
        ws_dropped = Counter()

    class State:
        metrics = Metrics()

    queue = ReplyQueue(3, State())  # type: ignore[arg-type]
    for i in range(10):
        queue.put({"i": i})
    assert queue.dropped == 7 and State.metrics.ws_dropped.n == 7

    sent: list[str] = []

    class FakeSocket:
        async def send_text(self, text: str) -> None:
            sent.append(text)
            if len(sent) == 3:
                raise asyncio.CancelledError

    with pytest.raises(asyncio.CancelledError):
        asyncio.run(queue.send_all(FakeSocket()))  # type: ignore[arg-type]
    assert [json.loads(s) for s in sent] == [{"i": 7, "dropped": 7}, {"i": 8}, {"i": 9}]
