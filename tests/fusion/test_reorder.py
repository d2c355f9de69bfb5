"""The reorder window over both filters: late packets give exactly the in-order result, and
an engine pickled mid-drive carries on as if it had not been."""

from __future__ import annotations

import pickle
from collections import deque
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from navsvc.errors import PacketError
from navsvc.fusion import PROFILES, FusionConfig, FusionEngine, SensorConfig
from navsvc.sim.simulate import SENSOR_KINDS, DriveSpec, simulate_drive
from navsvc.types import FusedEstimate, ImuSample
from navsvc.wire.packets import parse
from roadgraph import RoadGraph

BOTH = [SensorConfig.GYRO_ODOMETER, SensorConfig.STRAPDOWN]


@pytest.fixture(scope="module")
def drives(sample_graph: RoadGraph) -> dict[SensorConfig, list[dict[str, Any]]]:
    records = simulate_drive(sample_graph, DriveSpec(duration_s=40.0, seed=4, full_imu=True,
                                                     tunnels_block_gps=False))
    return {s: [r for r in records if r["kind"] in PROFILES[s].packets] for s in BOTH}


def same(a: object, b: object) -> bool:
    """Equal values all the way down (arrays element by element, NaN equal to NaN)."""
    if isinstance(a, np.ndarray):
        return isinstance(b, np.ndarray) and np.array_equal(a, b, equal_nan=True)
    if isinstance(a, (list, tuple, deque)):
        return type(a) is type(b) and len(a) == len(b) and all(
            same(x, y) for x, y in zip(a, b))
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if hasattr(a, "__dict__") and not isinstance(a, type):
        return type(a) is type(b) and same(vars(a), vars(b))
    return a == b


def rows(estimates: list[FusedEstimate]) -> list[tuple[object, ...]]:
    return [(e.t, e.x_m, e.y_m, e.heading_rad, e.speed_mps, e.yaw_rate_rps,
             e.position_cov_m2.tobytes(), e.heading_sigma_rad, e.initialized, e.gps)
            for e in estimates]


@pytest.mark.parametrize("sensors", BOTH, ids=lambda s: s.value)
@settings(max_examples=12, deadline=None)
@given(delays=st.lists(st.sampled_from([0.0, 0.0, 0.0, 0.03, 0.11, 0.2]), min_size=50,
                       max_size=50))
def test_packets_up_to_the_window_late_give_exactly_the_in_order_state(
        drives: dict[SensorConfig, list[dict[str, Any]]], sample_graph: RoadGraph,
        sensors: SensorConfig, delays: list[float]) -> None:
    """Each packet arrives up to 0.2 s late (the window is 0.25 s): rolled back and replayed,
    the filter ends exactly where the packets in time order leave it (a late packet goes
    after those of the same time that came before it)."""
    drive = drives[sensors]
    config = FusionConfig(sensors=sensors, reorder_window_s=0.25)
    in_order = FusionEngine(config, sample_graph.frame)
    shuffled = FusionEngine(config, sample_graph.frame)
    arrival = sorted(range(len(drive)),  # the first packet on time: nothing precedes it
                     key=lambda k: float(drive[k]["t"]) + (k > 0) * delays[k % 50])
    for k in sorted(arrival, key=lambda k: float(drive[k]["t"])):
        in_order.add(parse(drive[k]))
    for k in arrival:
        shuffled.add(parse(drive[k]))
    assert shuffled.window.late_rejected == 0
    assert in_order.estimate() is not None
    assert same(shuffled.filter.snapshot(), in_order.filter.snapshot())
    assert rows([shuffled.estimate()]) == rows([in_order.estimate()])  # type: ignore[list-item]


@pytest.mark.parametrize("sensors", BOTH, ids=lambda s: s.value)
def test_older_packets_are_refused_and_a_refused_late_one_changes_nothing(
        drives: dict[SensorConfig, list[dict[str, Any]]], sensors: SensorConfig) -> None:
    engine = FusionEngine(FusionConfig(sensors=sensors, reorder_window_s=0.25))
    for record in drives[sensors][:3000]:
        engine.add(parse(record))
    t = engine.t
    assert t is not None
    before = engine.filter.snapshot()
    with pytest.raises(PacketError, match="before the latest packet"):
        engine.add(ImuSample(t=t - 0.5, yaw_rate_rps=0.0))
    assert engine.window.late_rejected == 1
    if sensors == SensorConfig.STRAPDOWN:  # late, and refused by the filter itself
        with pytest.raises(PacketError, match="6-axis"):
            engine.add(ImuSample(t=t - 0.1, yaw_rate_rps=0.0))
    assert same(engine.filter.snapshot(), before)


@pytest.mark.parametrize("sensors", BOTH, ids=lambda s: s.value)
def test_an_engine_pickled_mid_drive_carries_on_exactly(
        drives: dict[SensorConfig, list[dict[str, Any]]], sample_graph: RoadGraph,
        sensors: SensorConfig) -> None:
    packets = [parse(r) for r in drives[sensors]]
    half = len(packets) // 2
    straight = FusionEngine(FusionConfig(sensors=sensors), sample_graph.frame)
    resumed = FusionEngine(FusionConfig(sensors=sensors), sample_graph.frame)
    for p in packets[:half]:
        straight.add(p)
        resumed.add(p)
    assert straight.estimate() is not None
    resumed = pickle.loads(pickle.dumps(resumed))
    out_straight = [e for p in packets[half:] for e in straight.add(p)]
    out_resumed = [e for p in packets[half:] for e in resumed.add(p)]
    assert len(out_straight) > 10
    assert rows(out_resumed) == rows(out_straight)


def test_the_profiles_name_the_packets_the_simulator_sends() -> None:
    for sensors, profile in PROFILES.items():
        assert profile.packets == set(SENSOR_KINDS[sensors.value])
