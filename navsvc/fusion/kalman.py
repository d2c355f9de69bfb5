"""Extended Kalman filter primitives over plain arrays (pure).

FilterPy's letters: ``x`` state, ``P`` covariance, ``F`` transition Jacobian, ``Q`` process
noise, ``z`` measurement, ``H`` measurement Jacobian, ``R`` measurement noise, ``y``
innovation, ``S`` its covariance, ``K`` gain, ``nis`` normalised innovation squared.
The update uses the Joseph form so that ``P`` stays symmetric positive semi-definite.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.float64]

# chi-square quantiles (probability 0.999) by degrees of freedom, for innovation gating
CHI2_999 = {1: 10.828, 2: 13.816, 3: 16.266, 4: 18.467}


def predict(x_next: Array, P: Array, F: Array, Q: Array) -> Array:
    """Covariance after one step: ``F P Fᵀ + Q`` (the state was propagated by the caller)."""
    P_next = F @ P @ F.T + Q
    return 0.5 * (P_next + P_next.T)


def innovation(z: Array, h: Array, H: Array, P: Array, R: Array) -> tuple[Array, Array, float]:
    """Innovation ``y = z - h(x)``, its covariance ``S`` and the NIS ``yᵀ S⁻¹ y``."""
    y = z - h
    S = H @ P @ H.T + R
    nis = float(y @ np.linalg.solve(S, y))
    return y, S, nis


def update(x: Array, P: Array, y: Array, S: Array, H: Array, R: Array) -> tuple[Array, Array]:
    """Measurement update from an innovation (Joseph form)."""
    K = np.linalg.solve(S, H @ P).T  # P Hᵀ S⁻¹, with S symmetric
    x_new = x + K @ y
    I_KH = np.eye(len(x)) - K @ H
    P_new = I_KH @ P @ I_KH.T + K @ R @ K.T
    return x_new, 0.5 * (P_new + P_new.T)


def gate(nis: float, dof: int, scale: float = 1.0) -> bool:
    """Whether an innovation passes the chi-square gate (``scale`` widens it)."""
    return nis <= CHI2_999[dof] * scale


def fixed_gain_update(x: Array, P: Array, y: Array, H: Array, R: Array,
                      K: Array) -> tuple[Array, Array]:
    """Update with a prescribed gain (the thesis's weighted sums), Joseph form for ``P``."""
    x_new = x + K @ y
    I_KH = np.eye(len(x)) - K @ H
    P_new = I_KH @ P @ I_KH.T + K @ R @ K.T
    return x_new, 0.5 * (P_new + P_new.T)
