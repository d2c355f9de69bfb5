"""Extended Kalman filter primitives over plain arrays (pure): the one update both filters use.

FilterPy's letters: ``x`` state, ``P`` covariance, ``F`` transition Jacobian, ``Q`` process
noise, ``z`` measurement, ``H`` measurement Jacobian, ``R`` measurement noise, ``y``
innovation, ``S`` its covariance, ``K`` gain, ``nis`` normalised innovation squared.
The update uses the Joseph form so that ``P`` stays symmetric positive semi-definite.

A sensor enters a filter as a measurement model (pyins's way): a small object whose ``model``
gives ``(z, h, H, R)`` at the filter's state (``Linearised``); the road filter's models are
in :mod:`navsvc.fusion.road.measurements`, the INS's in :mod:`navsvc.fusion.ins.measurements`.

The filter runs these at 100-200 Hz per vehicle on 8x8 matrices, where NumPy's per-call
overhead costs more than the arithmetic; the bodies are compiled with numba (cached on disk),
and their products are plain loops (:func:`matmul`), as BLAS calls cost more than the
arithmetic too at this size.
"""

from __future__ import annotations

import math
from typing import Protocol, TypeVar

import numpy as np

from navsvc.fusion._jit import Array, jit

State_contra = TypeVar("State_contra", contravariant=True)


# A measurement at a state: ``(z, h, H, R)``, ``z`` measured, ``h`` predicted, ``H = ∂h/∂x``,
# noise ``R`` (a plain tuple: a NamedTuple cost a third of a microsecond per update more)
Linearised = tuple[Array, Array, Array, Array]


class Measurement(Protocol[State_contra]):
    """A measurement model: adding a sensor is adding one."""

    def model(self, state: State_contra) -> Linearised: ...


# chi-square quantiles (probability 0.999) by degrees of freedom, for innovation gating; 3 and
# 6 rounded as the INS has always had them (16.266, 22.458): its soft gate scales R by
# nis / limit, so the last digit shows in its output
CHI2_999 = {1: 10.828, 2: 13.816, 3: 16.27, 4: 18.467, 5: 20.515, 6: 22.46}

@jit
def matmul(A: Array, B: Array) -> Array:  # pragma: no cover - compiled
    """``A @ B`` for small matrices (Jacobians are mostly zeros, which are skipped)."""
    C = np.zeros((A.shape[0], B.shape[1]))
    for i in range(A.shape[0]):
        for k in range(A.shape[1]):
            a = A[i, k]
            if a != 0.0:
                for j in range(B.shape[1]):
                    C[i, j] += a * B[k, j]
    return C


@jit
def predict(P: Array, F: Array, q_diag: Array) -> Array:  # pragma: no cover - compiled
    """Covariance after one step: ``F P Fᵀ + Q`` with a diagonal ``Q`` (the state was
    propagated by the caller)."""
    P_next = matmul(matmul(F, P), F.T)
    for i in range(len(q_diag)):
        P_next[i, i] += q_diag[i]
    return 0.5 * (P_next + P_next.T)


@jit
def inverse(S: Array) -> Array:  # pragma: no cover - compiled
    """Inverse of a small symmetric positive-definite matrix (closed form up to 2x2)."""
    n = S.shape[0]
    if n == 1:
        return np.array([[1.0 / S[0, 0]]])
    if n == 2:
        det = S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0]
        return np.array([[S[1, 1] / det, -S[0, 1] / det], [-S[1, 0] / det, S[0, 0] / det]])
    return np.ascontiguousarray(np.linalg.inv(S))


def gate_limit(dof: int, scale: float = 1.0) -> float:
    """The largest NIS that passes the chi-square gate (``scale`` widens it)."""
    return CHI2_999[dof] * scale


def nis(P: Array, H: Array, R: Array, y: Array) -> float:
    """The normalised innovation squared ``yᵀ (H P Hᵀ + R)⁻¹ y``."""
    return float(_nis(_f64(y), matmul(matmul(_f64(H), P), _f64(H).T) + _f64(R)))


@jit
def _nis(y: Array, S: Array) -> float:  # pragma: no cover - compiled
    S_inv = inverse(S)
    total = 0.0
    for i in range(len(y)):
        for j in range(len(y)):
            total += y[i] * S_inv[i, j] * y[j]
    return total


def _f64(a: Array) -> Array:
    """The array as float64 for the compiled kernels, copied only when it is not already."""
    return np.asarray(a, dtype=np.float64)


def correct(x: Array, P: Array, z: Array, h: Array, H: Array, R: Array,
            max_nis: float = math.inf) -> tuple[Array, Array, float]:
    """Measurement update: innovation ``y = z - h(x)``, its NIS ``yᵀ S⁻¹ y`` against the gate
    ``max_nis``, then the Joseph-form update. Returns ``(x, P, nis)``; past the gate ``x`` and
    ``P`` come back as they were. One compiled call: the filter makes one per inertial sample."""
    return correct_compiled(x, P, _f64(z), _f64(h), _f64(H), _f64(R), max_nis)


