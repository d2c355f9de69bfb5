"""The simulator: the default drive pinned before the harsh errors were added, and each harsh
error doing what its field says (on the sample map, short drives, seeded)."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from navsvc.sim.simulate import DriveSpec, SensorErrors, simulate_drive
from roadgraph import EdgeKey, RoadGraph

PINNED = Path(__file__).resolve().parent / "data" / "default_drives.json"
PINNED_SPECS = {  # as pinned on 2026-12-01, before the harsh-urban options existed (the
    # steering records re-pinned on 2026-12-02, when slow corners got their steering angle,
    # and every record on 2026-12-02 again, when corners got a radius a car can drive; on
    # 2026-12-07 hashes of rounded records gave way to fingerprints compared to 1e-7, the
    # simulator unchanged since 2026-12-02)
    "all_sensors": DriveSpec(duration_s=40.0, seed=7, outages=((15.0, 6.0),)),
    "strapdown": DriveSpec(duration_s=20.0, seed=11, full_imu=True,
                           sensors=("imu", "odometer", "gps")),
}
QUIET_GPS = SensorErrors(gps_markov_sigma_m=0.0, gps_white_sigma_m=0.0,
                         gps_multipath_rate_per_s=0.0)  # fix = truth, unless told otherwise


def _close(value: Any, pinned: Any) -> bool:
    """Equal, floats to a relative 1e-7: the pin holds what the simulator computes, not the
    last bits of its libraries (numpy 2.4 moved a GPS course in its 17th digit, and the
    IMU's rates, derivatives of the map's geometry, further)."""
    if isinstance(value, float) or isinstance(pinned, float):
        return bool(np.isclose(value, pinned, rtol=1e-7, atol=1e-9))
    if isinstance(value, dict) and isinstance(pinned, dict):
        return value.keys() == pinned.keys() and all(_close(value[k], pinned[k]) for k in value)
    if isinstance(value, list | tuple) and isinstance(pinned, list | tuple):
        return len(value) == len(pinned) and all(map(_close, value, pinned))
    return bool(value == pinned)


def _fingerprint(records: list[dict[str, Any]]) -> dict[str, list[float]]:
    """Per numeric field of the records: count, sum, sum of squares, min and max."""
    fields = sorted({k for r in records for k, v in r.items()
                     if isinstance(v, int | float) and not isinstance(v, bool)})
    out = {}
    for name in fields:
        v = np.array([r[name] for r in records if r.get(name) is not None], dtype=float)
        out[name] = [float(len(v)), float(v.sum()), float((v ** 2).sum()), float(v.min()),
                     float(v.max())]
    return out


@pytest.mark.parametrize("name", sorted(PINNED_SPECS))
def test_default_simulation_unchanged(sample_graph: RoadGraph, name: str) -> None:
    pinned = json.loads(PINNED.read_text())[name]
    records = simulate_drive(sample_graph, PINNED_SPECS[name])
    assert _close([r for r in records if r["kind"] == "gps"], pinned["gps"])
    for kind, fingerprint in pinned["fingerprint"].items():
        assert _close(_fingerprint([r for r in records if r["kind"] == kind]), fingerprint), kind


def _local(graph: RoadGraph, records: list[dict[str, Any]]) -> np.ndarray:
    return graph.frame.coords_to_local(np.array([(r["lon"], r["lat"]) for r in records]))


def _gps_minus_truth(graph: RoadGraph, records: list[dict[str, Any]],
                     lag_s: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Fix times and fix minus truth ``lag_s`` earlier (truth at 10 Hz on the same grid)."""
    truth = {round(r["t"], 1): r for r in records if r["kind"] == "truth"}
    gps = [r for r in records if r["kind"] == "gps" and round(r["t"] - lag_s, 1) in truth]
    true = [truth[round(r["t"] - lag_s, 1)] for r in gps]
    return np.array([r["t"] for r in gps]), _local(graph, gps) - _local(graph, true)


def test_fix_describes_the_car_gps_latency_before_its_time(sample_graph: RoadGraph) -> None:
    spec = DriveSpec(duration_s=60.0, seed=3, tunnels_block_gps=False,
                     errors=replace(QUIET_GPS, gps_latency_s=0.1))
    records = simulate_drive(sample_graph, spec)
    _, lagged = _gps_minus_truth(sample_graph, records, lag_s=0.1)
    _, same_time = _gps_minus_truth(sample_graph, records)
    assert np.abs(lagged).max() < 1e-3
    assert np.hypot(*same_time.T).max() > 0.5  # moving: 0.1 s is a metre or so


