"""Crash safety: a server killed with SIGKILL mid-stream restores its sessions on restart,
and no acknowledged packet is lost."""

from __future__ import annotations

import shutil
import threading
from pathlib import Path

import httpx

from navsvc.session import SessionConfig, VehicleSession
from navsvc.sim.simulate import SENSOR_KINDS, DriveSpec, simulate_drive
from navsvc.wire.positions import position_json
from roadgraph import RoadGraph
from tests.api.server import start_server

BATCH = 50


def test_kill_9_mid_stream_loses_no_acknowledged_packet(
        sample_db: Path, sample_graph: RoadGraph, tmp_path: Path) -> None:
    db = tmp_path / "monaco.db"
    shutil.copy(sample_db, db)
    drive = simulate_drive(sample_graph, DriveSpec(duration_s=120.0, seed=5))
    kinds = set(SENSOR_KINDS["gyro_odometer"])
    packets = [r for r in drive if r["kind"] in kinds]

    first = start_server(db, tmp_path / "server.log")
    client = first.client()
    sid = client.post("/sessions", json={"vehicle_id": "crash"}).json()["id"]
    acknowledged = 0
    half_way = threading.Event()

    def stream() -> None:
        nonlocal acknowledged
        try:
            for i in range(0, len(packets), BATCH):
                r = client.post(f"/sessions/{sid}/packets", json=packets[i:i + BATCH])
                assert r.status_code == 200
                acknowledged += r.json()["accepted"]
                if acknowledged >= len(packets) // 2:
                    half_way.set()
        except httpx.TransportError:
            pass  # the server died under us
        half_way.set()

    sender = threading.Thread(target=stream)
    sender.start()
    assert half_way.wait(timeout=120)
    first.kill()  # SIGKILL while the sender is still posting
    sender.join(timeout=60)
    assert 0 < acknowledged < len(packets)

    second = start_server(db, tmp_path / "server.log")
    try:
        client = second.client()
        info = client.get(f"/sessions/{sid}").json()
        restored = info["packets_accepted"]
        # every acknowledged packet is back; at most the batch in flight at the kill is extra
        assert acknowledged <= restored <= acknowledged + BATCH
        # the restored session is where an uninterrupted one would be after those packets
        offline = VehicleSession(SessionConfig(), sample_graph)
        offline.add_records(packets[:restored])
        assert offline.last_position is not None
        assert info["position"] == position_json(offline.last_position, sample_graph.frame)
        # and it carries on: the rest of the drive gives what one uninterrupted run gives
        rest = []
        for i in range(restored, len(packets), BATCH):
            rest += client.post(f"/sessions/{sid}/packets",
                                json=packets[i:i + BATCH]).json()["positions"]
        expected = offline.add_records(packets[restored:]).positions
        assert rest == [position_json(p, sample_graph.frame) for p in expected]
    finally:
        second.stop()


def test_deleted_session_is_not_restored(sample_db: Path, tmp_path: Path) -> None:
    db = tmp_path / "monaco.db"
    shutil.copy(sample_db, db)
    server = start_server(db, tmp_path / "server.log")
    client = server.client()
    keep = client.post("/sessions", json={"vehicle_id": "keep"}).json()["id"]
    gone = client.post("/sessions", json={"vehicle_id": "gone"}).json()["id"]
    client.delete(f"/sessions/{gone}")
    server.kill()
    server = start_server(db, tmp_path / "server.log")
    try:
        ids = {s["id"] for s in server.client().get("/sessions").json()["sessions"]}
        assert ids == {keep}
    finally:
        server.stop()


def test_idle_sessions_expire(sample_db: Path, tmp_path: Path) -> None:
    db = tmp_path / "monaco.db"
    shutil.copy(sample_db, db)
    server = start_server(db, tmp_path / "server.log", env={"NAVSVC_SESSION_IDLE_S": "1"})
    try:
        client = server.client()
        sid = client.post("/sessions", json={"vehicle_id": "idle"}).json()["id"]
        for _ in range(50):
            if client.get(f"/sessions/{sid}").status_code == 404:
                break
            threading.Event().wait(0.1)
        assert client.get(f"/sessions/{sid}").status_code == 404
        assert "navsvc_sessions_expired_total 1.0" in client.get("/metrics").text
    finally:
        server.stop()
