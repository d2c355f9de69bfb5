"""`navsvc send`: a drive file streamed to a real server, then evaluated like `navsvc run`."""

from __future__ import annotations

import json
import shutil
import threading
from pathlib import Path

import pytest

from navsvc.cli import main
from navsvc.session import SessionConfig, VehicleSession
from navsvc.sim.simulate import SENSOR_KINDS, DriveSpec, simulate_drive
from navsvc.wire.client import StreamResult, create_session, stream_packets
from navsvc.wire.jsonl import read_records
from navsvc.wire.positions import position_json
from roadgraph import RoadGraph
from tests.api.server import Server, free_port, start_server


def test_send_a_simulated_drive_and_evaluate_it(server: Server, sample_db: Path, tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    drive, out, offline = tmp_path / "drive.jsonl", tmp_path / "out.jsonl", tmp_path / "run.jsonl"
    assert main(["simulate", "--map", str(sample_db), "-o", str(drive), "--seed", "2",
                 "--duration", "120", "--sensors", "all"]) == 0
    capsys.readouterr()
    assert main(["send", str(drive), "--url", server.url, "-o", str(out), "--json",
                 "--quiet"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["rejected"] == 0 and summary["accepted"] == summary["packets"] > 10_000
    assert main(["run", "--map", str(sample_db), "-i", str(drive), "-o", str(offline),
                 "--quiet"]) == 0
    assert read_records(out) == read_records(offline)  # the service and the replay agree
    assert main(["evaluate", "--truth", str(drive), "--estimate", str(out), "--json"]) == 0


def test_send_to_nothing_is_a_clear_error(tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    drive = tmp_path / "d.jsonl"
    drive.write_text('{"t": 0, "kind": "gps", "lat": 43.7, "lon": 7.4}\n')
    url = f"http://127.0.0.1:{free_port()}"
    assert main(["send", str(drive), "--url", url, "--quiet"]) == 1
    assert f"navsvc: error: {url}: cannot connect" in capsys.readouterr().err


def test_send_survives_a_server_crash_without_losing_or_doubling_a_packet(
        sample_db: Path, sample_graph: RoadGraph, tmp_path: Path) -> None:
    """The client resends the unanswered batch under its number after reconnecting: whether
    the crashed server had logged it or not, it is applied exactly once."""
    db = tmp_path / "monaco.db"
    shutil.copy(sample_db, db)
    kinds = set(SENSOR_KINDS["gyro_odometer"])
    packets = [r for r in simulate_drive(sample_graph, DriveSpec(duration_s=90.0, seed=4))
               if r["kind"] in kinds]
    first = start_server(db, tmp_path / "server.log")
    port = int(first.url.rsplit(":", 1)[1])
    sid = create_session(first.url, {"vehicle_id": "crash"})
    sent = threading.Event()
    results: list[StreamResult] = []

    def progress(count: int) -> None:
        sent.set()

    sender = threading.Thread(target=lambda: results.append(stream_packets(
        first.url, sid, packets, batch=20, progress=progress)))
    sender.start()
    assert sent.wait(timeout=60)
    first.kill()
    second = start_server(db, tmp_path / "server.log", port=port)
    try:
        sender.join(timeout=120)
        (result,) = results
        assert result.reconnects >= 1
        assert result.accepted == len(packets) and result.rejected == []
        info = second.client().get(f"/sessions/{sid}").json()
        assert info["packets_accepted"] == len(packets)
        offline = VehicleSession(SessionConfig(), sample_graph)
        offline.add_records(packets)
        assert offline.last_position is not None
        assert info["position"] == position_json(offline.last_position, sample_graph.frame)
    finally:
        second.stop()


def test_send_needs_no_httpx(server: Server, sample_db: Path, tmp_path: Path) -> None:
    """`navsvc send` runs on the runtime dependencies alone (it crashed with
    ModuleNotFoundError: httpx in an install without the test extras)."""
    import subprocess
    import sys

    drive = tmp_path / "drive.jsonl"
    assert main(["simulate", "--map", str(sample_db), "-o", str(drive), "--seed", "3",
                 "--duration", "10", "--sensors", "gyro_odometer"]) == 0
    code = ("import sys\nsys.modules['httpx'] = None  # import httpx now raises\n"
            "from navsvc.cli import main\n"
            f"sys.exit(main(['send', {str(drive)!r}, '--url', {server.url!r}, '--json', "
            "'--quiet']))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert summary["rejected"] == 0 and summary["accepted"] == summary["packets"] > 1000


def test_send_lists_refused_packets_by_line_and_closes_the_session(
        server: Server, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    drive = tmp_path / "d.jsonl"
    drive.write_text('{"t": 0, "kind": "gps", "lat": 43.7398, "lon": 7.4218}\n'
                     'not json\n'
                     '{"t": 1, "kind": "gps", "lat": 91, "lon": 7.4218}\n'
                     '{"t": 2, "kind": "gps", "lat": 43.7399, "lon": 7.4219}\n')
    assert main(["send", str(drive), "--url", server.url, "--quiet"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].endswith(": 2 of 3 packets accepted, 1 rejected, 1 unreadable lines, "
                           "2 positions; session closed")  # each fix, before start-up
    assert out[1:] == [
        f"  {drive}:2: malformed: not JSON (Expecting value at column 1)",
        f"  {drive}:3: out_of_range: a value is out of range: lat=91 (must be <= 90.0)"]
    session_id = out[0].split()[1].rstrip(":")
    assert server.client().get(f"/sessions/{session_id}").status_code == 404  # closed
    assert main(["send", str(drive), "--url", server.url, "--quiet", "--keep", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["closed"] is False and summary["rejections"] == [
        {"line": 2, "code": "malformed", "message": "not JSON (Expecting value at column 1)"},
        {"line": 3, "code": "out_of_range",
         "message": "a value is out of range: lat=91 (must be <= 90.0)"}]
    assert server.client().get(f"/sessions/{summary['session_id']}").status_code == 200


@pytest.mark.parametrize("batch", ["0", "1001", "ten"])
def test_send_refuses_a_bad_batch_size(batch: str, tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(["send", str(tmp_path / "d.jsonl"), "--batch", batch])
    assert exit_.value.code == 2
    assert "argument --batch" in capsys.readouterr().err
