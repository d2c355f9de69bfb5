"""The harsh-urban profile: every draw within its stated range, for any seed; and drawn from
the seed alone (the same seed, the same profile)."""

from __future__ import annotations

from dataclasses import fields

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from navsvc.sim.harsh import RANGES, harsh_urban_errors, harsh_urban_spec
from navsvc.sim.simulate import DriveSpec

seeds = st.integers(min_value=0, max_value=2 ** 63 - 1)


def _within(value: float, bounds: tuple[float, ...]) -> bool:
    return bounds[0] <= value <= bounds[1]


@given(seeds)
def test_error_levels_within_their_ranges(seed: int) -> None:
    e = harsh_urban_spec(DriveSpec(seed=seed)).errors
    assert _within(e.gps_markov_sigma_m, RANGES.gps_markov_sigma_m)
    assert e.gps_markov_sigma_m <= 8.0 and e.gps_markov_tau_s <= 60.0
    assert _within(e.gps_markov_tau_s, RANGES.gps_markov_tau_s)
    assert _within(e.gps_white_sigma_m, RANGES.gps_white_sigma_m)
    assert _within(e.gps_nlos_rate_per_s, RANGES.gps_nlos_rate_per_s)
    assert e.gps_nlos_m == (20.0, 80.0) and e.gps_nlos_duration_s == (10.0, 60.0)
    assert _within(e.gps_heading_sigma_deg, RANGES.gps_heading_sigma_deg)
    assert _within(e.gps_course_sigma_1mps_deg, RANGES.gps_course_sigma_1mps_deg)
    assert e.gps_min_speed_for_course_mps == 1.0
    assert 0.1 <= e.gps_latency_s <= 0.2
    assert e.gyro_turn_on_bias_dps is not None and abs(e.gyro_turn_on_bias_dps) <= 1.0
    assert abs(e.gyro_scale_error) <= 0.03
    assert _within(e.gyro_noise_dps, RANGES.gyro_noise_dps)
    assert e.odometer_scale is not None and abs(e.odometer_scale) <= 0.05


@given(seeds)
def test_rates_receiver_and_odometer_within_their_ranges(seed: int) -> None:
    spec = harsh_urban_spec(DriveSpec(seed=seed))
    assert spec.gps_rate_hz in RANGES.gps_rate_hz and 1.0 <= spec.gps_rate_hz <= 10.0
    assert spec.odometer_rate_hz in RANGES.odometer_rate_hz
    assert 5.0 <= spec.odometer_rate_hz <= 50.0
    assert spec.odometer_reports in ("distance", "speed")
    assert _within(spec.start_standstill_s, RANGES.start_standstill_s)
    pitch, yaw = spec.errors.imu_mount_deg
    assert abs(pitch) <= 5.0 and abs(yaw) <= 3.0
    assert 1.0 <= spec.lane_offset_m <= 3.5 and abs(spec.one_way_offset_m) <= 2.0


@given(seeds)
def test_same_seed_same_profile_and_the_rest_of_the_spec_kept(seed: int) -> None:
    base = DriveSpec(seed=seed, duration_s=123.0, outages=((10.0, 60.0),))
    a, b = harsh_urban_spec(base), harsh_urban_spec(base)
    assert a == b
    assert (a.duration_s, a.outages, a.sensors) == (123.0, ((10.0, 60.0),), base.sensors)


def test_profiles_vary_between_seeds() -> None:
    specs = [harsh_urban_spec(DriveSpec(seed=s)) for s in range(200)]
    assert len({s.errors.gps_markov_sigma_m for s in specs}) == 200
    shares = {"speed": np.mean([s.odometer_reports == "speed" for s in specs]),
              "velocity": np.mean([s.gps_reports_velocity for s in specs]),
              "hdop": np.mean([s.gps_reports_hdop for s in specs]),
              "height": np.mean([s.gps_reports_height for s in specs])}
    assert 0.35 < shares["speed"] < 0.65 and 0.55 < shares["velocity"] < 0.85
    assert 0.55 < shares["hdop"] < 0.85 and 0.55 < shares["height"] < 0.85
    assert len({s.gps_rate_hz for s in specs}) == len(RANGES.gps_rate_hz)


def test_errors_alone_from_a_generator() -> None:
    e = harsh_urban_errors(np.random.default_rng(1))
    assert {f.name for f in fields(e)} >= {"gps_nlos_rate_per_s", "gps_latency_s"}
    assert e == harsh_urban_errors(np.random.default_rng(1))
