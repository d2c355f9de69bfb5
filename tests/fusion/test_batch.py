"""The road filter's batched path against the per-packet path (fast versus reference).

``FusionEngine.add_run`` (runs of dead-reckoning samples in one compiled call) must give what
``FusionEngine.add`` gives a packet at a time. Both paths now make the standstill and steering
updates with the same compiled kernel (they are bit for bit); ``TOLERANCE`` stays for the
odometer configurations, from when the per-packet standstill update went through LAPACK/BLAS.
And the sparse covariance products both paths use are the plain ones, bit for bit.
"""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from navsvc.fusion import PROFILES, FilterKind, FusionConfig, FusionEngine, SensorConfig, kalman
from navsvc.fusion.road import motion
from navsvc.fusion.road.batch import SampleRun
from navsvc.fusion.road.measurements import _predict_with_gyro, gyro_input
from navsvc.sim.simulate import SENSOR_KINDS, DriveSpec, simulate_drive
from navsvc.types import FusedEstimate, GpsFix, Packet
from navsvc.wire.packets import parse
from roadgraph import RoadGraph

ROAD = [s for s in SensorConfig if PROFILES[s].filter == FilterKind.ROAD and
        PROFILES[s].packets != {"gps"}]
EXACT = {SensorConfig.GYRO_ACCEL, SensorConfig.GYRO_TWO_ACCELS}  # no standstill update
TOLERANCE = 1e-9  # absolute, on metres, radians, m/s and covariances (seen: 4e-14)


@pytest.fixture(scope="module")
def drive(sample_graph: RoadGraph) -> list[dict[str, Any]]:
    """Two minutes with stops (standstill updates), a GPS outage and turns."""
    return simulate_drive(sample_graph, DriveSpec(duration_s=120.0, seed=2))


def packets_of(drive: list[dict[str, Any]], sensors: SensorConfig) -> list[Packet]:
    kinds = set(SENSOR_KINDS[sensors.value])
    return [parse(r) for r in drive if r["kind"] in kinds]


def per_packet(engine: FusionEngine, packets: list[Packet]) -> list[FusedEstimate]:
    return [e for p in packets for e in engine.add(p)]


def batched(engine: FusionEngine, packets: list[Packet], cuts: set[int] | None = None,
            size: int = 10) -> list[FusedEstimate]:
    """GPS fixes through ``add``, the samples between them in runs (of ``size``, or cut at
    ``cuts``)."""
    out: list[FusedEstimate] = []
    i = 0
    while i < len(packets):
        if isinstance(packets[i], GpsFix):
            out += engine.add(packets[i])
            i += 1
            continue
        j = i + 1
        while j < len(packets) and not isinstance(packets[j], GpsFix) and \
                (j not in cuts if cuts is not None else j - i < size):
            j += 1
        run, k = SampleRun.of(packets[i:j]), 0
        while k < len(run):
            k, estimates = engine.add_run(run, k)
            out += estimates
        i = j
    return out


def rows(estimates: list[FusedEstimate]) -> np.ndarray:
    return np.array([[e.t, e.x_m, e.y_m, e.heading_rad, e.speed_mps, e.yaw_rate_rps,
                      *e.position_cov_m2.ravel(), e.heading_sigma_rad, e.gps_bias_var_m2]
                     for e in estimates])


def assert_same(a: list[FusedEstimate], b: list[FusedEstimate], exact: bool) -> None:
    assert len(a) == len(b)
    decisions = [[(e.initialized, e.gps and (e.gps.used, e.gps.reason)) for e in x]
                 for x in (a, b)]
    assert decisions[0] == decisions[1]  # every fix used (or not) alike, for the same reason
    if exact:
        assert [e.gps for e in a] == [e.gps for e in b]
        assert np.array_equal(rows(a), rows(b), equal_nan=True)
    else:  # before start-up the heading is NaN and its sigma infinite, alike in both
        np.testing.assert_allclose(rows(a), rows(b), rtol=0.0, atol=TOLERANCE)


@pytest.mark.parametrize("sensors", ROAD, ids=lambda s: s.value)
def test_runs_give_the_per_packet_outputs_on_the_reference_drive(
        drive: list[dict[str, Any]], sample_graph: RoadGraph, sensors: SensorConfig) -> None:
    packets = packets_of(drive, sensors)
    config = FusionConfig(sensors=sensors)
    reference = FusionEngine(config, sample_graph.frame)
    fast = FusionEngine(config, sample_graph.frame)
    expected, got = per_packet(reference, packets), batched(fast, packets)
    assert len(expected) > 100  # a fix a second, and outputs through the outage
    assert_same(expected, got, exact=sensors in EXACT)
    a, b = reference.filter.state, fast.filter.state
    assert (a.t, a.still_samples, a.last_odo, a.odo_speed_mps, a.last_output_t,
            a.accel_fwd_mps2) == (b.t, b.still_samples, b.last_odo, b.odo_speed_mps,
                                  b.last_output_t, b.accel_fwd_mps2)


@pytest.mark.parametrize("sensors", [SensorConfig.GYRO_ODOMETER, SensorConfig.GYRO_ACCEL],
                         ids=lambda s: s.value)
