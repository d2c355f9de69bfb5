"""Tuning, reported honestly: tune on some drives, report on others (other seeds, other maps).

Both methods of ``navsvc tune`` (hill climbing and the GA, seed thesis 5.6) tune the default
parameter set (``navsvc.tuning.params.DEFAULT_SET``) on TUNE drives: the harsh-urban drives of
bench/generalisation_eval.py (its ``harsh_drive``: error levels drawn per seed, a 60 s outage
mid-drive, UrbanNav's real GNSS error on every third seed) with seeds from its TUNE split, on
``--tune-maps``. Each profile is then scored, beside the defaults, on REPORT drives: seeds from
the REPORT split on ``--report-maps`` (by default including two maps tuning never saw). The
table gives the fitness (``navsvc.tuning.fitness``) and its parts, medians over the drives.

The budget is in parameter sets (each one replay per tune drive); the total replays are
printed. Runs on a local Dask cluster of ``--workers`` processes (0: in this process).

    python bench/tune_eval.py [--budget 33] [--tune-drives 6] [--report-drives 10]
        [--duration 180] [--workers 2] [--seed 1]
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any

from generalisation_eval import REPORT_SEEDS, TUNE_SEEDS, _map_db, harsh_drive
from report import print_table, write_json
from tqdm import tqdm

from navsvc.batch import executor, worker_graph
from navsvc.tuning.fitness import DriveScore, mean_fitness
from navsvc.tuning.params import select
from navsvc.tuning.replay import TuneDrive
from navsvc.tuning.run import TuneRun, evaluate_sets, result_profile, tune


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--budget", type=int, default=33,
                        help="parameter sets per method (33: the defaults and 32 more; a GA "
                        "of 8 with 2 elites: 5 generations and a part)")
    parser.add_argument("--population", type=int, default=8, help="GA population")
    parser.add_argument("--tune-drives", type=int, default=6)
    parser.add_argument("--report-drives", type=int, default=10)
    parser.add_argument("--duration", type=float, default=180.0, help="seconds per drive")
    parser.add_argument("--tune-maps", default="monaco,andorra")
    parser.add_argument("--report-maps", default="monaco,andorra,gh-issue-70,stockholm")
    parser.add_argument("--workers", type=int, default=2, help="Dask processes (0: none)")
    parser.add_argument("--seed", type=int, default=1, help="the GA's seed")
    return parser


def _drives(maps: list[str], seeds: tuple[int, ...], count: int, duration: float,
            split: str, skipped: list[str]) -> list[TuneDrive]:
    """``count`` drives, maps in turn, each with the next seed of the split. A drive without
    a single GPS fix (UrbanNav's gaps, the outage and tunnels can cover a short drive) scores
    0 whatever the parameters: it is left out, named in ``skipped``, and the next seed taken."""
    out: list[TuneDrive] = []
    seed = iter(seeds)
    while len(out) < count:
        name = maps[len(out) % len(maps)]
        db, s = str(_map_db(name)), next(seed)
        records, _, _ = harsh_drive(worker_graph(db), s, duration)
        if not any(r["kind"] == "gps" for r in records):
            skipped.append(f"{split}:{name}:{s}")
            continue
        out.append(TuneDrive(f"{split}:{name}:{s}", tuple(records), map_path=db))
    return out


def _parts(rows: list[DriveScore]) -> list[float]:
    def med(values: list[float | None]) -> float:
        found = [v for v in values if v is not None]
        return statistics.median(found) if found else float("nan")
    return [mean_fitness(rows), 100.0 * med([r.right_road_share for r in rows]),
            100.0 * med([r.intersections_share for r in rows]),
            med([r.fused_to_raw_ratio for r in rows])]


def main() -> None:
    args = _parser().parse_args()
    tune_maps, report_maps = args.tune_maps.split(","), args.report_maps.split(",")
    skipped: list[str] = []
    tune_drives = _drives(tune_maps, TUNE_SEEDS, args.tune_drives, args.duration, "tune",
                          skipped)
    report_drives = _drives(report_maps, REPORT_SEEDS, args.report_drives, args.duration,
                            "report", skipped)
    params = select()
    results: dict[str, Any] = {}
    started = time.perf_counter()
    with executor(args.workers) as pool:
        profiles: dict[str, dict[str, Any]] = {"default": {"parameters": {},
                                                            "tuned": {"evaluations": 0}}}
        for method in ("hill", "ga"):
            run = TuneRun.start(method, params, args.seed, args.budget,
                                [d.name for d in tune_drives], {}, args.population)
            with tqdm(total=args.budget * len(tune_drives), desc=method, unit="replay") as bar:
                tune(run, pool, "", tune_drives, progress=lambda n, best: bar.update(n))
            profiles[method] = result_profile(run)
        handles = [pool.share(d) for d in report_drives]
        scored = evaluate_sets(pool, "", handles, {},
                               [p["parameters"] for p in profiles.values()])
        where = pool.where
    wall_s = time.perf_counter() - started
    table = []
    for (name, profile), rows in zip(profiles.items(), scored):
        tuned = profile["tuned"]
        before, after = tuned.get("fitness_before"), tuned.get("fitness_after")
        table.append([name, tuned["evaluations"], before if before is not None else "",
                      after if after is not None else "", *_parts(rows)])
        results[name] = {"profile": profile, "report": [r.to_json() for r in rows]}
    replays = sum(p["tuned"].get("replays", 0) for p in profiles.values()) + \
        len(report_drives) * len(profiles)
    print_table(f"Tuned on {len(tune_drives)} drives ({', '.join(tune_maps)}; TUNE seeds), "
                f"reported on {len(report_drives)} others ({', '.join(report_maps)}; REPORT "
                f"seeds), harsh-urban, {args.duration:.0f} s each",
                ["profile", "evaluations", "fitness on tune drives (default)",
                 "(tuned)", "fitness on report drives", "right road % (median)",
                 "intersections % (median)", "fused/raw RMS (median)"], table)
    for name in ("hill", "ga"):
        print(f"{name}: {results[name]['profile']['parameters']}")
    print(f"drives without a GPS fix, left out: {', '.join(skipped) or 'none'}")
    print(f"\n{replays} replays in {wall_s:.0f} s ({where})")
    write_json("tune_eval", {"budget": args.budget, "population": args.population,
                             "seed": args.seed, "duration_s": args.duration,
                             "tune_drives": [d.name for d in tune_drives],
                             "report_drives": [d.name for d in report_drives],
                             "skipped_without_gps": skipped,
                             "replays": replays, "wall_s": round(wall_s, 1),
                             "where": where, "results": results})


if __name__ == "__main__":
    main()
