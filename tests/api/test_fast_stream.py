"""The picows session stream (navsvc/api/fast_stream.py) against a real server on 127.0.0.1:
the same replies as the uvicorn endpoint, the same errors, auth and close codes."""

from __future__ import annotations

import json
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.sync.client import connect

from navsvc.api.fast_stream import StreamListener
from navsvc.sim.simulate import SENSOR_KINDS, DriveSpec, simulate_drive
from roadgraph import RoadGraph
from tests.api.server import Server, free_port, start_server

KEY = "fast-key"
HEADERS = {"X-API-Key": KEY}


@pytest.fixture(scope="module")
def served(sample_db: Path, tmp_path_factory: pytest.TempPathFactory
           ) -> Iterator[tuple[Server, str]]:
    """A server with API keys and the picows stream; its picows base URL."""
    folder = tmp_path_factory.mktemp("fast")
    db = folder / "monaco.db"
    shutil.copy(sample_db, db)
    port = free_port()
    server = start_server(db, folder / "server.log",
                          env={"NAVSVC_STREAM_PORT": str(port), "NAVSVC_API_KEYS": KEY})
    yield server, f"ws://127.0.0.1:{port}"
    server.stop()


def _session(server: Server, sensors: str = "gyro_accel") -> str:
    created = server.client(headers=HEADERS).post(
        "/sessions", json={"vehicle_id": "fast", "sensors": sensors})
    assert created.status_code == 201
    session_id: str = created.json()["id"]
    return session_id


def _stream(url: str, messages: list[str | bytes]) -> list[dict[str, Any]]:
    with connect(url, additional_headers=HEADERS, max_size=None) as ws:
        replies = []
        for message in messages:
            ws.send(message)
            replies.append(json.loads(ws.recv(timeout=30)))
    return replies


def test_a_drive_gets_the_same_replies_on_picows_as_on_uvicorn(
        served: tuple[Server, str], sample_graph: RoadGraph) -> None:
    server, fast = served
    drive = simulate_drive(sample_graph, DriveSpec(duration_s=120.0, seed=5))
    kinds = set(SENSOR_KINDS["gyro_accel"])
    packets = [r for r in drive if r["kind"] in kinds]
    messages: list[str | bytes] = [json.dumps(packets[i:i + 10])
                                   for i in range(0, len(packets), 10)]
    messages[3] = json.dumps({"type": "batch", "seq": 7, "packets": json.loads(messages[3])})
    messages.insert(4, messages[3])  # a resend: answered with the first reply, "duplicate"
    messages[9] = str(messages[9]).encode()  # a binary frame of the same JSON
    too_far = [{"t": 1e9, "kind": "imu", "yaw_rate_dps": 0.0}]  # refused: far ahead
    messages.insert(12, json.dumps(too_far))
    via_uvicorn = _stream(f"{server.ws_url}/v1/sessions/{_session(server)}/stream", messages)
    via_picows = _stream(f"{fast}/v1/sessions/{_session(server)}/stream", messages)
    assert via_picows == via_uvicorn
    assert sum(len(r["positions"]) for r in via_picows) >= 100
    assert via_picows[4]["duplicate"] and via_picows[12]["rejected"][0]["code"] == "out_of_range"


def test_pings_errors_and_single_packets(served: tuple[Server, str]) -> None:
    server, fast = served
    url = f"{fast}/v1/sessions/{_session(server)}/stream"
    replies = _stream(url, [json.dumps({"type": "ping"}), "{not json", b"\xff\xfe",
                            json.dumps({"type": "batch", "seq": -1, "packets": []}),
                            json.dumps({"t": 0, "kind": "gps", "lat": 43.7384, "lon": 7.4246})])
    assert replies[0] == {"type": "pong"}
    assert [r.get("code") for r in replies[1:4]] == ["malformed"] * 3
    assert replies[2]["message"] == "binary message is not UTF-8 JSON text"
    assert replies[4]["type"] == "result" and replies[4]["accepted"] == 1
    with connect(url, additional_headers=HEADERS) as ws:  # one message in three frames
        ws.send(iter(['[{"t": 1, "kind": "gps", ', '"lat": 43.7385, ', '"lon": 7.4246}]']))
        assert json.loads(ws.recv(timeout=10))["accepted"] == 1


def test_unknown_sessions_and_keys_are_closed_with_the_api_codes(
        served: tuple[Server, str]) -> None:
    server, fast = served
    session = _session(server)
    with connect(f"{fast}/v1/sessions/nope/stream", additional_headers=HEADERS) as ws:
        with pytest.raises(ConnectionClosed) as closed:
            ws.recv(timeout=10)
    assert closed.value.rcvd is not None
    assert (closed.value.rcvd.code, closed.value.rcvd.reason) == (4404, "no session 'nope'")
    for url, headers in ((f"{fast}/v1/sessions/{session}/stream", {}),
                         (f"{fast}/v1/sessions/{session}/stream", {"X-API-Key": "wrong"})):
        with connect(url, additional_headers=headers) as ws:
            with pytest.raises(ConnectionClosed) as closed:
                ws.recv(timeout=10)
        assert closed.value.rcvd is not None and closed.value.rcvd.code == 4401
        assert closed.value.rcvd.reason == "missing or unknown API key (header X-API-Key)"
    with connect(f"{fast}/v1/sessions/{session}/stream?api_key={KEY}") as ws:  # browsers
        ws.send(json.dumps({"type": "ping"}))
        assert json.loads(ws.recv(timeout=10)) == {"type": "pong"}
    with pytest.raises(InvalidStatus) as refused:
        connect(f"{fast}/v1/sessions")
    assert refused.value.response.status_code == 404


class _Transport:
    """What StreamListener._send uses of a picows transport."""

    is_disconnected = False

    def __init__(self) -> None:
        self.sent: list[dict[str, Any]] = []

    def send(self, kind: object, payload: bytes) -> None:
        self.sent.append(json.loads(payload))


def test_replies_wait_while_the_client_does_not_read_and_the_oldest_are_dropped() -> None:
    class Counter:
        n = 0

        def inc(self) -> None:
            self.n += 1

    class State:
        class settings:  # noqa: N801
            ws_queue_messages = 3

        class metrics:  # noqa: N801
            ws_dropped = Counter()

    listener = StreamListener(State(), "s", None, set())  # type: ignore[arg-type]
    transport = _Transport()
    listener._transport = transport  # type: ignore[assignment]
    listener._send({"i": 0})
    listener.pause_writing()
    for i in range(1, 8):
        listener._send({"i": i})
    assert transport.sent == [{"i": 0}] and State.metrics.ws_dropped.n == 4
    listener.resume_writing()
    assert transport.sent == [{"i": 0}, {"i": 5, "dropped": 4}, {"i": 6}, {"i": 7}]
