"""Measurement models of the strapdown INS (pure), one small object per aiding sensor.

Giroux, Gourdeau, Landry 2005 (docs/seed-digest.md), loosely coupled: GNSS position (with the
antenna's lever arm) and velocity; body-frame velocity for wheel speed, the non-holonomic
constraint and stops; the zero-rate update at rest; the matched road (map feedback). Each
``model(ins)`` gives ``(z, h, H, R)`` (:data:`~navsvc.fusion.kalman.Linearised`) in the
filter's own state: ``z`` is the residual (predicted less measured) and ``h = H dx`` its
prediction from the estimated error ``dx``, so the update is the one Kalman update of
:mod:`navsvc.fusion.kalman`. The residual and ``H`` come from the filter
(:class:`.error_state.InsFilter` analytic, :class:`.total_state.DirectInsFilter` by central
differences); a test checks the analytic ``H`` against central differences of the residual.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar, Protocol

import numpy as np

from navsvc.fusion._jit import Array
from navsvc.fusion.kalman import Linearised, no_surer_than

if TYPE_CHECKING:
    from navsvc.fusion.ins.error_state import GnssFix, InsFilter


class InsMeasurement(Protocol):
    """A measurement the INS takes: its model and how it is gated."""

    gate_dof: ClassVar[int]  # chi-square gate (99.9 %) of this many degrees of freedom
    soft_gate: ClassVar[bool]  # refused often in a row, taken with its noise inflated

    def model(self, ins: InsFilter) -> Linearised: ...


def _linearised(ins: InsFilter, y: Array, H: Array, R: Array) -> Linearised:
    return (y, H @ ins.dx, H, R)


@dataclass(frozen=True)
class GnssPosition:
    """A GNSS position at the state's time, at the antenna (lever arm in the body frame),
    with the receiver's slowly changing error (the filter's GNSS bias states)."""

    fix: GnssFix
    gate_dof: ClassVar[int] = 3
    soft_gate: ClassVar[bool] = True

    def __post_init__(self) -> None:
        sigma = self.fix.sigma_ned_m
        if not (np.all(np.isfinite(sigma)) and np.all(sigma > 0.0)):
            raise ValueError(f"GNSS standard deviations must be finite and > 0, got {sigma}")

    def model(self, ins: InsFilter) -> Linearised:
        y, H = ins.gnss_position_residual(self.fix)
        return _linearised(ins, y, H, np.diag(self.fix.sigma_ned_m**2))


@dataclass(frozen=True)
class GnssVelocity:
    """GNSS velocity: the ``rows`` of north, east, down that were measured."""

    v_ned_mps: Array
    rows: tuple[int, ...]
    sigma_mps: float
    gate_dof: ClassVar[int] = 3
    soft_gate: ClassVar[bool] = False

    def model(self, ins: InsFilter) -> Linearised:
        idx = list(self.rows)
        y, H = ins.velocity_residual(self.v_ned_mps)
        return _linearised(ins, y[idx], H[idx], np.eye(len(idx)) * self.sigma_mps**2)


@dataclass(frozen=True)
class BodyVelocity:
    """Measured components (``rows`` of x forward, y right, z down) of the velocity in the
    body frame: wheel speed (x), the non-holonomic constraint (y = z = 0), a stop (all 0)."""

    v_body_mps: Array
    rows: tuple[int, ...]
    sigma_mps: Array  # per axis
    gate_dof: ClassVar[int] = 3
    soft_gate: ClassVar[bool] = False

    def model(self, ins: InsFilter) -> Linearised:
        idx = list(self.rows)
        y, H = ins.body_velocity_residual(self.v_body_mps)
        R = np.diag(np.asarray(self.sigma_mps, dtype=np.float64)[idx] ** 2)
        return _linearised(ins, y[idx], H[idx], R)


@dataclass(frozen=True)
class Rest:
    """The vehicle stands still: zero velocity, and the gyro reads its bias plus the earth's
    rate (zero-velocity and zero-angular-rate updates)."""

    gyro_rps: Array
    gyro_sigma_rps: float
    velocity_sigma_mps: float
    gate_dof: ClassVar[int] = 6
    soft_gate: ClassVar[bool] = False

    def model(self, ins: InsFilter) -> Linearised:
        y, H = ins.rest_residual(self.gyro_rps)
        R = np.diag([self.velocity_sigma_mps**2] * 3 + [self.gyro_sigma_rps**2] * 3)
        return _linearised(ins, y, H, R)


@dataclass(frozen=True)
class AcrossRoad:
    """Map feedback: the position lies on the road through ``point`` with bearing
    ``road_bearing_rad`` (clockwise from north), within ``sigma_m`` across it; along it the
    map says nothing. The position residual at that point, projected on the road's normal;
    its variance raised so that the update leaves the position no surer across the road than
    the map is (the same road again and again: its error does not average out), and taken
    as right only with ``probability`` (:func:`navsvc.fusion.kalman.no_surer_than`)."""

    point: GnssFix  # its sigmas unused
    road_bearing_rad: float
    sigma_m: float
    probability: float = 1.0
    gate_dof: ClassVar[int] = 1
    soft_gate: ClassVar[bool] = False

    def model(self, ins: InsFilter) -> Linearised:
        y, H = ins.position_residual(self.point)
        normal_ne = np.array([-np.sin(self.road_bearing_rad), np.cos(self.road_bearing_rad)])
        y1, H1 = np.array([normal_ne @ y[:2]]), (normal_ne @ H[:2])[None, :]
        return _linearised(ins, y1, H1, no_surer_than(ins.P, H1, np.array([[self.sigma_m ** 2]]),
                                                     self.probability))
