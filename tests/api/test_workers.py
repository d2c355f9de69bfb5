"""`navsvc serve --workers 2` for real: HAProxy from Debian in front of two worker processes
(uvicorn on 127.0.0.1) under the supervisor, driven through the balancer over REST and
WebSocket. A worker killed with SIGKILL comes back with its sessions; the other's WebSocket
never notices; no acknowledged packet is lost; SIGTERM stops everything."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.sync.client import connect

from navsvc.cluster import find_haproxy
from navsvc.errors import ConfigError
from navsvc.sim.simulate import SENSOR_KINDS, DriveSpec, simulate_drive
from roadgraph import RoadGraph
from tests.api.server import Server, free_port, start_process

BATCH = 50


def _haproxy() -> str:
    try:
        return find_haproxy()
    except ConfigError:
        pytest.skip("no HAProxy installed (apt-get install haproxy; make test does it as "
                    "root)")


def children(pid: int) -> dict[int, str]:
    """The child processes of ``pid``: their command lines by pid."""
    found = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:
            continue
        if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
            found[int(entry.name)] = cmdline
    return found


def worker_pid(cluster: Server, worker: int) -> int:
    return next(pid for pid, cmd in children(cluster.process.pid).items()
                if f"--worker-id {worker} " in cmd + " ")


def wait_until(condition: object, timeout_s: float = 120.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            if condition():  # type: ignore[operator]
                return
        except httpx.TransportError:
            pass
        time.sleep(0.2)
    raise AssertionError(f"not so within {timeout_s} s")


def workers_up(cluster: Server) -> set[str]:
    text = httpx.get(cluster.url + "/v1/metrics", timeout=10).text
    return set(re.findall(r'navsvc_worker_up\{worker="(\d+)"\} 1\.0', text))


@pytest.fixture(scope="module")
def stream_port() -> int:
    """The balancer's port for the picows session streams (serve --stream-port)."""
    return free_port()


@pytest.fixture(scope="module")
def cluster(sample_db: Path, tmp_path_factory: pytest.TempPathFactory, stream_port: int
            ) -> Iterator[Server]:
    _haproxy()
    folder = tmp_path_factory.mktemp("cluster")
    db = folder / "monaco.db"
    shutil.copy(sample_db, db)
    base = free_port()
    server = start_process(lambda port: [
        sys.executable, "-m", "navsvc", "serve", "--map", str(db), "--host", "127.0.0.1",
        "--port", str(port), "--workers", "2", "--worker-port-base", str(base),
        "--stream-port", str(stream_port)],
        folder / "cluster.log")
    wait_until(lambda: workers_up(server) == {"0", "1"})
    yield server
    server.stop()


@pytest.fixture(scope="module")
def packets(sample_graph: RoadGraph) -> list[dict]:
    drive = simulate_drive(sample_graph, DriveSpec(duration_s=60.0, seed=11))
    kinds = set(SENSOR_KINDS["gyro_odometer"])
    return [r for r in drive if r["kind"] in kinds]


def one_on_each_worker(client: httpx.Client) -> dict[str, str]:
    """Create sessions until there is one on each worker: their ids by worker ("w0", "w1").
    HAProxy's health checks may take a few seconds more than the workers to see both up
    (until then new sessions all go to one): keep trying for 30 s."""
    ids: dict[str, str] = {}
    deadline = time.monotonic() + 30.0
    while time.monotonic() < deadline:
        sid = client.post("/sessions", json={"vehicle_id": "fleet"}).json()["id"]
        ids.setdefault(sid.split("-")[0], sid)
        if len(ids) == 2:
            return ids
        time.sleep(0.1)
    raise AssertionError(f"sessions landed on one worker only: {ids}")


def test_the_picows_streams_reach_each_sessions_worker_through_the_balancer(
        cluster: Server, stream_port: int, packets: list[dict]) -> None:
    client = cluster.client()
    streams = f"ws://127.0.0.1:{stream_port}/v1/sessions"
    for sid in one_on_each_worker(client).values():
        with connect(f"{streams}/{sid}/stream") as ws:
            for i in range(0, 4 * BATCH, BATCH):
                ws.send(json.dumps(packets[i:i + BATCH]))
                reply = json.loads(ws.recv(timeout=30))
                assert reply["type"] == "result" and reply["accepted"] == BATCH
        assert client.get(f"/sessions/{sid}").json()["packets_accepted"] == 4 * BATCH
    with connect(f"{streams}/w1-nope/stream") as ws:  # worker 1's picows says so
        with pytest.raises(ConnectionClosed) as closed:
            ws.recv(timeout=10)
    assert closed.value.rcvd is not None and closed.value.rcvd.code == 4404
    with pytest.raises(InvalidStatus) as refused:  # no worker's id: HAProxy's 404
        connect(f"{streams}/nope/stream")
    assert refused.value.response.status_code == 404


def test_session_ids_name_their_worker_and_every_request_reaches_it(
        cluster: Server, packets: list[dict]) -> None:
    client = cluster.client()
    ids = one_on_each_worker(client)
    assert set(ids) == {"w0", "w1"}
    for sid in ids.values():
        assert re.fullmatch(r"w[01]-[0-9a-f]{16}", sid)
        for _ in range(4):  # the balancer sends each of them to the same worker every time
            assert client.get(f"/sessions/{sid}").json()["id"] == sid
        reply = client.post(f"/sessions/{sid}/packets", json=packets[:BATCH]).json()
        assert reply["accepted"] == BATCH
        with connect(f"{cluster.ws_url}/v1/sessions/{sid}/stream") as ws:
            ws.send(json.dumps(packets[BATCH:2 * BATCH]))
            assert json.loads(ws.recv(timeout=30))["accepted"] == BATCH
        assert client.get(f"/sessions/{sid}").json()["packets_accepted"] == 2 * BATCH
    listed = client.get("/sessions").json()  # whichever worker answers lists both
    assert set(ids.values()) <= {s["id"] for s in listed["sessions"]}
    assert listed["workers_unreachable"] == []
    alone = client.get("/sessions", params={"scope": "worker"}).json()["sessions"]
    assert len({s["id"].split("-")[0] for s in alone}) == 1
    for sid in ids.values():
        assert client.delete(f"/sessions/{sid}").status_code == 204
        assert client.get(f"/sessions/{sid}").status_code == 404


