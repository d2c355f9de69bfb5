"""Fuzzy GPS fusion (pure). Seed: Mayhew 1999, section 5.5 and appendix D.

Inputs: Distance (estimate to GPS, m), Velocity (GPS speed, m/s), NumNoGood (consecutive fixes
rejected as too far). Outputs: GPS position and heading weights, by nine min/max rules and
centroid defuzzification. Velocity and the output sets are the thesis's; its distance sets
(squared milliarcseconds, SA-era errors of ~100 m) are rescaled to metres for modern GPS, and
NumNoGood counts fixes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

Trapezoid = tuple[float, float, float, float]
INF = math.inf


def trapezoid(value: float, t: Trapezoid) -> float:
    """Membership in a trapezoid ``(a, b, c, d)``: 0 below a, 1 on [b, c], 0 above d."""
    a, b, c, d = t
    if value < a or value > d:
        return 0.0
    if value < b:
        return (value - a) / (b - a)
    if value > c:
        return 1.0 if d == INF else (d - value) / (d - c)
    return 1.0


@dataclass(frozen=True)
class FuzzySets:
    distance_m: dict[str, Trapezoid]
    velocity_mps: dict[str, Trapezoid]
    num_no_good: dict[str, Trapezoid]
    position_weight: dict[str, Trapezoid]
    heading_weight: dict[str, Trapezoid]


THESIS_SETS = FuzzySets(
    distance_m={"SMALL": (0.0, 0.0, 10.0, 20.0), "MED": (10.0, 20.0, 40.0, 60.0),
                "LARGE": (40.0, 60.0, INF, INF)},
    velocity_mps={"SLOW": (0.0, 0.0, 2.0, 2.5), "MED": (2.0, 2.5, 3.0, 3.5),
                  "FAST": (2.5, 3.0, INF, INF)},
    num_no_good={"SMALL": (0.0, 0.0, 25.0, 35.0), "MED": (25.0, 35.0, 2500.0, 3500.0),
                 "LARGE": (2500.0, 3500.0, INF, INF)},
    position_weight={"ZERO": (0.0, 0.0, 0.001, 0.001), "SMALL": (0.0, 0.002, 0.015, 0.02),
                     "MED": (0.015, 0.02, 0.02, 0.03), "LARGE": (0.02, 0.03, 0.05, 0.10),
                     "ONE": (0.999, 0.999, 1.0, 1.0)},
    heading_weight={"ZERO": (0.0, 0.0, 0.03, 0.05), "SMALL": (0.02, 0.05, 0.25, 0.3),
                    "MED": (0.25, 0.3, 0.4, 0.5), "LARGE": (0.4, 0.5, 0.8, 0.95),
                    "ONE": (0.9, 0.95, 1.0, 1.0)},
)

# (distance set, other input, its set, output set): the thesis's nine rules
RULES = (
    ("SMALL", "velocity", "FAST", "LARGE"),
    ("MED", "velocity", "FAST", "MED"),
    ("SMALL", "velocity", "MED", "MED"),
    ("MED", "velocity", "MED", "SMALL"),
    ("SMALL", "velocity", "SLOW", "SMALL"),
    ("MED", "velocity", "SLOW", "ZERO"),
    ("LARGE", "num_no_good", "SMALL", "ZERO"),
    ("LARGE", "num_no_good", "MED", "ZERO"),
    ("LARGE", "num_no_good", "LARGE", "ONE"),
)

_GRID = np.linspace(0.0, 1.0, 2001)


def rule_strengths(sets: FuzzySets, distance_m: float, velocity_mps: float,
                   num_no_good: int) -> dict[str, float]:
    """Fuzzy AND (min) per rule, fuzzy OR (max) per output set."""
    inputs = {"velocity": (velocity_mps, sets.velocity_mps),
              "num_no_good": (float(num_no_good), sets.num_no_good)}
    out: dict[str, float] = {}
    for dist_set, other, other_set, output in RULES:
        value, other_sets = inputs[other]
        strength = min(trapezoid(distance_m, sets.distance_m[dist_set]),
                       trapezoid(value, other_sets[other_set]))
        out[output] = max(out.get(output, 0.0), strength)
    return out


def centroid(strengths: dict[str, float], output_sets: dict[str, Trapezoid]) -> float:
    """Centroid of the union of output sets clipped at their strengths; 0 when none fires."""
    mu = np.zeros_like(_GRID)
    for name, strength in strengths.items():
        if strength > 0.0:
            a, b, c, d = output_sets[name]
            member = np.interp(_GRID, [a, b, c, d], [0.0, 1.0, 1.0, 0.0]) if b > a \
                else np.where((_GRID >= a) & (_GRID <= d), 1.0, 0.0)
            mu = np.maximum(mu, np.minimum(member, strength))
    area = float(mu.sum())
    return 0.0 if area == 0.0 else float((mu * _GRID).sum() / area)


def fuzzy_weights(sets: FuzzySets, distance_m: float, velocity_mps: float,
                  num_no_good: int) -> tuple[float, float]:
    """GPS (position, heading) weights for one fix."""
    strengths = rule_strengths(sets, distance_m, velocity_mps, num_no_good)
    return (centroid(strengths, sets.position_weight),
            centroid(strengths, sets.heading_weight))


def zero_weight(sets: FuzzySets) -> float:
    """The largest position weight that is the ZERO set's: the fix is not used (its centroid
    is 0.0005, not 0; taken as a blend, a fix 260 m away never counted as rejected and the
    NumNoGood recovery never came)."""
    return sets.position_weight["ZERO"][3]
