"""The harsh-urban profile: sensor error levels drawn per drive, as bad as real roads get.

Our default simulation is kinder than the road (issue 15: the fusion met its targets on it and
did worse than raw GPS on data it had never seen). This profile draws, from each drive's seed,
the levels seen on real urban drives and in consumer hardware:

* GPS: correlated error (Gauss-Markov) sigma up to 8 m with a time constant up to 60 s;
  non-line-of-sight runs (a 20-80 m bias for 10-60 s) that the HDOP does not show; course
  noise growing as speed falls and no course or speed below 1 m/s; fixes at 1-10 Hz, 0.1-0.2 s
  late; on some drives a receiver that sends no course and speed, or no HDOP, and most send a
  height, 1.5 times as wrong as the position (UrbanNav, Hsu et al. 2021; u-blox M8 data sheet
  for latency and course accuracy).
* gyro: turn-on bias up to 1 deg/s and scale factor error up to 3 % (MEMS automotive grade).
* a 6-axis IMU not squared to the car: pitched up to 5 degrees, yawed up to 3 (comma2k19's
  phone: 3.8 and 0.8).
* odometer: scale error up to 5 % (tyre wear and pressure); on some drives a wheel-speed
  sensor sending speed only, at 5-50 Hz.
* the car stands still for a while before it drives off.
* the car drives in its lane, not on the road's centre line that the map holds: 1-3.5 m right
  of a two-way road's, up to 2 m either side of a one-way road's (map feedback that pulls the
  estimate onto the centre line is then held to the error it really has).

Every range is a constant of :data:`RANGES`, so that a test can hold the draws to them.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from navsvc.sim.simulate import HARSH_STREAM, DriveSpec, SensorErrors


@dataclass(frozen=True)
class HarshUrbanRanges:
    """What the profile draws from: (low, high) uniform, or a set of choices."""

    gps_markov_sigma_m: tuple[float, float] = (1.0, 8.0)
    gps_markov_tau_s: tuple[float, float] = (5.0, 60.0)
    gps_white_sigma_m: tuple[float, float] = (1.0, 3.0)
    gps_nlos_rate_per_s: tuple[float, float] = (1.0 / 600.0, 1.0 / 120.0)  # one run per 2-10 min
    gps_nlos_m: tuple[float, float] = (20.0, 80.0)
    gps_nlos_duration_s: tuple[float, float] = (10.0, 60.0)
    gps_heading_sigma_deg: tuple[float, float] = (1.0, 3.0)  # when fast
    gps_course_sigma_1mps_deg: tuple[float, float] = (10.0, 30.0)  # sigma at 1 m/s on top
    gps_min_speed_for_course_mps: float = 1.0
    gps_latency_s: tuple[float, float] = (0.1, 0.2)
    gps_rate_hz: tuple[float, ...] = (1.0, 2.0, 5.0, 10.0)  # divisors of the 100 Hz IMU
    gps_velocity_share: float = 0.7  # of receivers that send course and speed
    gps_hdop_share: float = 0.7  # of receivers that send HDOP
    gps_height_share: float = 0.7  # of receivers that send a height
    gyro_turn_on_bias_dps: tuple[float, float] = (-1.0, 1.0)
    gyro_scale_error: tuple[float, float] = (-0.03, 0.03)
    gyro_noise_dps: tuple[float, float] = (0.05, 0.3)
    odometer_scale: tuple[float, float] = (-0.05, 0.05)
    odometer_rate_hz: tuple[float, ...] = (5.0, 10.0, 20.0, 25.0, 50.0)
    odometer_speed_only_share: float = 0.5
    start_standstill_s: tuple[float, float] = (5.0, 30.0)
    imu_mount_pitch_deg: tuple[float, float] = (-5.0, 5.0)  # a 6-axis IMU not squared to the
    imu_mount_yaw_deg: tuple[float, float] = (-3.0, 3.0)  # car (comma2k19's phone: 3.8, 0.8)
    lane_offset_m: tuple[float, float] = (1.0, 3.5)  # right of a two-way road's centre line:
    # the middle of its right lane, on roads of two to four lanes of 2.5-3.5 m
    one_way_offset_m: tuple[float, float] = (-2.0, 2.0)  # any lane of a one-way road


RANGES = HarshUrbanRanges()


def _uniform(rng: np.random.Generator, bounds: tuple[float, float]) -> float:
    return float(rng.uniform(*bounds))


def harsh_urban_errors(rng: np.random.Generator,
                       ranges: HarshUrbanRanges = RANGES) -> SensorErrors:
    """One drive's sensor error levels."""
    return SensorErrors(
        gps_markov_sigma_m=_uniform(rng, ranges.gps_markov_sigma_m),
        gps_markov_tau_s=_uniform(rng, ranges.gps_markov_tau_s),
        gps_white_sigma_m=_uniform(rng, ranges.gps_white_sigma_m),
        gps_nlos_rate_per_s=_uniform(rng, ranges.gps_nlos_rate_per_s),
        gps_nlos_m=ranges.gps_nlos_m, gps_nlos_duration_s=ranges.gps_nlos_duration_s,
        gps_heading_sigma_deg=_uniform(rng, ranges.gps_heading_sigma_deg),
        gps_course_sigma_1mps_deg=_uniform(rng, ranges.gps_course_sigma_1mps_deg),
        gps_min_speed_for_course_mps=ranges.gps_min_speed_for_course_mps,
        gps_latency_s=_uniform(rng, ranges.gps_latency_s),
        gyro_turn_on_bias_dps=_uniform(rng, ranges.gyro_turn_on_bias_dps),
        gyro_scale_error=_uniform(rng, ranges.gyro_scale_error),
        gyro_noise_dps=_uniform(rng, ranges.gyro_noise_dps),
        odometer_scale=_uniform(rng, ranges.odometer_scale))


def harsh_urban_spec(spec: DriveSpec, ranges: HarshUrbanRanges = RANGES) -> DriveSpec:
    """``spec`` with the harsh-urban profile drawn from its seed (errors, rates, receiver and
    odometer kind, standstill at the start); everything else of ``spec`` is kept."""
    rng = np.random.default_rng((spec.seed, HARSH_STREAM, 1))
    errors = harsh_urban_errors(rng, ranges)
    out = replace(
        spec, errors=errors,
        gps_rate_hz=float(rng.choice(ranges.gps_rate_hz)),
        odometer_rate_hz=float(rng.choice(ranges.odometer_rate_hz)),
        odometer_reports="speed" if rng.random() < ranges.odometer_speed_only_share
        else "distance",
        gps_reports_velocity=bool(rng.random() < ranges.gps_velocity_share),
        gps_reports_hdop=bool(rng.random() < ranges.gps_hdop_share),
        start_standstill_s=_uniform(rng, ranges.start_standstill_s),
        lane_offset_m=_uniform(rng, ranges.lane_offset_m),
        one_way_offset_m=_uniform(rng, ranges.one_way_offset_m))
    # drawn last, so that every earlier draw is as it was before these were added (only a
    # 6-axis IMU sees the mount, only the INS reads a height)
    mount = (_uniform(rng, ranges.imu_mount_pitch_deg), _uniform(rng, ranges.imu_mount_yaw_deg))
    return replace(out, errors=replace(errors, imu_mount_deg=mount),
                   gps_reports_height=bool(rng.random() < ranges.gps_height_share))
