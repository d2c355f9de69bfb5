"""`navsvc tune` on real replays of two seeded drives: both methods improve a deliberately
mistuned profile, a resumed run ends where a whole one does, Dask gives the same answer as
one process, and bad input is refused naming the file."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import shapely

from navsvc.batch import Executor, executor, worker_graph
from navsvc.cli import main
from navsvc.tuning.params import select
from navsvc.tuning.replay import TuneDrive, replay
from navsvc.tuning.run import TuneRun, result_profile, tune
from roadgraph import RoadGraph
from tests.tuning.conftest import MISTUNED, TUNED


def tune_args(db: Path, drives: list[Path], out: Path, *extra: str) -> list[str]:
    return ["tune", "--map", str(db), "--drives", *map(str, drives), "--params", TUNED,
            "-o", str(out), "--quiet", "--json", *extra]


@pytest.mark.parametrize("method", ["hill", "ga"])
def test_each_method_improves_a_mistuned_profile(method: str, sample_db: Path,
                                                 drive_files: list[Path], mistuned: Path,
                                                 tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "profile.json"
    assert main(tune_args(sample_db, drive_files, out, "--from", str(mistuned), "--method",
                          method, "--budget", "10", "--population", "4", "--seed", "3")) == 0
    summary = json.loads(capsys.readouterr().out)
    profile = json.loads(out.read_text())
    tuned = profile["tuned"]
    assert tuned["fitness_after"] > tuned["fitness_before"] + 0.01
    assert summary["fitness_after"] == tuned["fitness_after"] and tuned["replays"] <= 20
    assert tuned["drives"] == [str(p) for p in drive_files]
    assert set(profile["parameters"]) <= set(TUNED.split(","))
    # the profile, applied as a session's, scores what the run said it would
    graph = RoadGraph.open(sample_db)
    from navsvc.tuning.fitness import mean_fitness
    from navsvc.wire.jsonl import read_records
    scores = [replay(graph, TuneDrive(str(p), tuple(read_records(p))), {},
                     profile["parameters"]) for p in drive_files]
    assert mean_fitness(scores) == pytest.approx(tuned["fitness_after"], abs=1e-5)


def test_a_resumed_run_ends_where_a_whole_one_does(sample_db: Path, drive_files: list[Path],
                                                   mistuned: Path, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    common = ("--from", str(mistuned), "--method", "ga", "--population", "4", "--seed", "1")
    whole, part = tmp_path / "whole.json", tmp_path / "part.json"
    state = tmp_path / "state.json"
    assert main(tune_args(sample_db, drive_files, whole, *common, "--budget", "9")) == 0
    assert main(tune_args(sample_db, drive_files, part, *common, "--budget", "5",
                          "--resume", str(state))) == 0
    # the start, one generation of 4 whose first is the start again (cached), and the
    # next generation's first new point: the budget is spent to the last evaluation
    assert json.loads(state.read_text())["evaluations"] == 5
    assert main(tune_args(sample_db, drive_files, part, *common, "--budget", "9",
                          "--resume", str(state))) == 0
    assert json.loads(part.read_text()) == json.loads(whole.read_text())
    capsys.readouterr()
    assert main(tune_args(sample_db, drive_files, part, "--method", "hill", "--budget", "9",
                          "--resume", str(state))) == 1
    assert "the state is of another run: its method is 'ga', this command's 'hill'" in \
        capsys.readouterr().err
    old = tmp_path / "old.json"
    old.write_text(json.dumps({**json.loads(state.read_text()),
                               "format": "navsvc-tune-state/1"}))
    assert main(tune_args(sample_db, drive_files, part, *common, "--budget", "9",
                          "--resume", str(old))) == 1
    assert (f"{old}: a tuning state of another navsvc version (navsvc-tune-state/1; this "
            "one reads navsvc-tune-state/2): start the run again") in capsys.readouterr().err


def test_dask_local_cluster_gives_the_answer_of_one_process(sample_db: Path,
                                                          drives: list[TuneDrive]) -> None:
    """A real LocalCluster of 2 worker processes on 127.0.0.1."""
    def run_on(pool: Executor) -> dict[str, object]:
        run = TuneRun.start("ga", select(TUNED.split(",")), 2, 5, [d.name for d in drives],
                            {"profile": {"parameters": MISTUNED}}, population=4)
        tune(run, pool, str(sample_db), drives)
        return result_profile(run)

    local = run_on(Executor())
    with executor(2) as pool:
        assert pool.workers == 2 and "local Dask cluster of 2" in pool.where
        assert pool.distributed
        cpu = pool.cpu_seconds()
        distributed = run_on(pool)
        # the workers' CPU (what bench/batch_scaling.py divides by the work): 10 replays
        used = pool.cpu_seconds() - cpu
    assert distributed == local
    assert used > 0.1


def test_a_real_log_scores_against_its_known_route(sample_db: Path, drives: list[TuneDrive],
                                                   tmp_path: Path) -> None:
    graph = worker_graph(str(sample_db))
    truth = [r for r in drives[0].records if r["kind"] == "truth"]
    gpx = tmp_path / "route.gpx"
    gpx.write_text("<gpx><trk><trkseg>" + "".join(
        f'<trkpt lat="{r["lat"]}" lon="{r["lon"]}"/>' for r in truth) + "</trkseg></trk></gpx>")
    from navsvc.tuning.inputs import read_route
    route = read_route(graph, gpx)
    log = TuneDrive("log", tuple(r for r in drives[0].records if r["kind"] != "truth"), route)
    good = replay(graph, log, {}, {})
    assert good.on_route_share is not None and good.on_route_share > 0.9
    assert good.route_rms_m is not None and good.route_rms_m < 10.0
    far = TuneDrive("log", log.records, shapely.affinity.translate(route, 200.0, 0.0))
    assert replay(graph, far, {}, {}).score < good.score - 0.3


def test_bad_input_is_refused_naming_the_file(sample_db: Path, drive_files: list[Path],
                                              tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    no_truth = tmp_path / "log.jsonl"
    no_truth.write_text("".join(line + "\n" for line in drive_files[0].read_text().splitlines()
                                if '"truth"' not in line))
    out = tmp_path / "p.json"
    cases = [
        (tune_args(sample_db, [no_truth], out), f"{no_truth}: the drive has no truth records; "
         "give its route with --route (a GPX, or the OSM way ids driven)"),
        (tune_args(sample_db, drive_files, out, "--route", "-"),
         "--route is given 1 times for 2 drives: give one per drive, '-' for a drive with "
         "truth records"),
        (tune_args(sample_db, [no_truth], out, "--route", str(tmp_path / "ways.txt")),
         f"{tmp_path / 'ways.txt'}: cannot read the route (No such file or directory)"),
        (["tune", "--map", str(sample_db), "--drives", str(drive_files[0]), "-o", str(out),
          "--params", "fusion.nope"], "unknown parameter(s) fusion.nope; known: "),
    ]
    for args, message in cases:
        assert main(args) == 1
        assert f"navsvc: error: {message}" in capsys.readouterr().err
    ways = tmp_path / "ways.txt"
    ways.write_text("123, 456\nabc\n")
    assert main(tune_args(sample_db, [no_truth], out, "--route", str(ways))) == 1
    assert f"{ways}:2: 'abc' is not an OSM way id" in capsys.readouterr().err
    assert main(["tune", "--drives", str(drive_files[0])]) == 2
    assert "tune needs --map, -o" in capsys.readouterr().err


def test_list_params(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["tune", "--list-params"]) == 0
    table = capsys.readouterr().out
    assert "fusion.rules.position_weight_per_s" in table and "gps fuzzy" in table
