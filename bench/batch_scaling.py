"""Batch work on Dask distributed: tuning evaluations and traces per second with 1 and 2
workers, and the same work in one process without Dask (the overhead).

* evaluations: ``--sets`` parameter sets (the defaults and random points of the default
  table, seeded) each replayed on ``--drives`` harsh-urban drives of bench/generalisation_eval.py
  (TUNE seeds, Monaco), through ``navsvc.tuning.run.evaluate_sets``;
* traces: ``--traces`` GPS traces (simulated drives on Monaco, 1 Hz, JSON Lines files)
  matched and written by ``navsvc.batch.match_file``, as ``navsvc match`` does.

Each configuration warms up first (the workers open the map and load the compiled kernels),
then the work is timed ``--repeats`` times; medians. Cluster start-up is timed apart. The
target of issue 19 is 1.7x with 2 workers; this machine has 2 cores shared with other work,
so the load at the time is printed with the figures.

    python bench/batch_scaling.py [--sets 4] [--drives 4] [--traces 40] [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from generalisation_eval import TUNE_SEEDS, _map_db, harsh_drive
from report import print_table, write_json

from navsvc.batch import (
    Executor,
    chunks,
    executor,
    match_file,
    match_files,
    open_map,
    worker_graph,
)
from navsvc.matching.hmm import HmmConfig
from navsvc.sim.simulate import DriveSpec, simulate_drive
from navsvc.tuning.params import decode, select
from navsvc.tuning.replay import TuneDrive
from navsvc.tuning.run import evaluate_sets
from navsvc.wire.jsonl import write_records


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sets", type=int, default=4, help="parameter sets")
    parser.add_argument("--drives", type=int, default=4, help="drives per set")
    parser.add_argument("--duration", type=float, default=120.0, help="seconds per drive")
    parser.add_argument("--traces", type=int, default=40, help="traces to match")
    parser.add_argument("--repeats", type=int, default=3)
    return parser


def _evaluations(pool: Executor, db: str, drives: list[TuneDrive],
                 sets: list[dict[str, Any]]) -> float:
    handles = [pool.share(d) for d in drives]
    evaluate_sets(pool, db, handles, {}, sets[:1])  # warm-up
    started = time.perf_counter()
    evaluate_sets(pool, db, handles, {}, sets)
    return time.perf_counter() - started


def _traces(pool: Executor, db: str, jobs: list[tuple[str, str]]) -> float:
    """As ``navsvc match`` sends them: in chunks on Dask, one by one in process."""
    parts = chunks(jobs, pool.workers if pool.where != "in process" else 1)
    list(pool.run(match_file, [(db, *jobs[0], HmmConfig())]))  # warm-up
    started = time.perf_counter()
    list(pool.run(match_files, [(db, part, HmmConfig()) for part in parts]))
    return time.perf_counter() - started


def main() -> None:
    args = _parser().parse_args()
    db = str(_map_db("monaco"))
    graph = worker_graph(db)
    drives = [TuneDrive(f"tune:{s}", tuple(harsh_drive(graph, s, args.duration)[0]))
              for s in TUNE_SEEDS[:args.drives]]
    params = select()
    rng = np.random.default_rng(0)
    sets = [{}] + [decode(params, rng.random(len(params)).tolist())
                   for _ in range(args.sets - 1)]
    folder = Path(tempfile.mkdtemp(prefix="batch_scaling_"))
    tasks: list[tuple[str, str]] = []
    for i in range(args.traces):
        trace = folder / f"trace{i}.jsonl"
        write_records(trace, [r for r in simulate_drive(graph, DriveSpec(
            duration_s=300.0, seed=1000 + i, sensors=("gps",), tunnels_block_gps=False))
            if r["kind"] == "gps"])
        tasks.append((str(trace), str(folder / f"trace{i}.route.json")))
    modes = (("one process, no Dask", 0), ("Dask, 1 worker", 1), ("Dask, 2 workers", 2))
    pools, startup = [], []
    for _, workers in modes:  # all three up at once; idle ones cost nothing
        started = time.perf_counter()
        pools.append(executor(workers))
        startup.append(time.perf_counter() - started)
        pools[-1].warm_up(open_map, db)
    # Interleaved: each round times every mode in turn, so that a slow spell of this shared
    # machine falls on all of them alike; medians over the rounds.
    evals: list[list[float]] = [[] for _ in modes]
    matched: list[list[float]] = [[] for _ in modes]
    try:
        for _ in range(args.repeats):
            for k, pool in enumerate(pools):
                evals[k].append(_evaluations(pool, db, drives, sets))
                matched[k].append(_traces(pool, db, tasks))
    finally:
        for pool in pools:
            pool.close()
    rows: list[dict[str, Any]] = []
    for k, (label, workers) in enumerate(modes):
        rows.append({"mode": label, "workers": max(workers, 1), "startup_s": startup[k],
                     "evaluations_per_s": len(sets) / statistics.median(evals[k]),
                     "replays_per_s": len(sets) * len(drives) / statistics.median(evals[k]),
                     "traces_per_s": len(tasks) / statistics.median(matched[k]),
                     "evaluation_seconds": evals[k], "trace_seconds": matched[k],
                     "load_avg_1min": os.getloadavg()[0]})
    one = next(r for r in rows if r["mode"] == "Dask, 1 worker")
    table = [[r["mode"], r["startup_s"], r["evaluations_per_s"], r["replays_per_s"],
              r["evaluations_per_s"] / one["evaluations_per_s"], r["traces_per_s"],
              r["traces_per_s"] / one["traces_per_s"], r["load_avg_1min"]] for r in rows]
    print_table(f"{args.sets} parameter sets x {args.drives} drives of {args.duration:.0f} s; "
                f"{args.traces} traces of 300 s (1 Hz); medians of {args.repeats}; "
                f"{os.cpu_count()} cores",
                ["mode", "start-up s", "evaluations/s", "replays/s", "vs 1 worker",
                 "traces/s", "vs 1 worker", "load (1 min)"], table)
    write_json("batch_scaling", {"sets": args.sets, "drives": args.drives,
                                 "duration_s": args.duration, "traces": args.traces,
                                 "repeats": args.repeats, "rows": rows})


if __name__ == "__main__":
    main()
