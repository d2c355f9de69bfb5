"""The fitness of one replayed drive: a weighted score in [0, 1], higher is better.

Seed: Mayhew 1999, section 5.6 (fitness: how far the fused output lies from the roads
actually driven). Two kinds of drive:

* with truth records (the simulator's): :func:`truth_score`, the weighted mean of
  - the share of epochs matched to the right road (weight 0.4),
  - the share of intersections traversed correctly (0.3; on a drive that passes none, its
    weight goes to the right-road share),
  - the fused error relative to raw GPS, as ``max(0, 1 - ratio / 2)`` (0.3): 1 at no error,
    0.5 as good as raw GPS, 0 at twice its RMS;
  (:func:`navsvc.sim.evaluate.evaluate` measures the three.)
* a real log without truth, with the route known (``navsvc tune --route``): :func:`route_score`,
  the mean of the share of output positions within :data:`ON_ROUTE_M` of the route and
  ``1 / (1 + d / ROUTE_SCALE_M)``, ``d`` the RMS distance of the fused track from the route.

A drive whose configuration is refused, or whose replay produces no position, scores 0 (the
worst). The fitness of a parameter set is the mean score over the drives. Pure.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
import shapely

from navsvc.sim.evaluate import Evaluation

WEIGHT_ROAD = 0.4
WEIGHT_INTERSECTIONS = 0.3
WEIGHT_ERROR = 0.3
ON_ROUTE_M = 10.0  # an output position this close to the known route is on it
ROUTE_SCALE_M = 10.0  # the RMS distance from the route at which its term is 0.5

Array = npt.NDArray[np.float64]


@dataclass(frozen=True)
class DriveScore:
    """One drive's score and what went into it (None where it does not apply)."""

    score: float
    right_road_share: float | None = None
    intersections_share: float | None = None
    fused_to_raw_ratio: float | None = None
    on_route_share: float | None = None
    route_rms_m: float | None = None
    error: str | None = None  # why the drive scored 0

    def to_json(self) -> dict[str, Any]:
        return {k: (round(v, 5) if isinstance(v, float) else v)
                for k, v in asdict(self).items() if v is not None}


def truth_score(e: Evaluation) -> DriveScore:
    """The weighted score of an evaluation against truth."""
    road = e.on_right_road_share or 0.0
    ratio = e.fused_to_raw_ratio
    error_term = max(0.0, 1.0 - ratio / 2.0) if np.isfinite(ratio) else 0.0
    crossings: float | None = None
    if e.intersections_total:
        crossings = share = e.intersections_correct / e.intersections_total
        score = WEIGHT_ROAD * road + WEIGHT_INTERSECTIONS * share + WEIGHT_ERROR * error_term
    else:
        score = (WEIGHT_ROAD + WEIGHT_INTERSECTIONS) * road + WEIGHT_ERROR * error_term
    return DriveScore(score, road, crossings, ratio if np.isfinite(ratio) else None)


def route_score(route: shapely.Geometry, output_xy: Array, fused_xy: Array) -> DriveScore:
    """The score of a run against its known route (all in the map's metres)."""
    if len(output_xy) == 0:
        return DriveScore(0.0, error="the replay produced no position")
    on_route = float(np.mean(shapely.distance(shapely.points(output_xy), route) <= ON_ROUTE_M))
    fused = shapely.distance(shapely.points(fused_xy), route)
    rms = float(np.sqrt(np.mean(fused ** 2)))
    score = 0.5 * on_route + 0.5 / (1.0 + rms / ROUTE_SCALE_M)
    return DriveScore(score, on_route_share=on_route, route_rms_m=rms)


def failed(reason: str) -> DriveScore:
    return DriveScore(0.0, error=reason)


def mean_fitness(scores: list[DriveScore]) -> float:
    return float(np.mean([s.score for s in scores])) if scores else 0.0