def test_no_course_or_speed_below_the_threshold(sample_graph: RoadGraph) -> None:
    spec = DriveSpec(duration_s=90.0, seed=5, start_standstill_s=20.0,
                     errors=SensorErrors(gps_min_speed_for_course_mps=1.0,
                                         gps_course_sigma_1mps_deg=20.0))
    records = simulate_drive(sample_graph, spec)
    gps = [r for r in records if r["kind"] == "gps"]
    assert all(("speed_mps" in r) == ("heading_deg" in r) for r in gps)
    assert all(r["speed_mps"] >= 1.0 for r in gps if "speed_mps" in r)
    assert not any("speed_mps" in r for r in gps if r["t"] < 20.0)  # standing still
    assert any("speed_mps" in r for r in gps)


def test_course_noise_grows_as_speed_falls(sample_graph: RoadGraph) -> None:
    spec = DriveSpec(duration_s=600.0, seed=8, gps_rate_hz=5.0,
                     errors=SensorErrors(gps_heading_sigma_deg=1.0,
                                         gps_course_sigma_1mps_deg=20.0,
                                         gps_min_speed_for_course_mps=1.0))
    records = simulate_drive(sample_graph, spec)
    truth = {round(r["t"], 1): r for r in records if r["kind"] == "truth"}
    slow, fast = [], []
    for r in records:
        if r["kind"] == "gps" and "heading_deg" in r:
            true = truth[round(r["t"], 1)]
            err = (r["heading_deg"] - true["heading_deg"] + 180.0) % 360.0 - 180.0
            (slow if true["speed_mps"] < 3.0 else fast if true["speed_mps"] > 8.0
             else []).append(err)
    assert len(slow) > 20 and len(fast) > 20
    assert np.std(slow) > 7.0 and np.std(fast) < 4.0  # 1 + 20/v: >= 7.7 deg, <= 3.5 deg


def test_receiver_without_velocity_or_hdop(sample_graph: RoadGraph) -> None:
    spec = DriveSpec(duration_s=30.0, seed=2, gps_reports_velocity=False,
                     gps_reports_hdop=False)
    gps = [r for r in simulate_drive(sample_graph, spec) if r["kind"] == "gps"]
    assert gps and not any({"speed_mps", "heading_deg", "hdop"} & set(r) for r in gps)


def test_heights_err_more_than_positions_and_change_nothing_else(
        sample_graph: RoadGraph) -> None:
    """A receiver that sends a height: its error is 1.5 times the horizontal one, drawn from
    a stream of its own (every other record as without it)."""
    spec = DriveSpec(duration_s=300.0, seed=4, tunnels_block_gps=False)
    plain = simulate_drive(sample_graph, spec)
    with_height = simulate_drive(sample_graph, replace(spec, gps_reports_height=True))
    assert [{k: v for k, v in r.items() if k != "alt_m"} for r in with_height] == plain
    heights = np.array([r["alt_m"] for r in with_height if r["kind"] == "gps"])
    e = spec.errors
    expected = 1.5 * math.hypot(e.gps_markov_sigma_m, e.gps_white_sigma_m)
    assert 0.5 * expected < np.std(heights) < 1.5 * expected


def test_a_pitched_and_yawed_imu_sees_gravity_and_the_turns_turned(
        sample_graph: RoadGraph) -> None:
    """The 6-axis fields of an IMU mounted 4 degrees nose up and 2 left: at rest gravity
    reads forward by sin(4 degrees); the single yaw-rate gyro of the other configurations
    is not the 6-axis IMU and keeps its reading."""
    spec = DriveSpec(duration_s=60.0, seed=3, full_imu=True, start_standstill_s=5.0)
    level = [r for r in simulate_drive(sample_graph, spec) if r["kind"] == "imu"]
    mounted = [r for r in simulate_drive(sample_graph, replace(
        spec, errors=replace(spec.errors, imu_mount_deg=(4.0, 2.0)))) if r["kind"] == "imu"]
    assert [r["yaw_rate_dps"] for r in mounted] == [r["yaw_rate_dps"] for r in level]
    forward, _, up = mounted[0]["accel_mps2"]
    assert math.degrees(math.atan2(forward, up)) == pytest.approx(4.0, abs=0.5)
    for a, b in zip(level[::50], mounted[::50]):
        assert np.linalg.norm(a["gyro_dps"]) == pytest.approx(np.linalg.norm(b["gyro_dps"]))
        assert np.linalg.norm(a["accel_mps2"]) == pytest.approx(np.linalg.norm(b["accel_mps2"]))


def _runs(t: np.ndarray, err: np.ndarray) -> list[tuple[float, float, float]]:
    """(start, length in fix intervals, size) of each stretch of one constant non-zero bias."""
    runs: list[tuple[float, float, float]] = []
    start = None
    for i in range(len(t) + 1):
        same = i < len(t) and start is not None and np.abs(err[i] - err[start]).max() < 1e-3
        if start is not None and not same:
            runs.append((t[start], t[i - 1] - t[start] + 1.0, float(np.hypot(*err[start]))))
            start = None
        if i < len(t) and start is None and np.hypot(*err[i]) > 1e-3:
            start = i
    return runs


