"""`navsvc send`: a drive file streamed to a real server, then evaluated like `navsvc run`."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from navsvc.cli import main
from navsvc.wire.jsonl import read_records
from tests.api.server import Server, free_port


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