def test_metrics_cover_every_worker(cluster: Server, packets: list[dict]) -> None:
    client = cluster.client()
    ids = one_on_each_worker(client)
    for sid in ids.values():
        client.post(f"/sessions/{sid}/packets", json=packets[:BATCH] + [{"t": 1.0}])
    text = client.get("/metrics").text
    for name in ("navsvc_packets_accepted_total", "navsvc_sessions",
                 "navsvc_batch_seconds_count", "navsvc_triplog_append_seconds_count",
                 "navsvc_checkpoint_lag_packets", "navsvc_event_loop_lag_seconds_count"):
        for worker in ("0", "1"):
            match = re.search(rf'^{name}\{{worker="{worker}"\}} (\S+)$', text, re.M)
            assert match and float(match.group(1)) > 0, (name, worker)
    for worker in ("0", "1"):
        assert re.search(rf'navsvc_packets_rejected_total\{{reason="[a-z_]+",worker="{worker}"'
                         r'\} [1-9]', text)
        assert re.search(rf'navsvc_triplog_bytes\{{file="database",worker="{worker}"\}} '
                         r'[1-9]', text)
    alone = client.get("/metrics", params={"scope": "worker"}).text  # for a scrape per worker
    assert "worker=" not in alone and "navsvc_triplog_append_seconds_count" in alone
    for sid in ids.values():
        client.delete(f"/sessions/{sid}")


def test_kill_9_of_one_worker_loses_nothing_and_the_other_never_notices(
        cluster: Server, packets: list[dict]) -> None:
    client = cluster.client()
    ids = one_on_each_worker(client)
    victim, bystander = ids["w1"], ids["w0"]
    half = len(packets) // 2 // BATCH * BATCH
    acknowledged = 0
    for seq, i in enumerate(range(0, half, BATCH)):
        r = client.post(f"/sessions/{victim}/packets", params={"batch_seq": seq},
                        json=packets[i:i + BATCH])
        assert r.status_code == 200
        acknowledged += r.json()["accepted"]
    bystander_replies: list[dict] = []
    killed, done = threading.Event(), threading.Event()

    def stream_bystander() -> None:  # one WebSocket through the balancer, before and after
        with connect(f"{cluster.ws_url}/v1/sessions/{bystander}/stream") as ws:
            for seq, i in enumerate(range(0, len(packets), BATCH)):
                if seq == 3:
                    killed.wait(timeout=30)
                ws.send(json.dumps({"type": "batch", "seq": seq,
                                    "packets": packets[i:i + BATCH]}))
                bystander_replies.append(json.loads(ws.recv(timeout=30)))
                time.sleep(0.05)
        done.set()

    sender = threading.Thread(target=stream_bystander)
    sender.start()
    old = worker_pid(cluster, 1)
    os.kill(old, signal.SIGKILL)
    killed.set()
    # a new connection: HAProxy closes a client's kept-alive one whose worker died, as any
    # server restarting would
    client = cluster.client()
    during = client.get(f"/sessions/{victim}")  # its worker is down, or back already
    assert during.status_code in (200, 502, 503, 504)
    if during.status_code != 200:  # the API's error shape, from HAProxy
        assert during.json()["error"]["code"] == "unavailable"
    wait_until(lambda: client.get(f"/sessions/{victim}").status_code == 200)
    assert worker_pid(cluster, 1) != old  # the supervisor started it again
    info = client.get(f"/sessions/{victim}").json()
    assert info["packets_accepted"] == acknowledged  # restored from its own trip log
    # the client goes on where it was: a resend of its last batch is known, the next applies
    last = half // BATCH - 1
    again = client.post(f"/sessions/{victim}/packets", params={"batch_seq": last},
                        json=packets[half - BATCH:half]).json()
    assert again["duplicate"] is True
    with connect(f"{cluster.ws_url}/v1/sessions/{victim}/stream") as ws:
        ws.send(json.dumps({"type": "batch", "seq": last + 1,
                            "packets": packets[half:half + BATCH]}))
        assert json.loads(ws.recv(timeout=30))["accepted"] == BATCH
    assert client.get(f"/sessions/{victim}").json()["packets_accepted"] == acknowledged + BATCH
    sender.join(timeout=120)
    assert done.is_set()
    assert [r["type"] for r in bystander_replies] == ["result"] * len(bystander_replies)
    assert sum(r["accepted"] for r in bystander_replies) == len(packets)
    assert client.get(f"/sessions/{bystander}").json()["packets_accepted"] == len(packets)
    for sid in ids.values():
        client.delete(f"/sessions/{sid}")


def test_sigterm_stops_the_balancer_and_every_worker(cluster: Server) -> None:
    """(Last: it ends the module's cluster.)"""
    spawned = children(cluster.process.pid)
    assert len(spawned) == 3 and sum("haproxy" in cmd for cmd in spawned.values()) == 1
    cluster.process.send_signal(signal.SIGTERM)
    assert cluster.process.wait(timeout=60) == 0
    assert not [pid for pid in spawned if Path(f"/proc/{pid}").exists()]
    with pytest.raises(httpx.TransportError):
        httpx.get(cluster.url + "/v1/healthz", timeout=2)