def test_nlos_runs_have_the_stated_size_and_duration(sample_graph: RoadGraph) -> None:
    spec = DriveSpec(duration_s=900.0, seed=4, tunnels_block_gps=False,
                     errors=replace(QUIET_GPS, gps_nlos_rate_per_s=1.0 / 40.0))
    t, err = _gps_minus_truth(sample_graph, simulate_drive(sample_graph, spec))
    runs = [r for r in _runs(t, err) if r[0] + r[1] < t[-1]]  # not cut off by the end
    assert len(runs) >= 5
    assert all(20.0 - 1e-3 <= size <= 80.0 + 1e-3 for _, _, size in runs)
    assert all(10.0 <= length <= 61.0 for _, length, _ in runs)
    assert len(t) > 0.9 * 900  # NLOS biases fixes; it does not drop them


def test_speed_only_odometer(sample_graph: RoadGraph) -> None:
    spec = DriveSpec(duration_s=60.0, seed=6, odometer_reports="speed", odometer_rate_hz=10.0,
                     start_standstill_s=10.0,
                     errors=SensorErrors(odometer_scale=0.05, odometer_speed_sigma_mps=0.0))
    records = simulate_drive(sample_graph, spec)
    odo = [r for r in records if r["kind"] == "odometer"]
    truth = {round(r["t"], 1): r["speed_mps"] for r in records if r["kind"] == "truth"}
    assert all(set(r) == {"t", "kind", "speed_mps"} for r in odo)
    assert len(odo) == pytest.approx(600, abs=2)
    moving = [(r["speed_mps"], truth[round(r["t"], 1)]) for r in odo
              if truth[round(r["t"], 1)] > 1.0]
    assert moving and all(math.isclose(v, 1.05 * true, rel_tol=0.02) for v, true in moving)
    assert all(r["speed_mps"] == 0.0 for r in odo if r["t"] < 10.0)


def test_gyro_turn_on_bias_at_standstill(sample_graph: RoadGraph) -> None:
    spec = DriveSpec(duration_s=15.0, seed=9, start_standstill_s=10.0,
                     errors=SensorErrors(gyro_turn_on_bias_dps=0.8, gyro_scale_error=0.03,
                                         gyro_noise_dps=0.0, gyro_bias_drift_dps_per_sqrt_s=0.0))
    imu = [r for r in simulate_drive(sample_graph, spec) if r["kind"] == "imu" and r["t"] < 9.0]
    assert imu and all(r["yaw_rate_dps"] == pytest.approx(0.8) for r in imu)


def _distance_to_own_road(graph: RoadGraph, records: list[dict[str, Any]]) -> np.ndarray:
    """Each truth record's signed distance from the centre line of the edge it is on (right
    of the direction of travel positive), away from the ends of its edge (corners)."""
    out = []
    truth = [r for r in records if r["kind"] == "truth" and r["speed_mps"] > 1.0]
    for r, (x, y) in zip(truth, _local(graph, truth), strict=True):
        key = next(k for k in graph.out_edges(r["u"]) if k.v == r["v"])
        edge = EdgeKey(key.u, key.v, key.key)
        p = graph.project(edge, x, y)
        if min(p.offset_m, p.remaining_m) < 15.0:
            continue
        right = (x - p.x_m) * math.cos(p.bearing_rad) - (y - p.y_m) * math.sin(p.bearing_rad)
        out.append((right, key.oneway))
    return np.array(out)


def test_the_car_keeps_its_lane_right_of_the_centre_line(sample_graph: RoadGraph) -> None:
    """Two-way roads ``lane_offset_m`` right of the centre line, one-way roads
    ``one_way_offset_m``; without them, on it (the map's line, which map feedback pulls to)."""
    spec = DriveSpec(duration_s=240.0, seed=12, lane_offset_m=2.5, one_way_offset_m=-1.0)
    lanes = _distance_to_own_road(sample_graph, simulate_drive(sample_graph, spec))
    centre = _distance_to_own_road(sample_graph, simulate_drive(
        sample_graph, replace(spec, lane_offset_m=0.0, one_way_offset_m=0.0)))
    two_way, one_way = lanes[lanes[:, 1] == 0, 0], lanes[lanes[:, 1] == 1, 0]
    assert len(two_way) > 100 and len(one_way) > 20
    assert np.median(two_way) == pytest.approx(2.5, abs=0.3)
    assert np.median(one_way) == pytest.approx(-1.0, abs=0.3)
    assert np.median(np.abs(centre[:, 0])) < 0.3


def test_impossible_options_refused() -> None:
    with pytest.raises(ValueError, match="odometer_reports must be 'distance' or 'speed', "
                                         "not 'ticks'"):
        DriveSpec(odometer_reports="ticks")
    with pytest.raises(ValueError, match="must be >= 0"):
        DriveSpec(start_standstill_s=-1.0)
