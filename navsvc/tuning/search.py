"""The two searches of the seed thesis (Mayhew 1999, section 5.6), as ask/tell state machines.

Both maximise a fitness over the unit cube of :mod:`navsvc.tuning.params` and know nothing of
drives or roads: :meth:`propose` returns the points to evaluate next, :meth:`tell` takes their
fitnesses. Their whole state (the random generator's included) goes to JSON and back, so an
interrupted run continues exactly where it stopped (``navsvc tune --resume``), and a seed
makes a run reproducible.

* :class:`HillClimb`: iterative hill climbing by coordinate steps. From the start point, step
  one parameter; a step that improves the fitness is kept and tried again; a step that makes
  it worse (or no better) is undone, halved and reversed, and the next parameter is tried.
  The search ends when every step is below ``min_step``.
* :class:`Genetic`: a genetic algorithm over bit-string genotypes (Gray-coded, so that one
  flipped bit moves a parameter to a neighbouring value as often as to a far one):
  reproduction by tournament (the fittest of three drawn at random; it needs no scaling of
  fitnesses that differ by 1 %), single-point crossover, bit-flip mutation, and the best
  individuals carried over unchanged (elitism, so the best never gets worse). The first
  population is the start point, mutants of it (each coordinate moved by a normal step of
  ``start_spread``) and a share drawn at random. A child that repeats a genotype already
  evaluated is mutated again (up to a few times), so that each generation spends its
  evaluations on new points; the elites, evaluated already, cost nothing.

  The settings were chosen on the TUNE split only (bench/tune_eval.py's 6 tune drives, scored
  on 8 other TUNE seeds of the same two maps; default parameters 0.855 there): tournaments of
  two reached 0.788 on the tune drives and 0.868 on the others at a budget of 33, three 0.796
  and 0.869 (hill climbing 0.797 and 0.886); at 65, two 0.794 and 0.839, three 0.796 and 0.869.

Pure: no I/O, no clock.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from navsvc.errors import ConfigError
from navsvc.tuning.params import (
    Parameter,
    genotype_length,
    genotype_to_unit,
    unit_to_genotype,
)

METHODS = ("hill", "ga")


@dataclass
class HillClimb:
    """Coordinate hill climbing: halve and reverse a step that does not improve."""

    u: list[float]  # the current point
    steps: list[float]  # signed step per coordinate (unit-cube units)
    min_step: float = 1.0 / 256.0
    fitness: float | None = None  # of ``u``; None until the start point is evaluated
    coordinate: int = 0  # the parameter stepped next
    trial: list[float] | None = None  # proposed and not yet told

    @classmethod
    def start(cls, u0: Sequence[float], initial_step: float = 0.25) -> HillClimb:
        return cls(u=list(u0), steps=[initial_step] * len(u0))

    @property
    def done(self) -> bool:
        return self.fitness is not None and all(abs(s) < self.min_step for s in self.steps)

    @property
    def best(self) -> tuple[list[float], float | None]:
        return self.u, self.fitness

    def propose(self) -> list[list[float]]:
        if self.fitness is None:
            self.trial = list(self.u)
            return [self.trial]
        for _ in range(len(self.u)):  # skip coordinates whose step leaves the cube
            i = self.coordinate
            moved = min(max(self.u[i] + self.steps[i], 0.0), 1.0)
            if abs(self.steps[i]) >= self.min_step and moved != self.u[i]:
                self.trial = list(self.u)
                self.trial[i] = moved
                return [self.trial]
            self._worse(i)
        return []

    def tell(self, fitnesses: Sequence[float]) -> None:
        assert self.trial is not None and len(fitnesses) == 1, "tell follows one propose"
        f, trial, self.trial = fitnesses[0], self.trial, None
        if self.fitness is None:
            self.fitness = f
        elif f > self.fitness:
            self.u, self.fitness = trial, f  # better: keep it, try the same step again
        else:
            self._worse(self.coordinate)

    def _worse(self, i: int) -> None:
        self.steps[i] = -self.steps[i] / 2.0
        self.coordinate = (i + 1) % len(self.u)

    def to_json(self) -> dict[str, Any]:
        return {"u": self.u, "steps": self.steps, "min_step": self.min_step,
                "fitness": self.fitness, "coordinate": self.coordinate}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> HillClimb:
        return cls(u=list(d["u"]), steps=list(d["steps"]), min_step=d["min_step"],
                   fitness=d["fitness"], coordinate=d["coordinate"])


@dataclass
class Genetic:
    """A generational GA over bit strings (tournament reproduction, one-point crossover,
    bit-flip mutation, elites), started around the start point."""

    params: tuple[Parameter, ...]
    population: list[list[int]]
    rng: np.random.Generator
    crossover_rate: float = 0.7
    mutation_rate: float = 0.0  # per bit; 0: one over the genotype length
    elites: int = 2
    tournament: int = 3  # chosen on the TUNE split (see the module's note)
    generation: int = 0
    fitness: list[float] | None = None  # of ``population`` once told
    best_bits: list[int] | None = None
    best_fitness: float | None = None
    history: list[float] = field(default_factory=list)  # best fitness per generation
    seen: set[str] = field(default_factory=set)  # genotypes proposed so far ("0101...")

    @classmethod
    def start(cls, params: Sequence[Parameter], u0: Sequence[float], seed: int,
              size: int = 10, start_spread: float = 0.15, random_share: float = 0.25
              ) -> Genetic:
        """The start point; ``random_share`` of the others drawn at random, the rest the
        start point with each coordinate moved by a normal step of ``start_spread``."""
        if size < 2:
            raise ConfigError("a GA population needs at least 2 individuals")
        rng = np.random.default_rng(seed)
        n = genotype_length(params)
        population = [unit_to_genotype(params, u0)]
        randoms = round(random_share * (size - 1))
        tries = 0  # a small genotype space (a few booleans) may hold fewer than ``size``
        while len(population) < size:
            if len(population) < size - randoms:
                u = np.clip(np.asarray(u0) + rng.normal(0.0, start_spread, len(u0)), 0.0, 1.0)
                bits = unit_to_genotype(params, u.tolist())
            else:
                bits = [int(b) for b in rng.integers(0, 2, n)]
            tries += 1
            if bits not in population or tries > 100 * size:
                population.append(bits)
        return cls(tuple(params), population, rng, elites=min(2, size - 1),
                   seen={_bits(g) for g in population})

    @property
    def done(self) -> bool:
        return False  # a GA runs until its budget is spent

    @property
    def best(self) -> tuple[list[float], float | None]:
        if self.best_bits is None:
            return genotype_to_unit(self.params, self.population[0]), None
        return genotype_to_unit(self.params, self.best_bits), self.best_fitness

    def propose(self) -> list[list[float]]:
        if self.fitness is not None:
            self._breed()
        return [genotype_to_unit(self.params, g) for g in self.population]

    def tell(self, fitnesses: Sequence[float]) -> None:
        assert len(fitnesses) == len(self.population), "one fitness per individual"
        self.fitness = [float(f) for f in fitnesses]
        k = int(np.argmax(self.fitness))
        if self.best_fitness is None or self.fitness[k] > self.best_fitness:
            self.best_bits, self.best_fitness = list(self.population[k]), self.fitness[k]
        self.history.append(float(self.best_fitness))

    def _breed(self) -> None:
        assert self.fitness is not None
        order = np.argsort(self.fitness, kind="stable")[::-1]
        children = [list(self.population[i]) for i in order[:self.elites]]
        while len(children) < len(self.population):
            a, b = self._crossover(self._select(), self._select())
            for child in (a, b):
                child = self._mutate(child)
                for _ in range(MAX_REMUTATIONS):  # a repeat would cost a slot, not a replay
                    if _bits(child) not in self.seen:
                        break
                    child = self._mutate(child, at_least_one=True)
                children.append(child)
                self.seen.add(_bits(child))
        self.population = children[:len(self.population)]
        self.fitness = None
        self.generation += 1

    def _select(self) -> list[int]:
        """Reproduction: the fittest of ``tournament`` individuals drawn at random (a
        refused configuration's NaN or -inf loses to any finite fitness)."""
        assert self.fitness is not None
        f = [x if math.isfinite(x) else -math.inf for x in self.fitness]
        drawn = self.rng.choice(len(f), size=min(self.tournament, len(f)), replace=False)
        return list(self.population[int(max(drawn, key=lambda i: f[int(i)]))])

    def _crossover(self, a: list[int], b: list[int]) -> tuple[list[int], list[int]]:
        if len(a) < 2 or self.rng.random() >= self.crossover_rate:
            return a, b
        cut = int(self.rng.integers(1, len(a)))
        return a[:cut] + b[cut:], b[:cut] + a[cut:]

    def _mutate(self, bits: list[int], at_least_one: bool = False) -> list[int]:
        rate = self.mutation_rate or 1.0 / len(bits)
        flips = self.rng.random(len(bits)) < rate
        if at_least_one and not flips.any():
            flips[int(self.rng.integers(len(bits)))] = True
        return [b ^ int(f) for b, f in zip(bits, flips)]

    def to_json(self) -> dict[str, Any]:
        return {"population": self.population, "rng": self.rng.bit_generator.state,
                "crossover_rate": self.crossover_rate, "mutation_rate": self.mutation_rate,
                "elites": self.elites, "tournament": self.tournament,
                "generation": self.generation, "fitness": self.fitness,
                "best_bits": self.best_bits, "best_fitness": self.best_fitness,
                "history": self.history, "seen": sorted(self.seen)}

    @classmethod
    def from_json(cls, params: Sequence[Parameter], d: dict[str, Any]) -> Genetic:
        rng = np.random.default_rng()
        rng.bit_generator.state = d["rng"]
        return cls(tuple(params), [list(g) for g in d["population"]], rng,
                   crossover_rate=d["crossover_rate"], mutation_rate=d["mutation_rate"],
                   elites=d["elites"], tournament=d["tournament"],
                   generation=d["generation"], fitness=d["fitness"],
                   best_bits=d["best_bits"], best_fitness=d["best_fitness"],
                   history=list(d["history"]), seen=set(d["seen"]))


MAX_REMUTATIONS = 8


def _bits(genotype: Sequence[int]) -> str:
    return "".join(str(b) for b in genotype)


Search = HillClimb | Genetic


def start_search(method: str, params: Sequence[Parameter], u0: Sequence[float], seed: int,
                 population: int = 10) -> Search:
    """A new search of ``method`` ("hill" or "ga") from the unit point ``u0``."""
    if method == "hill":
        return HillClimb.start(u0)
    if method == "ga":
        return Genetic.start(params, u0, seed, population)
    raise ConfigError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")


def search_to_json(search: Search) -> dict[str, Any]:
    return {"method": "hill" if isinstance(search, HillClimb) else "ga", **search.to_json()}


def search_from_json(params: Sequence[Parameter], d: dict[str, Any]) -> Search:
    if d["method"] == "hill":
        return HillClimb.from_json(d)
    return Genetic.from_json(params, d)
