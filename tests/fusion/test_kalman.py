import numpy as np
import pytest
from hypothesis import example, given
from hypothesis import strategies as st

from navsvc.fusion import kalman
from navsvc.fusion.road import measurements, motion


def test_scalar_update_by_hand() -> None:
    # prior 0 +- 2 (var 4), measurement 3 +- 1 (var 1): K = 4/5, x = 2.4, P = 0.8
    x, P = np.array([0.0]), np.array([[4.0]])
    H, R = np.array([[1.0]]), np.array([[1.0]])
    x2, P2, nis = kalman.correct(x, P, np.array([3.0]), x, H, R)
    assert nis == pytest.approx(9.0 / 5.0)  # S = 5
    assert x2[0] == pytest.approx(2.4) and P2[0, 0] == pytest.approx(0.8)


def test_two_by_two_position_update() -> None:
    x = np.array([0.0, 0.0])
    P = np.diag([4.0, 9.0])
    H, R = np.eye(2), np.eye(2)
    x2, P2, _ = kalman.correct(x, P, np.array([5.0, 10.0]), x, H, R)
    assert x2 == pytest.approx([4.0, 9.0])
    assert np.diag(P2) == pytest.approx([0.8, 0.9])


def test_gate() -> None:
    assert kalman.gate_limit(2) == pytest.approx(13.816)
    assert kalman.gate_limit(2, scale=2.0) == pytest.approx(2 * 13.816)
    # past the gate the state comes back unchanged, with the NIS that refused it
    x, P = np.array([0.0, 0.0]), np.diag([4.0, 9.0])
    x2, P2, nis = kalman.correct(x, P, np.array([50.0, 0.0]), x, np.eye(2), np.eye(2),
                                 kalman.gate_limit(2))
    assert nis == pytest.approx(2500.0 / 5.0)
    assert np.array_equal(x2, x) and np.array_equal(P2, P)


spd = st.floats(0.1, 100.0)


@given(spd, spd, spd, st.floats(-50, 50), st.floats(-50, 50))
def test_covariance_stays_symmetric_psd(a: float, b: float, r: float, z0: float,
                                        z1: float) -> None:
    P = np.array([[a, 0.3 * min(a, b)], [0.3 * min(a, b), b]])
    H, R = np.array([[1.0, 0.5]]), np.array([[r]])
    x = np.zeros(2)
    _, P2, _ = kalman.correct(x, P, np.array([z0]), H @ x, H, R)
    assert np.allclose(P2, P2.T)
    assert np.linalg.eigvalsh(P2).min() > -1e-9
    F = np.array([[1.0, 0.1], [0.0, 1.0]])
    P3 = kalman.predict(P2, F, np.full(2, z1 ** 2 * 1e-3))
    assert np.allclose(P3, P3.T) and np.linalg.eigvalsh(P3).min() > -1e-9


@given(st.lists(st.floats(-3, 3), min_size=9, max_size=9))
def test_inverse_matches_numpy(values: list[float]) -> None:
    A = np.array(values).reshape(3, 3)
    S = A @ A.T + np.eye(3)  # symmetric positive definite
    for n in (1, 2, 3):
        assert np.allclose(kalman.inverse(S[:n, :n]) @ S[:n, :n], np.eye(n), atol=1e-9)


state = st.tuples(st.floats(-1e3, 1e3), st.floats(-1e3, 1e3), st.floats(0, 6.28),
                  st.floats(0, 40), st.floats(-1, 1), st.floats(-0.05, 0.05),
                  st.floats(0.9, 1.1), st.floats(-0.5, 0.5), st.floats(-0.05, 0.05),
                  st.floats(-10, 10), st.floats(-10, 10), st.floats(0.0, 0.5))


@given(state, st.floats(0.0, 0.35), st.floats(-2, 2), st.one_of(st.none(), st.floats(-5, 5)))
def test_predict_with_gyro_is_predict_then_the_rate_from_the_gyro(
        x0: tuple[float, ...], dt: float, rate: float, accel: float | None) -> None:
    """The fused compiled step against its two parts written plainly: the rate becomes
    ``-(gyro - bias) / (1 + scale error)``, its covariance that of this linear map."""
    x = np.array(x0)
    P = np.diag([4.0, 4.0, 0.01, 1.0, 0.01, 1e-4, 1e-3, 1e-2, 4e-4, 9.0, 9.0, 0.01])
    noise = motion.ProcessNoise()
    fused_x, fused_P = measurements.predict_with_gyro(x, P, dt, 0.1, accel, noise, rate,
                                                      0.005)
    x1, P1 = (x, P) if dt <= 1e-9 else motion.predict(x, P, dt, 0.1, accel, noise)
    gain = 1.0 + x1[motion.GYRO_SCALE]
    A = np.eye(motion.N_STATES)
    A[motion.HEADING_RATE, motion.HEADING_RATE] = 0.0
    A[motion.HEADING_RATE, motion.GYRO_BIAS] = 1.0 / gain
    A[motion.HEADING_RATE, motion.GYRO_SCALE] = (rate - x1[motion.GYRO_BIAS]) / gain ** 2
    P2 = A @ P1 @ A.T
    P2[motion.HEADING_RATE, motion.HEADING_RATE] += 0.005 ** 2 / gain ** 2
    x2 = x1.copy()
    x2[motion.HEADING_RATE] = -(rate - x1[motion.GYRO_BIAS]) / gain
    np.testing.assert_allclose(fused_x, x2, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(fused_P, P2, rtol=1e-12, atol=1e-15)


@given(st.lists(st.floats(-3.0, 3.0), min_size=9, max_size=9),
       st.floats(0.01, 10.0), st.floats(0.01, 10.0))
def test_a_repeated_measurement_never_makes_the_state_surer_than_itself(
        values: list[float], r0: float, r1: float) -> None:
    """The map's road constraint, looked at again and again: after any number of updates
    with ``no_surer_than``, an update never takes the variance along its row below the
    measurement's own, nor lowers it when it is already there (another row correlated with
    it in ``P`` can: the road filter's two rows, across the road and heading, hardly are)."""
    A = np.array(values).reshape(3, 3)
    P = A @ A.T + 5.0 * np.eye(3)
    rows = (np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 0.6, 0.8]]))
    x = np.zeros(3)
    for k in range(6):
        H, R = rows[k % 2], np.array([[(r0, r1)[k % 2]]])
        before = H[0] @ P @ H[0]
        x, P, _ = kalman.correct(x, P, np.zeros(1), H @ x, H, kalman.no_surer_than(P, H, R),
                                 np.inf)
        assert H[0] @ P @ H[0] >= min(R[0, 0], before) * (1.0 - 1e-6)


