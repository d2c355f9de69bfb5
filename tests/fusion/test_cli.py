"""`navsvc simulate | run | evaluate` end to end on the sample map."""

import json
from pathlib import Path

import pytest

from navsvc.cli import main


@pytest.fixture(scope="module")
def drive_file(sample_db: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("drive") / "drive.jsonl"
    assert main(["simulate", "--map", str(sample_db), "-o", str(path), "--seed", "4",
                 "--duration", "90", "--outage", "40:20"]) == 0
    return path


def test_simulate_writes_packets_and_truth(drive_file: Path) -> None:
    kinds = {json.loads(line)["kind"] for line in drive_file.read_text().splitlines()}
    assert kinds == {"truth", "gps", "imu", "odometer", "steering"}


def test_simulate_sensor_choice_and_json(sample_db: Path, tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "d.jsonl"
    assert main(["simulate", "--map", str(sample_db), "-o", str(out), "--duration", "10",
                 "--sensors", "steering_odometer", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert set(summary["by_kind"]) == {"truth", "gps", "odometer", "steering"}
    assert summary["records"] == len(out.read_text().splitlines())


def test_run_then_evaluate(sample_db: Path, drive_file: Path, tmp_path: Path,
                           capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out.jsonl"
    assert main(["run", "--map", str(sample_db), "-i", str(drive_file), "-o", str(out),
                 "--json", "--quiet"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["rejected"] == 0 and summary["positions"] >= 85
    first = json.loads(out.read_text().splitlines()[0])
    assert {"t", "lat", "lon", "fused_lat", "fused_lon", "heading_deg", "speed_mps",
            "position_sigma_m", "state", "edge", "gps"} <= set(first)
    plot = tmp_path / "run.png"
    assert main(["evaluate", "--truth", str(drive_file), "--estimate", str(out), "--json",
                 "--plot", str(plot), "--map", str(sample_db)]) == 0
    metrics = json.loads(capsys.readouterr().out)
    assert metrics["fused"]["rms_m"] < metrics["raw_gps"]["rms_m"]
    outage = next(o for o in metrics["outages"] if o["start_s"] <= 41 <= o["end_s"])
    assert outage["distance_m"] > 50 and outage["end_error_m"] < 15.0  # bias still settling
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["evaluate", "--truth", str(drive_file), "--estimate", str(out)]) == 0
    assert "fused / raw GPS RMS" in capsys.readouterr().out


def test_evaluate_plots_a_drive_without_truth(sample_db: Path, drive_file: Path,
                                              tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    """A real log has no truth: --plot draws raw GPS, fused and matched over the map; without
    --plot it is an error that says so."""
    log = tmp_path / "log.jsonl"
    log.write_text("".join(line + "\n" for line in drive_file.read_text().splitlines()
                           if json.loads(line)["kind"] != "truth"))
    out = tmp_path / "out.jsonl"
    assert main(["run", "--map", str(sample_db), "-i", str(log), "-o", str(out),
                 "--quiet"]) == 0
    plot = tmp_path / "log.png"
    assert main(["evaluate", "--truth", str(log), "--estimate", str(out), "--plot", str(plot),
                 "--map", str(sample_db), "--title", "a real log"]) == 0
    assert "no truth records; plotted" in capsys.readouterr().out
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["evaluate", "--truth", str(log), "--estimate", str(out)]) == 1
    assert "has no truth records" in capsys.readouterr().err


def test_run_reports_bad_lines_and_keeps_going(sample_db: Path, drive_file: Path,
                                               tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    lines = drive_file.read_text().splitlines()[:3000]
    lines[5] = "{not json"
    lines[6] = json.dumps({"t": 0.5, "kind": "gps", "lat": 123.0, "lon": 7.4})
    bad = tmp_path / "bad.jsonl"
    bad.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out.jsonl"
    assert main(["run", "--map", str(sample_db), "-i", str(bad), "-o", str(out),
                 "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "2 rejected" in text
    assert f"{bad}:6: malformed: not JSON" in text
    assert f"{bad}:7: out_of_range: lat=123.0" in text
    assert out.read_text()


def test_evaluate_names_file_and_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    truth = tmp_path / "t.jsonl"
    truth.write_text('{"t": 0, "kind": "truth"}\n[1, 2]\n')
    assert main(["evaluate", "--truth", str(truth), "--estimate", str(truth)]) == 1
    assert f"{truth}:2: expected a JSON object" in capsys.readouterr().err


def test_missing_map_and_bad_outage(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["simulate", "--map", str(tmp_path / "none.db"), "-o",
                 str(tmp_path / "d.jsonl")]) == 1
    assert "none.db" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["simulate", "--map", "x.db", "-o", "d.jsonl", "--outage", "12"])
    assert exc.value.code == 2
    assert "expected START:LENGTH" in capsys.readouterr().err
