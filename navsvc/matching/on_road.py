"""Where a car is, given an estimate of its position and that it is on a road (pure).

Before start-up the fixes alone place the car, and their error across the road is as large
as along it. The car is on a road: with a prior uniform along the roads near the estimate
(per metre of road) and Gaussian across each (``road_sigma_m``: lanes, the centre line's own
error), the posterior of its position is a mixture with one part per road. Each road is
taken as straight through the estimate's projection onto it, from its start to its end;
along it the part is the estimate's Gaussian cut at the road's ends, across it the estimate
and the road's spread combined. The mixture's mean and covariance are what is reported: on
a lone road the error across it goes, at a junction the mean lies among the roads and the
covariance spans them.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from roadgraph import EdgeProjection

_SQRT_2PI = math.sqrt(2.0 * math.pi)


def on_road_posterior(x_m: float, y_m: float, var_m2: float, roads: Iterable[EdgeProjection],
                      road_sigma_m: float) -> tuple[float, float, np.ndarray] | None:
    """The mean (x, y) and 2x2 covariance of the car's position given an estimate at
    ``(x_m, y_m)`` with variance ``var_m2`` in each axis and that the car is on one of
    ``roads`` (the estimate projected onto each: :meth:`roadgraph.RoadGraph.edges_near`).
    A road stored once each way counts once. None when no road holds any of the mass."""
    sigma = math.sqrt(var_m2)
    across_var = var_m2 + road_sigma_m ** 2
    shrink = road_sigma_m ** 2 / across_var  # of the offset across, what the road leaves
    seen: set[tuple[frozenset[int], int]] = set()
    weights, means, covs = [], [], []
    for road in roads:
        key = (frozenset((road.edge.u, road.edge.v)), road.edge.key)
        if key in seen:
            continue
        seen.add(key)
        along = np.array([math.sin(road.bearing_rad), math.cos(road.bearing_rad)])
        across = np.array([along[1], -along[0]])
        offset = np.array([x_m - road.x_m, y_m - road.y_m])
        a, c = float(offset @ along), float(offset @ across)
        low, high = (-road.offset_m - a) / sigma, (road.remaining_m - a) / sigma
        mass = _normal_cdf(high) - _normal_cdf(low)
        if mass <= 1e-12:
            continue
        ratio = (_normal_pdf(low) - _normal_pdf(high)) / mass
        mean_along = a + sigma * ratio
        var_along = var_m2 * (1.0 + (low * _normal_pdf(low) - high * _normal_pdf(high)) / mass
                              - ratio ** 2)
        weights.append(mass * math.exp(-0.5 * c * c / across_var) / math.sqrt(across_var))
        means.append(np.array([road.x_m, road.y_m]) + mean_along * along + shrink * c * across)
        covs.append(var_along * np.outer(along, along)
                    + var_m2 * shrink * np.outer(across, across))
    w, parts = np.array(weights), np.array(means)
    total = float(w.sum())
    if total <= 0.0:
        return None
    mean = w @ parts / total
    spread = parts - mean
    cov = (np.einsum("i,ijk->jk", w, np.array(covs)) + (w[:, None] * spread).T @ spread) / total
    return float(mean[0]), float(mean[1]), cov


def _normal_pdf(z: float) -> float:
    return math.exp(-0.5 * z * z) / _SQRT_2PI


def _normal_cdf(z: float) -> float:
    return 0.5 * math.erfc(-z / math.sqrt(2.0))