@jit
def correct_compiled(x: Array, P: Array, z: Array, h: Array, H: Array, R: Array,
                     max_nis: float) -> tuple[Array, Array, float]:  # pragma: no cover
    """:func:`correct` for compiled callers (float64 arrays)."""
    y = z - h
    K, nis = gain_and_nis(P, H, R, y)
    if not nis <= max_nis:
        return x, P, nis
    x_new, P_new = joseph(x, P, y, H, R, K)
    return x_new, P_new, nis


@jit
def gain_and_nis(P: Array, H: Array, R: Array, y: Array) -> tuple[Array, float]:  # pragma: no cover
    """The Kalman gain ``P Hᵀ S⁻¹`` and the innovation's NIS ``yᵀ S⁻¹ y``."""
    PHt = matmul(P, H.T)
    S_inv = inverse(matmul(H, PHt) + R)
    nis = 0.0
    for i in range(len(y)):
        for j in range(len(y)):
            nis += y[i] * S_inv[i, j] * y[j]
    return matmul(PHt, S_inv), nis


@jit
def joseph(x: Array, P: Array, y: Array, H: Array, R: Array,
            K: Array) -> tuple[Array, Array]:  # pragma: no cover - compiled
    x_new = x + matmul(K, y.reshape(-1, 1)).ravel()
    I_KH = np.eye(len(x)) - matmul(K, H)
    P_new = matmul(matmul(I_KH, P), I_KH.T) + matmul(matmul(K, R), K.T)
    return x_new, 0.5 * (P_new + P_new.T)


def fixed_gain_update(x: Array, P: Array, y: Array, H: Array, R: Array,
                      K: Array) -> tuple[Array, Array]:
    """Update with a prescribed gain (the thesis's weighted sums), Joseph form for ``P``."""
    return joseph(x, P, _f64(y), _f64(H), _f64(R), _f64(K))


def correct_leaving(x: Array, P: Array, z: Array, h: Array, H: Array, R: Array,
                    unchanged: tuple[int, ...], max_nis: float = math.inf
                    ) -> tuple[Array, Array, float]:
    """:func:`correct` with a zero gain for the states ``unchanged`` (a Schmidt, or
    "consider", update: the Joseph form keeps ``P`` right for that gain). For a measurement
    that says nothing of those states although its linearisation seems to, and for states
    a filter considers but does not estimate. Returns ``(x, P, nis)``, as :func:`correct`."""
    return correct_leaving_compiled(x, P, _f64(z - h), _f64(H), _f64(R), kept_mask(unchanged),
                                    max_nis)


def kept_mask(unchanged: tuple[int, ...], n_states: int | None = None) -> Array:
    """1 for each state an update may change, 0 for those it leaves (``correct_leaving``)."""
    keep = np.ones(n_states if n_states is not None else max(unchanged) + 1)
    keep[list(unchanged)] = 0.0
    return keep


@jit
def correct_leaving_compiled(x: Array, P: Array, y: Array, H: Array, R: Array, keep: Array,
                             max_nis: float) -> tuple[Array, Array, float]:  # pragma: no cover
    """:func:`correct_leaving` for compiled callers: innovation ``y``; ``keep`` 0 for the
    states left as they are (states past its end are changed)."""
    K, nis = gain_and_nis(P, H, R, y)
    if not nis <= max_nis:
        return x, P, nis
    for i in range(len(keep)):
        if keep[i] == 0.0:
            K[i, :] = 0.0
    x_new, P_new = joseph(x, P, y, H, R, K)
    return x_new, P_new, nis


def no_surer_than(P: Array, H: Array, R: Array, probability: float = 1.0) -> Array:
    """``R`` (diagonal) raised so that no row of the update leaves the state surer along it
    than the measurement itself is: for a source that says the same thing again and again
    with one error that does not average out (the map: a road's line is as wrong the
    hundredth time it is looked at as the first). A row already that sure is dropped.

    A measurement right only with ``probability`` (a road that others beside the estimate
    rival) takes that share of the variance the update would take away, and moves the
    state by that share of its full step: the mixture of taking it and leaving it, as in
    probabilistic data association (the other roads' own pulls left out)."""
    R = R.copy()
    for i in range(len(R)):
        p, r = float(H[i] @ P @ H[i]), float(R[i, i])
        removed = probability * (p - r)  # of the variance p along the row
        R[i, i] = DROPPED_VARIANCE if p <= r * (1.0 + 1e-9) or not removed > 0.0 \
            else min(max(r, p * (p - removed) / removed), DROPPED_VARIANCE)  # a road all
        # but ruled out beside a huge P: no infinite variance, which the inverse turns to NaN;
        # nor a division by a share so small that the variance it removes rounds to zero
    return R


DROPPED_VARIANCE = 1e12  # a measurement row that says nothing