@given(st.floats(0.5, 1e4), st.floats(0.01, 0.99), st.floats(0.0, 1.0), st.floats(-50.0, 50.0))
@example(1.0, 0.5, 5e-324, 1.0)  # the variance it removes rounds to zero: no division by it
def test_a_measurement_only_that_likely_takes_that_share_of_its_update(
        variance: float, measured_share: float, probability: float, innovation: float) -> None:
    """A road that others rival (map feedback after a long outage, when the estimate could
    lie on any of a dozen): the update removes ``probability`` of the variance it would
    remove for a sure road, and moves the state ``probability`` of the way, as the mixture
    of taking the road and not would; at 1 it is the sure road's ``no_surer_than``."""
    P = np.array([[variance, 0.3 * variance], [0.3 * variance, variance]])
    H = np.array([[1.0, 0.0]])
    R = np.array([[measured_share * variance]])
    y = np.array([innovation])
    sure_x, sure_P, _ = kalman.correct(np.zeros(2), P, y, np.zeros(1), H,
                                       kalman.no_surer_than(P, H, R), np.inf)
    x, P_after, _ = kalman.correct(np.zeros(2), P, y, np.zeros(1), H,
                                   kalman.no_surer_than(P, H, R, probability), np.inf)
    removed = variance - P_after[0, 0]
    assert removed == pytest.approx(probability * (variance - sure_P[0, 0]), rel=1e-6,
                                    abs=1e-6 * variance)  # a dropped row: 1e12
    np.testing.assert_allclose(x, probability * sure_x, rtol=1e-6, atol=1e-6 * abs(innovation))


@given(st.floats(1.0, 1e300), st.floats(0.0, 1e-12))
def test_a_road_all_but_ruled_out_says_nothing_and_stays_finite(variance: float,
                                                                 probability: float) -> None:
    """A road of (next to) no probability beside a huge variance: its row says nothing
    (``DROPPED_VARIANCE``), not an infinite variance, whose ``K R K^T`` is NaN."""
    R = kalman.no_surer_than(np.array([[variance]]), np.array([[1.0]]), np.array([[0.25]]),
                             probability)
    assert 0.25 <= R[0, 0] <= kalman.DROPPED_VARIANCE


@given(st.floats(0.01, 120.0), st.floats(1.0, 100.0), st.floats(0.1, 30.0),
       st.floats(-40.0, 40.0))
def test_a_held_gps_bias_keeps_its_value_and_grows_as_the_process_would(
        dt_s: float, tau_s: float, sigma_m: float, bias_m: float) -> None:
    """Held (a start between two tracks), the GPS bias keeps its value and its covariance
    with the rest, and its variance grows by what a Gauss-Markov process of the same
    ``tau`` and ``sigma`` adds, up to the held sigma (never shrinking to it); not held, it
    decays toward zero."""
    x = np.zeros(motion.N_STATES)
    x[list(motion.GPS_BIAS)] = bias_m
    P = np.eye(motion.N_STATES)
    P[motion.X_M, motion.GPS_BIAS_E] = P[motion.GPS_BIAS_E, motion.X_M] = -0.5
    held_x, held_P = x.copy(), P.copy()
    motion.propagate_gps_bias(held_x, held_P, dt_s, tau_s, sigma_m, held_within_m=1e3)
    grown = sigma_m ** 2 * (1.0 - np.exp(-2.0 * dt_s / tau_s))
    assert np.array_equal(held_x, x)
    assert held_P[motion.GPS_BIAS_E, motion.GPS_BIAS_E] == pytest.approx(1.0 + grown)
    assert held_P[motion.X_M, motion.GPS_BIAS_E] == -0.5
    for within_m in (0.5, 1.0 + 0.5 * grown):
        capped_P = P.copy()
        motion.propagate_gps_bias(x.copy(), capped_P, dt_s, tau_s, sigma_m,
                                  held_within_m=within_m)
        assert capped_P[motion.GPS_BIAS_N, motion.GPS_BIAS_N] == pytest.approx(
            max(1.0, min(1.0 + grown, within_m ** 2)))
    decayed_x, decayed_P = x.copy(), P.copy()
    motion.propagate_gps_bias(decayed_x, decayed_P, dt_s, tau_s, sigma_m)
    assert abs(decayed_x[motion.GPS_BIAS_E]) <= abs(bias_m)
    assert decayed_P[motion.GPS_BIAS_E, motion.GPS_BIAS_E] == pytest.approx(
        np.exp(-2.0 * dt_s / tau_s) + grown)
