"""Hill climbing and the GA on closed-form fitnesses: they find the optimum, follow the
thesis's rules step by step, are reproducible from a seed, and resume exactly."""

from __future__ import annotations

import json
from collections.abc import Callable

from navsvc.tuning.params import Parameter
from navsvc.tuning.search import (
    Genetic,
    HillClimb,
    Search,
    search_from_json,
    search_to_json,
    start_search,
)

PARAMS = tuple(Parameter(f"p{i}", "test", 0.0, 1.0, bits=8) for i in range(3))
TARGET = (0.2, 0.7, 0.45)


def bowl(u: list[float]) -> float:
    return -sum((a - b) ** 2 for a, b in zip(u, TARGET))


def drive(search: Search, f: Callable[[list[float]], float], budget: int) -> list[list[float]]:
    """Run a search for ``budget`` evaluations; every point it evaluated, in order."""
    seen: list[list[float]] = []
    while len(seen) < budget and not search.done:
        points = search.propose()
        if not points:
            break
        seen += points
        search.tell([f(u) for u in points])
    return seen


def test_hill_climbing_halves_and_reverses_a_step_that_makes_things_worse() -> None:
    search = HillClimb.start([0.5], initial_step=0.25)
    seen = drive(search, lambda u: -abs(u[0] - 0.3), 6)
    # start 0.5; 0.75 worse → step -0.125: 0.375 better, kept; the same step again: 0.25
    # better; 0.125 worse → +0.0625 from 0.25: 0.3125 better
    assert [round(u[0], 5) for u in seen] == [0.5, 0.75, 0.375, 0.25, 0.125, 0.3125]
    assert search.u == [0.3125] and search.steps == [0.0625]


def test_hill_climbing_finds_the_optimum_and_stops() -> None:
    search = HillClimb.start([0.5, 0.5, 0.5])
    drive(search, bowl, 500)
    assert search.done
    u, f = search.best
    assert max(abs(a - b) for a, b in zip(u, TARGET)) < 0.01 and f is not None and f > -3e-4


def test_the_ga_improves_on_its_start_and_never_loses_its_best() -> None:
    search = Genetic.start(PARAMS, [0.9, 0.1, 0.9], seed=5, size=12)
    drive(search, bowl, 12 * 25)
    assert search.history == sorted(search.history)  # elitism: the best never gets worse
    _, f = search.best
    assert f is not None and f > -0.01 and search.history[0] < f


def test_the_ga_is_reproducible_from_its_seed() -> None:
    runs = [drive(Genetic.start(PARAMS, [0.5] * 3, seed=9, size=6), bowl, 30) for _ in range(2)]
    assert runs[0] == runs[1]
    assert drive(Genetic.start(PARAMS, [0.5] * 3, seed=10, size=6), bowl, 30) != runs[0]


def test_a_resumed_search_continues_exactly() -> None:
    for method in ("hill", "ga"):
        whole = drive(start_search(method, PARAMS, [0.5] * 3, seed=2, population=6), bowl, 36)
        first = start_search(method, PARAMS, [0.5] * 3, seed=2, population=6)
        part = drive(first, bowl, 18)
        resumed = search_from_json(PARAMS, json.loads(json.dumps(search_to_json(first))))
        assert part + drive(resumed, bowl, 36 - len(part)) == whole, method


def test_the_ga_starts_around_its_start_point_and_fits_a_tiny_genotype_space() -> None:
    search = Genetic.start(PARAMS, [0.5] * 3, seed=1, size=12)
    units = search.propose()
    assert units[0] == [round(0.5 * 255) / 255] * 3
    near = [u for u in units[1:] if max(abs(x - 0.5) for x in u) < 0.5]
    assert len(near) >= 8  # 8 mutants of the start (steps of 0.15), 3 drawn at random
    assert len({tuple(u) for u in units}) == 12
    one_bit = (Parameter("b", "test", 0.0, 1.0, bits=1),)
    assert len(Genetic.start(one_bit, [0.0], seed=1, size=6).population) == 6
