"""`navsvc match` over many traces: one route file each and a summary; a bad trace is named
with its line and the others go on; the same results in process and on a real Dask
LocalCluster of 2 workers."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from navsvc.batch import expand_traces, output_paths
from navsvc.cli import main
from navsvc.errors import ConfigError
from navsvc.sim.simulate import DriveSpec, simulate_drive
from navsvc.wire.jsonl import write_records
from roadgraph import RoadGraph


@pytest.fixture(scope="module")
def traces(sample_graph: RoadGraph, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder: two simulated drives (JSON Lines; their GPS packets are the trace), a CSV
    of the first's fixes, and a CSV broken on line 3."""
    folder = tmp_path_factory.mktemp("traces")
    for seed in (1, 4):
        records = simulate_drive(sample_graph, DriveSpec(duration_s=60.0, seed=seed,
                                                         sensors=("gps",)))
        write_records(folder / f"drive{seed}.jsonl", records)
    fixes = [r for r in simulate_drive(sample_graph, DriveSpec(duration_s=60.0, seed=1,
                                                               sensors=("gps",)))
             if r["kind"] == "gps"]
    (folder / "fixes.csv").write_text("t,lat,lon\n" + "".join(
        f"{r['t']},{r['lat']},{r['lon']}\n" for r in fixes))
    (folder / "broken.csv").write_text("t,lat,lon\n0,43.73,7.42\n1,north,7.42\n")
    (folder / "notes.txt").write_text("not a trace")  # a folder's other files are left
    return folder


def batch(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, dict, str]:
    code = main(["match", *args, "--json", "--quiet"])
    captured = capsys.readouterr()
    return code, json.loads(captured.out), captured.err


def test_a_folder_matches_every_trace_and_names_the_bad_one(
        traces: Path, sample_db: Path, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "routes"
    code, summary, err = batch([str(traces), "--map", str(sample_db), "--out-dir", str(out)],
                               capsys)
    assert code == 1  # one trace failed; the others were matched
    by_name = {Path(t["trace"]).name: t for t in summary["traces"]}
    assert sorted(by_name) == ["broken.csv", "drive1.jsonl", "drive4.jsonl", "fixes.csv"]
    broken = traces / "broken.csv"
    assert by_name["broken.csv"]["error"].startswith(f"{broken}:3: ")
    assert f"navsvc: error: {broken}:3: " in err
    assert summary["total"]["matched"] == 3 and summary["total"]["failed"] == 1
    for name in ("drive1", "drive4", "fixes"):
        t = by_name[f"{name}.jsonl" if name != "fixes" else "fixes.csv"]
        route = json.loads((out / f"{name}.route.json").read_text())
        assert t["points"] == len(route["points"]) > 10 and t["length_m"] == route["length_m"]
        assert t["matched_share"] > 0.8 and t["time_s"] > 0.0 and t["error"] is None
    # a trace matched alone gives the same route as in the batch
    single = tmp_path / "single.json"
    assert main(["match", str(traces / "fixes.csv"), "--map", str(sample_db), "-o",
                 str(single)]) == 0
    assert json.loads(single.read_text()) == json.loads((out / "fixes.route.json").read_text())
    assert by_name["fixes.csv"]["length_m"] == by_name["drive1.jsonl"]["length_m"]


def test_dask_workers_give_the_same_routes(traces: Path, sample_db: Path, tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    glob = str(traces / "drive*.jsonl")
    one, two = tmp_path / "one", tmp_path / "two"
    code1, s1, _ = batch([glob, "--map", str(sample_db), "--out-dir", str(one)], capsys)
    code2, s2, _ = batch([glob, "--map", str(sample_db), "--out-dir", str(two), "--workers",
                          "2"], capsys)
    assert code1 == code2 == 0
    assert s2["total"]["workers"] == 2 and "local Dask cluster" in s2["total"]["where"]
    assert s1["total"]["where"] == "in process"
    for name in ("drive1.route.json", "drive4.route.json"):
        assert (one / name).read_text() == (two / name).read_text()
    strip = [{k: v for k, v in t.items() if k not in ("time_s", "output")} for t in s1["traces"]]
    assert strip == [{k: v for k, v in t.items() if k not in ("time_s", "output")}
                     for t in s2["traces"]]


def test_usage_errors(traces: Path, sample_db: Path, tmp_path: Path,
                      capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["match", str(traces), "--map", str(sample_db), "-o", "x.json"]) == 2
    assert "-o names one route file; for several traces use --out-dir" in \
        capsys.readouterr().err
    assert main(["match", str(tmp_path / "none*.gpx"), "--map", str(sample_db)]) == 1
    assert f"navsvc: error: {tmp_path / 'none*.gpx'}: no file matches" in \
        capsys.readouterr().err
    with pytest.raises(ConfigError, match="no such file or folder"):
        expand_traces([str(tmp_path / "missing.gpx")])


def test_repeated_stems_get_distinct_route_files(tmp_path: Path) -> None:
    names = [Path("a/x.gpx"), Path("b/x.gpx"), Path("b/y.csv")]
    assert [p.name for p in output_paths(names, tmp_path)] == [
        "x.route.json", "x-2.route.json", "y.route.json"]


def test_chunks_keep_order_and_size() -> None:
    from navsvc.batch import chunks

    assert chunks(list(range(10)), 2) == [[0, 1], [2, 3], [4, 5], [6, 7], [8, 9]]
    assert chunks(list(range(3)), 0) == [[0], [1], [2]]  # in process: one each
    assert chunks(list(range(8)), 1) == [[0, 1], [2, 3], [4, 5], [6, 7]]  # 1 worker: chunks
    assert chunks(list(range(3)), 8) == [[0], [1], [2]]
    assert chunks([], 2) == []


def test_scheduler_joins_an_existing_cluster(traces: Path, sample_db: Path, tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str],
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """--scheduler ADDRESS sends the same work to a cluster someone else started."""
    from distributed import LocalCluster

    import navsvc.batch
    monkeypatch.setattr(navsvc.batch, "SCHEDULER_TIMEOUT_S", 1.0)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address="127.0.0.1:0") as cluster:
        code, summary, _ = batch([str(traces / "drive1.jsonl"), "--map", str(sample_db),
                                  "--out-dir", str(tmp_path), "--scheduler",
                                  cluster.scheduler_address], capsys)
        assert len(cluster.scheduler_info["workers"]) == 1  # left running for its owner
    assert code == 0 and summary["total"]["where"] == \
        f"on the Dask cluster at {cluster.scheduler_address}"
    assert (tmp_path / "drive1.route.json").exists()
    assert main(["match", str(traces), "--map", str(sample_db), "--scheduler",
                 "tcp://127.0.0.1:1"]) == 1
    assert "navsvc: error: cannot reach the Dask scheduler at tcp://127.0.0.1:1" in \
        capsys.readouterr().err
