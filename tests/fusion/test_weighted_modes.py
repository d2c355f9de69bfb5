"""The thesis's ``rules`` and ``fuzzy`` GPS modes never diverge (issue 15, section 3).

Seeded harsh-urban drives (``navsvc.sim.harsh``: each draws its own error levels, gyro
turn-on bias up to 1 deg/s, odometer scale error up to 5 %, non-line-of-sight runs of 20-80 m,
receivers with or without course/speed/HDOP, a standstill at the start), each with a 30 s GPS
outage, for every dead-reckoning sensor configuration in both modes. Wherever a fix came in the
second before, and GPS has been back for ``SETTLE_S`` since its last gap (the modes may need a
few seconds to notice that the estimate drifted in the gap), the fused position must lie within
``MAX_ERROR_M`` of the truth.

Before the modes calibrated the sensor errors and guarded against divergence (navsvc commit
07a9249), 6 of the 8 failed; each configuration's worst error over these drives, rules / fuzzy:
gyro_odometer 85 / 68 m, steering_odometer 410 / 325 m, gyro_accel 621 / 143 m, gyro_two_accels
113 / 67 m. Now: 36 / 48, 37 / 70, 68 / 69 and 34 / 48 m (the largest: a 66 m
non-line-of-sight run, restarted onto once dead reckoning's own uncertainty covered it, and
runs within the thesis's 50 m distance threshold, which the weighted sums blend).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from navsvc.fusion import FusionConfig, GpsMode, SensorConfig
from navsvc.session import SessionConfig, VehicleSession
from navsvc.sim.harsh import harsh_urban_spec
from navsvc.sim.simulate import SENSOR_KINDS, DriveSpec, simulate_drive
from navsvc.wire.positions import position_json
from roadgraph import LocalFrame, RoadGraph

SEEDS = (1, 2, 3, 4)
DURATION_S = 150.0
OUTAGE = (60.0, 30.0)  # start, length (s)
SETTLE_S = 10.0  # GPS back this long since its last gap (no fix for GAP_S) ...
GAP_S = 2.0
MAX_ERROR_M = 80.0  # ... and the estimate is this close to the truth


@pytest.fixture(scope="module")
def drives(sample_graph: RoadGraph) -> list[list[dict[str, Any]]]:
    return [simulate_drive(sample_graph, harsh_urban_spec(DriveSpec(
        duration_s=DURATION_S, seed=seed, outages=(OUTAGE,), full_imu=True)))
        for seed in SEEDS]


def fused_errors(drive: list[dict[str, Any]], estimates: list[dict[str, Any]]
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Times and fused-position errors (m) of the estimates, against the interpolated truth."""
    truth = sorted((r for r in drive if r["kind"] == "truth"), key=lambda r: r["t"])
    frame = LocalFrame.for_point(truth[0]["lon"], truth[0]["lat"])
    tt = np.array([r["t"] for r in truth], dtype=float)
    xy = frame.coords_to_local(np.array([(r["lon"], r["lat"]) for r in truth], dtype=float))
    within = [e for e in estimates if tt[0] <= e["t"] <= tt[-1]]
    t = np.array([e["t"] for e in within], dtype=float)
    est = frame.coords_to_local(np.array([(e["fused_lon"], e["fused_lat"]) for e in within],
                                         dtype=float))
    true = np.column_stack([np.interp(t, tt, xy[:, 0]), np.interp(t, tt, xy[:, 1])])
    return t, np.hypot(*(est - true).T)


def settled_errors_m(drive: list[dict[str, Any]],
                     estimates: list[dict[str, Any]]) -> np.ndarray:
    """Fused-position errors at the epochs with a fix in the second before, once GPS has been
    back ``SETTLE_S`` since its last gap (and since the first fix)."""
    t, err = fused_errors(drive, estimates)
    gps_t = np.sort([float(r["t"]) for r in drive if r["kind"] == "gps"])
    last = np.searchsorted(gps_t, t, side="right") - 1
    with_gps = (last >= 0) & (t - gps_t[np.maximum(last, 0)] < 1.0)
    run_start = np.full(len(t), gps_t[0])
    for i in np.where(np.diff(gps_t) > GAP_S)[0]:
        run_start[t >= gps_t[i + 1]] = gps_t[i + 1]
    settled: np.ndarray = err[with_gps & (t - run_start >= SETTLE_S)]
    return settled


@pytest.mark.parametrize("mode", [GpsMode.RULES, GpsMode.FUZZY])
@pytest.mark.parametrize("sensors", [
    SensorConfig.GYRO_ODOMETER, SensorConfig.STEERING_ODOMETER, SensorConfig.GYRO_ACCEL,
    SensorConfig.GYRO_TWO_ACCELS])
def test_the_weighted_modes_never_diverge_while_gps_is_there(
        sensors: SensorConfig, mode: GpsMode, sample_graph: RoadGraph,
        drives: list[list[dict[str, Any]]]) -> None:
    worst = []
    for drive in drives:
        kinds = set(SENSOR_KINDS[sensors.value]) | {"truth"}
        session = VehicleSession(SessionConfig(FusionConfig(sensors=sensors, gps_mode=mode)),
                                 sample_graph)
        result = session.add_records([r for r in drive if r["kind"] in kinds])
        errors = settled_errors_m(
            drive, [position_json(p, sample_graph.frame) for p in result.positions])
        assert len(errors) > 0
        worst.append(round(float(errors.max()), 1))
    assert max(worst) <= MAX_ERROR_M, worst