@settings(max_examples=10)
@given(cuts=st.sets(st.integers(1, 6000), max_size=400))
def test_splitting_the_stream_into_any_runs_gives_the_same_outputs(
        drive: list[dict[str, Any]], sample_graph: RoadGraph, sensors: SensorConfig,
        cuts: set[int]) -> None:
    """Where the runs start and end changes nothing, bit for bit (one run per packet is the
    per-packet arithmetic through the kernel)."""
    packets = packets_of(drive, sensors)[:6000]
    config = FusionConfig(sensors=sensors)
    tens = batched(FusionEngine(config, sample_graph.frame), packets)
    cut = batched(FusionEngine(config, sample_graph.frame), packets, cuts=cuts)
    assert_same(tens, cut, exact=True)


@settings(max_examples=10)
@given(late=st.lists(st.tuples(st.integers(300, 5900), st.sampled_from([0.02, 0.11, 0.2])),
                     min_size=1, max_size=8, unique_by=lambda x: x[0]))
def test_a_late_packet_inside_a_run_is_replayed_to_the_in_order_state(
        drive: list[dict[str, Any]], sample_graph: RoadGraph,
        late: list[tuple[int, float]]) -> None:
    """Samples held back and sent after the runs that passed them: the window rolls back
    into (and splits) those runs and ends exactly where the in-order stream leaves it."""
    packets = packets_of(drive, SensorConfig.GYRO_ACCEL)[:6000]
    config = FusionConfig(sensors=SensorConfig.GYRO_ACCEL, reorder_window_s=0.25)
    in_order = FusionEngine(config, sample_graph.frame)
    batched(in_order, packets)
    held = {k: delay for k, delay in late if not isinstance(packets[k], GpsFix)}
    shuffled = FusionEngine(config, sample_graph.frame)
    pending: list[tuple[float, Packet]] = []
    stream = [p for k, p in enumerate(packets) if k not in held]
    for k in sorted(held):
        pending.append((packets[k].t + held[k], packets[k]))
    pending.sort(key=lambda item: item[0])
    i = 0
    for due, packet in pending:  # the samples up to its arrival in runs, then the late one
        j = i
        while j < len(stream) and stream[j].t <= due:
            j += 1
        batched(shuffled, stream[i:j])
        shuffled.add(packet)
        i = j
    batched(shuffled, stream[i:])
    assert shuffled.window.late_rejected == 0
    a, b = in_order.filter.state, shuffled.filter.state
    assert np.array_equal(a.x, b.x) and np.array_equal(a.P, b.P)
    assert a.t == b.t


@numba.njit
def _old_predict_with_gyro(x: np.ndarray, P: np.ndarray, dt_s: float, max_step_s: float,
                           densities: np.ndarray, rate_left: float, variance: float
                           ) -> tuple[np.ndarray, np.ndarray]:
    """The gyro step as written before the sparse products: the plain ``matmul`` chain."""
    remaining = dt_s
    while remaining > 1e-9:
        step = min(remaining, max_step_s)
        x, F, q = motion._propagate(x, step, math.nan, densities, math.nan)
        P = kalman.predict(P, F, q)
        remaining -= step
    rate, J = gyro_input(x, rate_left)
    A = np.eye(len(x))
    A[motion.HEADING_RATE, :] = J
    P_new = kalman.matmul(kalman.matmul(A, P), A.T)
    P_new[motion.HEADING_RATE, motion.HEADING_RATE] += \
        variance / (1.0 + x[motion.GYRO_SCALE]) ** 2
    x_new = x.copy()
    x_new[motion.HEADING_RATE] = rate
    return x_new, 0.5 * (P_new + P_new.T)


@settings(max_examples=200)
@given(seed=st.integers(0, 2**32 - 1), zeros=st.floats(0.0, 0.95), n=st.integers(1, 21),
       m=st.integers(1, 21))
def test_the_sparse_products_are_the_plain_ones_bit_for_bit(seed: int, zeros: float, n: int,
                                                            m: int) -> None:
    """``motion.matmul_transposed`` and ``symmetrised`` (the road filter's covariance steps)
    give exactly what ``kalman.matmul(A, B.T)`` and ``0.5 * (S + S.T)`` give."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, m)) * (rng.random((n, m)) > zeros)
    B = rng.normal(size=(n, m)) * (rng.random((n, m)) > zeros) * 10.0 ** rng.integers(-8, 8)
    assert np.array_equal(motion.matmul_transposed(A, B), kalman.matmul(A, B.T))
    S = rng.normal(size=(n, n))
    assert np.array_equal(motion.symmetrised(S.copy()), 0.5 * (S + S.T))
    F = np.eye(n) + rng.normal(size=(n, n)) * (rng.random((n, n)) > zeros)
    M = rng.normal(size=(n, n))
    q = rng.random(n)
    assert np.array_equal(motion._predict_covariance(M @ M.T, F, q),
                          kalman.predict(M @ M.T, F, q))


@settings(max_examples=100)
@given(seed=st.integers(0, 2**32 - 1), dt=st.floats(0.0, 0.35), rate=st.floats(-2.0, 2.0))
def test_the_gyro_step_is_the_plain_matmul_chain_bit_for_bit(seed: int, dt: float,
                                                             rate: float) -> None:
    rng = np.random.default_rng(seed)
    x = rng.normal(size=motion.N_STATES)
    M = rng.normal(size=(motion.N_STATES, motion.N_STATES))
    P = M @ M.T
    densities = motion.ProcessNoise().densities
    new = _predict_with_gyro(x, P, dt, 0.1, math.nan, densities, math.nan, rate, 2.5e-5)
    old = _old_predict_with_gyro(x, P, dt, 0.1, densities, rate, 2.5e-5)
    assert np.array_equal(new[0], old[0]) and np.array_equal(new[1], old[1])
