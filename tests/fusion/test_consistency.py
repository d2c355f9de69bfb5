"""Is the filter's uncertainty honest? (issue 15, part 2; the pyins manner: seeded drives
across a randomised range of error levels, normalised errors against their chi-square law.)

Each drive draws its own GPS white and correlated error, gyro turn-on bias and scale error,
odometer scale error and standstill at the start (no NLOS runs and no outages: those are
``bench/generalisation_eval.py``'s harsh profile). Pooled over the drives, the true position
error must lie inside the reported 2.45-sigma circle (the 95 % point of chi-square with 2
degrees of freedom) at 90 % of epochs or more, and the mean NEES per degree of freedom must
stay below 2: a filter may be cautious, never sure of a position it does not have.

Measured on the test's own drives (pooled; since the map-seen error scales the reported
covariance down as well as up): gyro + odometer 96.5 % inside (NEES per dof 0.64),
steering + odometer 93.1 % (0.94), gyro + accelerometer 98.6 % (0.54), two accelerometers
99.3 % (0.48), GPS alone 99.0 % (0.51), the strapdown INS 99.6 % (0.29): inside the issue's
90-98 % band for the first two, cautious for the rest.

The heading likewise: at speed (3 m/s and more, where a heading means something) the true
heading error lies inside 1.96 sigma (95 % of one degree of freedom) at 90 % of epochs or
more, with a mean NEES below 2. Measured: every road-filter configuration 99-100 % inside
(NEES 0.3-0.4); the strapdown INS 91.7 % (NEES 1.19), since it considers the fixes'
slowly changing error (GNSS bias states it does not estimate); before, taking the fixes'
error as white, 75 % (NEES 2.4).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, cast

import numpy as np
import pytest

from navsvc.fusion import FusionConfig, SensorConfig
from navsvc.session import SessionConfig, VehicleSession
from navsvc.sim.scorecard import CIRCLE_SIGMAS, consistency
from navsvc.sim.simulate import SENSOR_KINDS, DriveSpec, SensorErrors, simulate_drive
from navsvc.types import MatchedPosition
from navsvc.wire.positions import position_json
from roadgraph import RoadGraph

SEEDS = (1, 2, 3, 4)
DURATION_S = 120.0


def _errors(seed: int) -> tuple[SensorErrors, float]:
    rng = np.random.default_rng((seed, 77))
    errors = SensorErrors(
        gps_white_sigma_m=rng.uniform(1.0, 3.0), gps_markov_sigma_m=rng.uniform(0.5, 4.0),
        gps_markov_tau_s=rng.uniform(10.0, 60.0),
        gyro_turn_on_bias_dps=rng.uniform(-0.5, 0.5), gyro_scale_error=rng.uniform(-0.02, 0.02),
        odometer_scale=rng.uniform(-0.03, 0.03), gps_multipath_rate_per_s=0.0)
    return errors, rng.uniform(5.0, 15.0)


@pytest.fixture(scope="module")
def drives(sample_graph: RoadGraph) -> list[list[dict[str, object]]]:
    out = []
    for seed in SEEDS:
        errors, standstill_s = _errors(seed)
        out.append(simulate_drive(sample_graph, DriveSpec(
            duration_s=DURATION_S, seed=seed, errors=errors, start_standstill_s=standstill_s,
            tunnels_block_gps=False, full_imu=True)))
    return out


Runs = Callable[[SensorConfig], list[list[MatchedPosition]]]


@pytest.fixture(scope="module")
def runs(sample_graph: RoadGraph, drives: list[list[dict[str, object]]]) -> Runs:
    """Each drive's positions in a configuration, run once for both tests."""
    done: dict[SensorConfig, list[list[MatchedPosition]]] = {}

    def positions(sensors: SensorConfig) -> list[list[MatchedPosition]]:
        if sensors not in done:
            kinds = set(SENSOR_KINDS[sensors.value]) | {"truth"}
            done[sensors] = [
                VehicleSession(SessionConfig(FusionConfig(sensors=sensors)), sample_graph)
                .add_records([r for r in drive if r["kind"] in kinds]).positions
                for drive in drives]
        return done[sensors]
    return positions


@pytest.mark.parametrize("sensors", [
    SensorConfig.GYRO_ODOMETER, SensorConfig.GYRO_ACCEL, SensorConfig.GYRO_TWO_ACCELS,
    SensorConfig.GPS_ONLY, SensorConfig.STEERING_ODOMETER, SensorConfig.STRAPDOWN])
def test_the_reported_position_sigma_is_never_overconfident(
        sensors: SensorConfig, sample_graph: RoadGraph,
        drives: list[list[dict[str, object]]], runs: Runs) -> None:
    inside, nees = [], []
    for drive, positions in zip(drives, runs(sensors)):
        share, mean_nees, _ = consistency(
            drive, [position_json(p, sample_graph.frame) for p in positions])
        assert share is not None and mean_nees is not None
        inside.append(share)
        nees.append(mean_nees)
    assert float(np.mean(inside)) >= 0.90, (CIRCLE_SIGMAS, inside)
    assert float(np.mean(nees)) <= 2.0, nees


HEADING_SIGMAS = 1.96  # the 95 % point of one degree of freedom
HEADING_MIN_SPEED_MPS = 3.0


@pytest.mark.parametrize("sensors", [
    SensorConfig.GYRO_ODOMETER, SensorConfig.GYRO_ACCEL, SensorConfig.GYRO_TWO_ACCELS,
    SensorConfig.GPS_ONLY, SensorConfig.STEERING_ODOMETER, SensorConfig.STRAPDOWN])
def test_the_reported_heading_sigma_is_never_overconfident(
        sensors: SensorConfig, drives: list[list[dict[str, object]]], runs: Runs) -> None:
    normalised: list[float] = []
    for drive, positions in zip(drives, runs(sensors)):
        truth: list[dict[str, Any]] = sorted(
            (r for r in drive if r["kind"] == "truth"), key=lambda r: cast(float, r["t"]))
        t = np.array([r["t"] for r in truth])
        heading = np.unwrap(np.radians([r["heading_deg"] for r in truth]))
        speed = np.array([r["speed_mps"] for r in truth])
        for p in positions:
            e = p.estimate
            if e.heading_sigma_rad > 0.0 and np.interp(e.t, t, speed) >= HEADING_MIN_SPEED_MPS:
                error = math.remainder(e.heading_rad - float(np.interp(e.t, t, heading)),
                                       2.0 * math.pi)
                normalised.append(error / e.heading_sigma_rad)
    z = np.array(normalised)
    assert len(z) > 100
    inside, nees = float(np.mean(np.abs(z) <= HEADING_SIGMAS)), float(np.mean(z ** 2))
    assert inside >= 0.90, (inside, nees)
    assert nees <= 2.0, (inside, nees)
