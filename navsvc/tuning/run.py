"""A tuning run: a search (:mod:`navsvc.tuning.search`) driven by replays of drives.

Each parameter set the search proposes is evaluated on every drive (one task per drive, so an
executor spreads them over workers; see :mod:`navsvc.batch`), and its fitness is the mean drive
score. Evaluations are cached by their parameter values: the GA's elites, and any point
proposed again, cost nothing. The budget counts parameter sets evaluated (each one replay per
drive), all of it spent: the defaults are the first (so the profile can say what tuning
gained), and a last GA generation larger than what is left is evaluated in part. The result
is the best parameter set evaluated.

The whole run (search state, random generator, cache) is :class:`TuneRun`, saved after each
step and loaded by ``--resume``: a resumed run ends where an uninterrupted one would.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from navsvc.batch import Executor, worker_graph
from navsvc.errors import ConfigError
from navsvc.session import SessionConfig, config_from_options
from navsvc.tuning.fitness import DriveScore, mean_fitness
from navsvc.tuning.params import BY_NAME, Parameter, Value, decode
from navsvc.tuning.profile import changed, current_value, defaults, profile_document
from navsvc.tuning.replay import TuneDrive, replay
from navsvc.tuning.search import Search, search_from_json, search_to_json, start_search

STATE_FORMAT = "navsvc-tune-state/2"  # 2: the GA of Gray codes and tournaments


def score_task(map_path: str, drive: TuneDrive, options: dict[str, Any],
               parameters: dict[str, Value]) -> DriveScore:
    """One replay (a worker's task; the map is opened once per worker)."""
    return replay(worker_graph(drive.map_path or map_path), drive, options, parameters)


def _key(values: dict[str, Value]) -> str:
    return json.dumps(values, sort_keys=True)


@dataclass
class TuneRun:
    """Everything a tuning run needs to continue."""

    method: str
    params: tuple[Parameter, ...]
    seed: int
    budget: int
    drives: tuple[str, ...]
    options: dict[str, Any]
    search: Search
    population: int = 10
    cache: dict[str, dict[str, Any]] = field(default_factory=dict)  # key → fitness, scores
    evaluations: int = 0

    @classmethod
    def start(cls, method: str, params: Sequence[Parameter], seed: int, budget: int,
              drives: Sequence[str], options: dict[str, Any], population: int = 10
              ) -> TuneRun:
        if budget < 2:
            raise ConfigError(f"--budget must be at least 2 evaluations, got {budget}")
        base = config_from_options(options)
        u0 = [p.unit(v) for p, v in zip(params, defaults(params, base).values())]
        search = start_search(method, params, u0, seed, population)
        return cls(method, tuple(params), seed, budget, tuple(drives), dict(options), search,
                   population)

    @property
    def default_values(self) -> dict[str, Value]:
        """The start: the defaults, or the profile the options start from."""
        return defaults(self.params, config_from_options(self.options))

    def fitness_of(self, values: dict[str, Value]) -> float | None:
        found = self.cache.get(_key(values))
        return None if found is None else float(found["fitness"])

    def best(self) -> tuple[dict[str, Value], float]:
        """The best parameter values evaluated (the defaults when nothing beat them; of
        equals, the first evaluated)."""
        base = self.default_values
        base_f = self.fitness_of(base)
        key, f = None, None
        for k, found in self.cache.items():
            if f is None or found["fitness"] > f:
                key, f = k, float(found["fitness"])
        if key is None or f is None or (base_f is not None and base_f >= f):
            return base, base_f if base_f is not None else float("nan")
        values = json.loads(key)
        return {p.name: values[p.name] for p in self.params}, f

    def to_json(self) -> dict[str, Any]:
        return {"format": STATE_FORMAT, "method": self.method,
                "params": [p.name for p in self.params], "seed": self.seed,
                "budget": self.budget, "drives": list(self.drives), "options": self.options,
                "population": self.population, "evaluations": self.evaluations,
                "search": search_to_json(self.search), "cache": self.cache}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> TuneRun:
        found = d.get("format")
        if isinstance(found, str) and found.startswith("navsvc-tune-state/") and \
                found != STATE_FORMAT:
            raise ConfigError(f"a tuning state of another navsvc version ({found}; this one "
                              f"reads {STATE_FORMAT}): start the run again")
        if found != STATE_FORMAT:
            raise ConfigError("not a tuning state (from `navsvc tune`)")
        params = tuple(BY_NAME[n] for n in d["params"])
        return cls(d["method"], params, d["seed"], d["budget"], tuple(d["drives"]),
                   d["options"], search_from_json(params, d["search"]), d["population"],
                   d["cache"], d["evaluations"])

    def check_same(self, other: TuneRun) -> None:
        """Refuse to resume a state with a different run (budget may change)."""
        for name in ("method", "params", "seed", "drives", "options", "population"):
            if getattr(self, name) != getattr(other, name):
                raise ConfigError(f"the state is of another run: its {name} is "
                                  f"{getattr(self, name)!r}, this command's "
                                  f"{getattr(other, name)!r}")


Progress = Callable[[int, float | None], None]  # (replays done, best fitness so far)


def evaluate_sets(executor: Executor, map_path: str, drives: Sequence[Any],
                  options: dict[str, Any], sets: Sequence[dict[str, Value]],
                  progress: Progress | None = None, best: float | None = None
                  ) -> list[list[DriveScore]]:
    """Each parameter set's score on each drive (``drives``: values or shared handles)."""
    tasks = [(map_path, d, options, s) for s in sets for d in drives]
    scores: list[list[DriveScore | None]] = [[None] * len(drives) for _ in sets]
    for i, score in executor.run(score_task, tasks):
        scores[i // len(drives)][i % len(drives)] = score
        if progress is not None:
            progress(1, best)
    return [[s for s in row if s is not None] for row in scores]


def tune(run: TuneRun, executor: Executor, map_path: str, drives: Sequence[TuneDrive],
         save: Callable[[TuneRun], None] | None = None, progress: Progress | None = None
         ) -> TuneRun:
    """Run the search until its budget is spent (or it converges); ``save`` after each step."""
    handles = [executor.share(d) for d in drives]

    def spend(sets: list[dict[str, Value]]) -> None:
        new = list({_key(s): s for s in sets if _key(s) not in run.cache}.values())
        best = run.best()[1] if run.cache else None
        for s, row in zip(new, evaluate_sets(executor, map_path, handles, run.options, new,
                                             progress, best)):
            run.cache[_key(s)] = {"fitness": mean_fitness(row),
                                  "scores": [r.to_json() for r in row]}
        run.evaluations += len(new)

    if run.fitness_of(run.default_values) is None:
        spend([run.default_values])
        if save:
            save(run)
    for _ in range(50 * run.budget):  # a converged GA may propose only cached points a while
        if run.evaluations >= run.budget or run.search.done:
            break
        points = run.search.propose()
        if not points:
            break
        sets = [decode(run.params, u) for u in points]
        new = [s for k, s in {_key(s): s for s in sets}.items() if k not in run.cache]
        left = run.budget - run.evaluations
        if len(new) > left:
            # The last generation does not fit: its first ``left`` new points are evaluated
            # (each may be the best found) and the search is not told. A run resumed with a
            # larger budget proposes the same generation, finds these in the cache, and ends
            # where an uninterrupted run would.
            spend(new[:left])
            if save:
                save(run)
            break
        spend(sets)
        fitnesses = [run.fitness_of(s) for s in sets]
        run.search.tell([f if f is not None else 0.0 for f in fitnesses])
        if save:
            save(run)
    return run


def result_profile(run: TuneRun) -> dict[str, Any]:
    """The profile document of a finished run."""
    base = run.default_values
    values, fitness = run.best()
    before = run.cache[_key(base)]
    after = run.cache.get(_key(values), before)
    tuned = {"method": run.method, "seed": run.seed, "budget": run.budget,
             "evaluations": run.evaluations, "replays": run.evaluations * len(run.drives),
             "options": run.options, "parameters_searched": [p.name for p in run.params],
             "fitness_before": round(before["fitness"], 5),
             "fitness_after": round(fitness, 5), "drives": list(run.drives),
             "scores_before": before["scores"], "scores_after": after["scores"],
             "values": values}
    start = dict(run.options.get("profile", {}).get("parameters", {})) \
        if isinstance(run.options.get("profile"), dict) else {}
    merged = {**start, **values}
    true_defaults = {**defaults(run.params), **{k: current_value(SessionConfig(), k)
                                               for k in start if k not in values}}
    return profile_document(changed(merged, true_defaults), tuned)


def save_json(path: Path, doc: dict[str, Any]) -> None:
    """Write JSON via a temporary file (an interrupted write leaves the old file)."""
    tmp = path.with_name(path.name + ".tmp")
    try:
        tmp.write_text(json.dumps(doc, indent=1), encoding="utf-8")
        tmp.replace(path)
    except OSError as exc:
        raise ConfigError(f"{path}: cannot write ({exc.strerror})") from None
