"""The tunable parameters: one declared table, and the unit-cube coordinates both searches use.

Each :class:`Parameter` names a field of the session's configuration by its dotted path into
:class:`navsvc.session.SessionConfig` (``fusion.*`` is ``navsvc.fusion.FusionConfig``,
``matcher.*`` is ``navsvc.matching.online.MatcherConfig``), the component it belongs to, its
range (or set of values), its scale and the bits a GA genotype gives it. This module only reads
those names; :func:`navsvc.session.apply_profile` sets them.

Both searches work in the unit cube: a coordinate ``u`` in [0, 1] per parameter maps to its
range linearly or logarithmically (a set: ``u`` picks an element, evenly spaced). A genotype is
``bits`` per parameter (seed: Mayhew 1999, section 5.6, parameters as bit-string genotypes),
in Gray code: the integer ``k`` of ``u = k / (2^bits - 1)`` is written as ``k ^ (k >> 1)``, so
that neighbouring values differ in one bit and a mutation's single flip can always step a
parameter to its neighbour (in plain binary, 127 to 128 flips all 8 bits). Pure.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from navsvc.errors import ConfigError

Value = float | int | bool


@dataclass(frozen=True)
class Parameter:
    """One tunable parameter. ``low``/``high`` bound a range; ``choices`` is a set instead."""

    name: str  # dotted path into SessionConfig
    component: str  # fusion noise | fusion gating | gps rules | gps fuzzy | matcher | session
    low: float = 0.0
    high: float = 1.0
    scale: str = "linear"  # "linear" or "log" (a range spanning decades)
    bits: int = 8  # of a GA genotype
    integer: bool = False
    choices: tuple[Value, ...] = ()
    note: str = ""

    def __post_init__(self) -> None:
        if self.scale not in ("linear", "log"):
            raise ConfigError(f"{self.name}: scale must be linear or log")
        if not self.choices and not self.low < self.high:
            raise ConfigError(f"{self.name}: need low < high")
        if self.scale == "log" and self.low <= 0.0:
            raise ConfigError(f"{self.name}: a log scale needs low > 0")
        if not 1 <= self.bits <= 30:
            raise ConfigError(f"{self.name}: bits must be 1-30")

    def value(self, u: float) -> Value:
        """The value at unit coordinate ``u`` (clipped to [0, 1])."""
        u = min(max(u, 0.0), 1.0)
        if self.choices:
            return self.choices[round(u * (len(self.choices) - 1))]
        if self.scale == "log":
            x = math.exp(math.log(self.low) + u * (math.log(self.high) - math.log(self.low)))
        else:
            x = self.low + u * (self.high - self.low)
        return round(x) if self.integer else _significant(x)

    def unit(self, value: Any) -> float:
        """The unit coordinate of ``value`` (clipped to the range; a set: its element)."""
        if self.choices:
            if value not in self.choices:
                raise ConfigError(f"{self.name}: {value!r} is not one of {self.choices}")
            return self.choices.index(value) / max(len(self.choices) - 1, 1)
        x = min(max(float(value), self.low), self.high)
        if self.scale == "log":
            return (math.log(x) - math.log(self.low)) / (math.log(self.high) - math.log(self.low))
        return (x - self.low) / (self.high - self.low)

    def describe(self) -> str:
        if self.choices:
            return "{" + ", ".join(str(c) for c in self.choices) + "}"
        return f"[{self.low:g}, {self.high:g}] {self.scale}"


def _significant(x: float) -> float:
    """Five significant digits: profiles stay readable and a decoded value round-trips."""
    return float(f"{x:.5g}")


def _p(name: str, component: str, low: float, high: float, scale: str = "linear",
       bits: int = 8, integer: bool = False, note: str = "") -> Parameter:
    return Parameter(name, component, low, high, scale, bits, integer, (), note)


TABLE: tuple[Parameter, ...] = (
    # fusion noise
    _p("fusion.gyro_sigma_rps", "fusion noise", 5e-4, 0.05, "log"),
    _p("fusion.odometer_sigma_mps", "fusion noise", 0.02, 1.5, "log"),
    _p("fusion.gps_uere_m", "fusion noise", 1.0, 15.0, "log"),
    _p("fusion.gps_default_sigma_m", "fusion noise", 1.0, 20.0, "log"),
    _p("fusion.gps_velocity_sigma_mps", "fusion noise", 0.05, 5.0, "log"),
    _p("fusion.gps_bias_share", "fusion noise", 0.0, 0.95),
    _p("fusion.gps_bias_tau_s", "fusion noise", 5.0, 120.0, "log"),
    _p("fusion.initial_gps_latency_s", "fusion noise", 0.0, 0.4),
    _p("fusion.process.accel_mps2", "fusion noise", 0.1, 10.0, "log"),
    _p("fusion.process.heading_accel_rps2", "fusion noise", 0.02, 4.0, "log"),
    _p("fusion.process.gyro_bias_drift_rps_per_sqrt_s", "fusion noise", 1e-6, 1e-2, "log"),
    _p("fusion.process.odo_scale_drift_per_sqrt_s", "fusion noise", 1e-7, 1e-3, "log"),
    # fusion gating
    _p("fusion.gps_gate_scale", "fusion gating", 0.25, 4.0, "log"),
    _p("fusion.gps_huber_nis", "fusion gating", 1.0, 30.0, "log"),
    _p("fusion.gps_nis_memory_fixes", "fusion gating", 3.0, 300.0, "log"),
    _p("fusion.reacquire_after_gated_s", "fusion gating", 5.0, 120.0, "log"),
    _p("fusion.inflate_after_gated_fixes", "fusion gating", 1, 10, bits=4, integer=True),
    _p("fusion.min_speed_for_gps_heading_mps", "fusion gating", 0.5, 8.0),
    _p("fusion.track_settled_s", "fusion gating", 1.0, 30.0, "log"),
    _p("fusion.track_confirm_nis", "fusion gating", 0.5, 10.0, "log"),
    _p("fusion.max_jump_s", "fusion gating", 5.0, 120.0, "log"),
    _p("fusion.heading_unknown_sigma_rad", "fusion gating", 0.05, 1.0, "log"),
    _p("fusion.gps_lost_beyond_m", "fusion gating", 80.0, 500.0, "log"),
    _p("fusion.gps_lost_after_s", "fusion gating", 0.5, 10.0, "log"),
    # the thesis's rule-based GPS fusion (gps_mode "rules")
    _p("fusion.rules.position_weight_per_s", "gps rules", 0.005, 0.5, "log",
       note="GPSPosWeight"),
    _p("fusion.rules.heading_weight_per_s", "gps rules", 0.05, 1.0, note="GPSHeadingWeight"),
    _p("fusion.rules.max_distance_m", "gps rules", 10.0, 200.0, "log", note="GPSPosThreshold"),
    _p("fusion.rules.widen_after_fixes", "gps rules", 3, 100, "log", bits=6, integer=True,
       note="m_GPSNoUpdateThresh"),
    _p("fusion.rules.widen_factor", "gps rules", 1.05, 3.0),
    # the thesis's fuzzy GPS fusion (gps_mode "fuzzy"): whole membership sets scaled
    _p("fusion.fuzzy.distance_m.scale", "gps fuzzy", 0.25, 4.0, "log",
       note="the Distance sets SMALL/MED/LARGE"),
    _p("fusion.fuzzy.position_weight.scale", "gps fuzzy", 0.25, 4.0, "log",
       note="the output position weights"),
    _p("fusion.fuzzy.heading_weight.scale", "gps fuzzy", 0.25, 1.0, "log",
       note="the output heading weights (at most 1)"),
    # the online matcher
    _p("matcher.road_sigma_m", "matcher", 1.0, 20.0, "log"),
    _p("matcher.turn_sigma_rad", "matcher", 0.05, 1.0, "log"),
    _p("matcher.prior_keep", "matcher", 0.0, 0.98),
    _p("matcher.confident_probability", "matcher", 0.5, 0.99),
    _p("matcher.drift_fraction", "matcher", 0.01, 0.2, "log", note="seed: 4 %"),
    _p("matcher.min_radius_m", "matcher", 3.0, 30.0, "log"),
    _p("matcher.off_road_distance_m", "matcher", 10.0, 100.0, "log"),
    # the session's map feedback
    Parameter("map_feedback", "session", choices=(False, True), bits=1),
    _p("feedback_sigma_across_m", "session", 0.5, 10.0, "log"),
    _p("feedback_max_distance_m", "session", 3.0, 30.0, "log"),
    _p("feedback_gate_sigmas", "session", 1.0, 6.0, "log"),
)

BY_NAME = {p.name: p for p in TABLE}

# The default selection: the noise and gating of the EKF (the default fusion mode) and the
# matcher's two spreads (the heading-rate noise left it when the gyro became the filter's
# input: it matters only without a gyro). These move the scores most on the harsh-urban
# drives; the rules and fuzzy parameters matter only with their own GPS mode, so they are
# picked by name.
DEFAULT_SET: tuple[str, ...] = (
    "fusion.gps_uere_m", "fusion.gps_bias_share", "fusion.gps_gate_scale",
    "fusion.gps_huber_nis", "fusion.process.accel_mps2", "fusion.gps_bias_tau_s",
    "fusion.gyro_sigma_rps", "fusion.odometer_sigma_mps", "matcher.road_sigma_m",
    "matcher.prior_keep",
)


def select(names: Sequence[str] | None = None) -> tuple[Parameter, ...]:
    """The parameters named (default :data:`DEFAULT_SET`); an unknown name is an error."""
    chosen = list(DEFAULT_SET if not names else names)
    unknown = [n for n in chosen if n not in BY_NAME]
    if unknown:
        raise ConfigError(f"unknown parameter(s) {', '.join(unknown)}; known: "
                          f"{', '.join(BY_NAME)}")
    if len(set(chosen)) != len(chosen):
        raise ConfigError("a parameter is named twice")
    return tuple(BY_NAME[n] for n in chosen)


def decode(params: Sequence[Parameter], u: Sequence[float]) -> dict[str, Value]:
    """The values at unit coordinates ``u``."""
    return {p.name: p.value(x) for p, x in zip(params, u, strict=True)}


def genotype_to_unit(params: Sequence[Parameter], bits: Sequence[int]) -> list[float]:
    """Unit coordinates of a bit string (each parameter's ``bits`` of Gray code, most
    significant first)."""
    u, at = [], 0
    for p in params:
        k, binary = 0, 0
        for b in bits[at:at + p.bits]:
            binary ^= int(b)  # Gray to binary: each bit is the XOR of the Gray bits so far
            k = 2 * k + binary
        u.append(k / (2 ** p.bits - 1))
        at += p.bits
    return u


def unit_to_genotype(params: Sequence[Parameter], u: Sequence[float]) -> list[int]:
    """The bit string (Gray code) nearest to unit coordinates ``u``."""
    bits: list[int] = []
    for p, x in zip(params, u, strict=True):
        k = round(min(max(x, 0.0), 1.0) * (2 ** p.bits - 1))
        g = k ^ (k >> 1)
        bits += [(g >> s) & 1 for s in range(p.bits - 1, -1, -1)]
    return bits


def genotype_length(params: Sequence[Parameter]) -> int:
    return sum(p.bits for p in params)
