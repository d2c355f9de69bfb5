"""Strapdown INS/GNSS: closed-form cases, random input, and a real drive against RTK."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from navsvc.errors import TraceError
from navsvc.fusion.ins import (
    EARTH_RATE_RPS,
    BodyVelocity,
    GnssFix,
    GnssPosition,
    GnssVelocity,
    ImuNoise,
    Integration,
    Mechanisation,
    NavState,
    Rest,
    dcm_to_euler,
    euler_to_dcm,
    ins_filter,
    level_from_accel,
    normal_gravity_mps2,
    radii_m,
    replay,
)
from navsvc.fusion.ins.error_state import ATT, N_ERR, corrected
from navsvc.wire.kfgins import gnss_fixes, read_gnss, read_imu, read_profile
from tests.conftest import DATA

DRIVE = DATA / "drive0708"
LAT = math.radians(45.0)
NOISE = ImuNoise.from_kfgins(0.6, 0.4, 50.0, 2000.0, 1.0)
P0 = np.diag(np.concatenate([[1.0] * 3, [0.1] * 3, [0.01] * 3, [1e-4] * 3, [0.05] * 3,
                             [1e-3] * 6]) ** 2)


def at_rest(t: float = 0.0) -> NavState:
    return NavState(t, LAT, 0.0, 100.0, np.zeros(3), np.eye(3))


def resting_increments(dt: float) -> tuple[np.ndarray, np.ndarray]:
    """What a perfect IMU, level and facing north, reads at rest over dt."""
    w_ie = EARTH_RATE_RPS * np.array([math.cos(LAT), 0.0, -math.sin(LAT)])
    return w_ie * dt, np.array([0.0, 0.0, -normal_gravity_mps2(LAT, 100.0)]) * dt


@pytest.mark.parametrize("integration", list(Integration))
@pytest.mark.parametrize("mech", list(Mechanisation))
def test_a_perfect_imu_at_rest_stays_put(mech: Mechanisation, integration: Integration) -> None:
    ins = ins_filter(at_rest(), P0, NOISE, None, integration, mech)
    dtheta, dvel = resting_increments(0.01)
    for k in range(1, 6001):  # 60 s at 100 Hz
        ins.predict(0.01 * k, dtheta, dvel)
    s = ins.state
    rm, _ = radii_m(LAT)
    assert abs(s.lat_rad - LAT) * rm < 0.05 and abs(s.h_m - 100.0) < 0.05
    assert np.abs(s.v_ned).max() < 2e-3
    assert np.allclose(s.c_bn, np.eye(3), atol=1e-5)


@pytest.mark.parametrize("integration", list(Integration))
def test_gnss_pulls_a_wrong_start_onto_the_truth(integration: Integration) -> None:
    start = at_rest()
    start.lat_rad += 10.0 / radii_m(LAT)[0]  # 10 m north of the truth
    ins = ins_filter(start, np.diag(np.r_[[10.0] * 3, [0.1] * 3, [0.01] * 3, [1e-4] * 3,
                                          [0.05] * 3, [1e-3] * 6] ** 2), NOISE, None,
                     integration)
    dtheta, dvel = resting_increments(0.01)
    imu = np.array([[0.01 * k, *dtheta, *dvel] for k in range(1, 3001)])
    fixes = [GnssFix(float(t), LAT, 0.0, 100.0, np.array([0.5, 0.5, 1.0]))
             for t in range(1, 31)]
    track = replay(ins, imu, fixes)
    assert abs(track[-1, 1] - LAT) * radii_m(LAT)[0] < 0.3


def test_euler_round_trip_and_levelling() -> None:
    roll, pitch, yaw = 0.1, -0.2, 5.0
    got = dcm_to_euler(euler_to_dcm(roll, pitch, yaw))
    assert np.allclose(got, (roll, pitch, yaw), atol=1e-12)
    c = euler_to_dcm(roll, pitch, 0.0)
    f_b = c.T @ np.array([0.0, 0.0, -9.8])  # specific force at rest, in the body frame
    assert np.allclose(level_from_accel(f_b), (roll, pitch), atol=1e-12)


@pytest.mark.parametrize("integration", list(Integration))
def test_bad_samples_are_refused_and_change_nothing(integration: Integration) -> None:
    ins = ins_filter(at_rest(), P0, NOISE, None, integration)
    before = (ins.state.copy(), ins.P.copy())
    dtheta, dvel = resting_increments(0.01)
    with pytest.raises(ValueError, match="not finite"):
        ins.predict(0.01, np.array([math.nan, 0.0, 0.0]), dvel)
    with pytest.raises(ValueError, match="saturated"):
        ins.predict(0.01, np.array([1.0, 0.0, 0.0]), dvel)  # 100 rad/s
    with pytest.raises(ValueError, match="must increase"):
        ins.predict(0.0, dtheta, dvel)
    with pytest.raises(ValueError, match="standard deviations"):
        ins.update(GnssPosition(GnssFix(0.0, LAT, 0.0, 100.0, np.array([0.0, 1.0, 1.0]))))
    assert ins.state.lat_rad == before[0].lat_rad and np.array_equal(ins.P, before[1])


@settings(max_examples=40, deadline=None)
@given(
    steps=st.lists(st.tuples(
        st.floats(0.001, 2.0),  # dt, gaps included
        st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3),  # rad/s
        st.lists(st.floats(-30.0, 30.0), min_size=3, max_size=3),  # m/s²
        st.one_of(st.none(), st.tuples(st.floats(-50.0, 50.0), st.floats(-50.0, 50.0),
                                       st.floats(1e-3, 1e4)))),  # fix offset N, E (m), sigma
        min_size=1, max_size=40),
    integration=st.sampled_from(list(Integration)),
    mech=st.sampled_from(list(Mechanisation)))
def test_covariance_stays_symmetric_positive_definite(steps: list, integration: Integration,
                                                      mech: Mechanisation) -> None:
    ins = ins_filter(at_rest(), P0, NOISE, np.array([0.5, 0.0, -1.0]), integration, mech,
                     gps_bias_sigma_m=2.0, gps_latency_sigma_s=0.1, mount_sigma_rad=0.05)
    t = 0.0
    for dt, rate, accel, fix in steps:
        t += dt
        ins.predict(t, np.array(rate) * dt, np.array(accel) * dt)
        if fix is not None:
            north, east, sigma = fix
            rm, rn = radii_m(LAT)
            ins.update(GnssPosition(GnssFix(t, LAT + north / rm, east / (rn * math.cos(LAT)),
                                            100.0, np.array([sigma, sigma, 2 * sigma]))))
            ins.update(GnssVelocity(np.array([north, east, 0.0]) / 10.0, (0, 1), 0.5))
            ins.update(BodyVelocity(np.array([abs(east), 0.0, 0.0]), (0, 1, 2),
                                    np.full(3, 0.2)))
            ins.update(Rest(np.array(rate), 0.01, 0.1))
        assert np.allclose(ins.P, ins.P.T)
        # positive definite, tested on the correlations: the direct filter holds position in
        # radians, which puts 16 orders of magnitude between P's diagonal entries
        sigma = np.sqrt(np.diag(ins.P))
        assert np.all(sigma > 0.0)
        assert np.linalg.eigvalsh(ins.P / np.outer(sigma, sigma)).min() > 0.0
        assert math.isfinite(ins.output().lat_rad)


@pytest.mark.parametrize("integration", list(Integration))
def test_real_drive_with_1hz_rtk_matches_the_withheld_epochs(integration: Integration) -> None:
    """rtklibexplorer drive 0708, first 90 s (30 s still, then driving): 1 Hz RTK in, the
    other 3 of every 4 RTK epochs withheld and scored, as bench/ins_eval.py does; each
    integration."""
    profile = read_profile(DRIVE / "kfgins_profileA.yaml")
    imu = read_imu(DRIVE / "imu_kfgins_90s.txt.gz")
    gnss = read_gnss(DRIVE / "gnss_4hz_90s.txt.gz")
    one_hz = np.isclose((gnss[:, 0] - 0.499) % 1.0, 0.0, atol=1e-3)
    track = replay(profile.filter(integration), imu, gnss_fixes(gnss[one_hz]))
    check = gnss[~one_hz & (gnss[:, 0] > profile.start_t + 1.0) & (gnss[:, 0] < imu[-1, 0])]
    lat = np.interp(check[:, 0], track[:, 0], track[:, 1])
    lon = np.interp(check[:, 0], track[:, 0], track[:, 2])
    rm, rn = radii_m(float(lat[0]))
    north = (lat - np.radians(check[:, 1])) * rm
    east = (lon - np.radians(check[:, 2])) * rn * np.cos(lat)
    rms = float(np.sqrt(np.mean(north**2 + east**2)))
    assert rms < 0.15  # KF-GINS scores 0.082 m over the whole drive
    moving = np.hypot(*np.diff(check[:, 1:3], axis=0).T).max()
    assert moving > 1e-5  # the window really includes driving


def test_kfgins_readers_name_the_bad_line(tmp_path: Path) -> None:
    bad = tmp_path / "imu.txt"
    bad.write_text("1.0 0 0 0 0 0 0\n2.0 0 0 x 0 0 0\n")
    with pytest.raises(TraceError, match=r"imu.txt:2: not a number"):
        read_imu(bad)
    bad.write_text("1.0 0 0 0 0 0 0\n0.5 0 0 0 0 0 0\n")
    with pytest.raises(TraceError, match="time does not increase at record 2"):
        read_imu(bad)
    gnss = tmp_path / "gnss.txt"
    gnss.write_text("1.0 40 -105 1600 0.01 0 0.01\n")
    with pytest.raises(TraceError, match="record 1: standard deviations must be > 0"):
        read_gnss(gnss)
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text("starttime: 1\n")
    with pytest.raises(TraceError, match="missing setting"):
        read_profile(cfg)


@pytest.mark.parametrize("integration", list(Integration))
def test_fixes_that_err_alike_do_not_average_away(integration: Integration) -> None:
    """The fixes' slowly changing error is considered, not estimated: thirty seconds of
    10 Hz fixes, each with 0.5 m of white error on top of a 3 m bias of 30 s, leave the
    position about as unsure as the bias (taken as white, three hundred fixes made it sure
    to 3 cm), and no update moves the bias off its prior."""
    ins = ins_filter(at_rest(), P0, NOISE, None, integration, gps_bias_sigma_m=3.0,
                     gps_bias_tau_s=30.0)
    dtheta, dvel = resting_increments(0.01)
    imu = np.array([[0.01 * k, *dtheta, *dvel] for k in range(1, 3001)])
    fixes = [GnssFix(0.1 * k, LAT, 0.0, 100.0, np.array([0.5, 0.5, 1.0]))
             for k in range(1, 301)]
    replay(ins, imu, fixes)
    north_east_sigma_m = np.sqrt(np.diag(ins.position_cov_ned_m2())[:2])
    assert np.all(north_east_sigma_m > 2.0), north_east_sigma_m
    assert np.all(ins.state.gps_bias_ne_m == 0.0)


def test_an_attitude_correction_is_a_rotation() -> None:
    """The feedback takes the attitude error off as a rotation (Rodrigues), not as the
    first-order ``I - [phi x]``, which is no rotation (it stretches by about
    ``sqrt(1 + phi^2)``): after a heading corrected by 16 degrees just after alignment, the
    INS's velocity in its body axes was 3 % longer than in north-east-down from then on, so
    with the wheels' 8.5 m/s along the body the INS ran at 8.3 (Andorra 17 of the tune split)."""
    s = NavState(0.0, 0.76, 0.13, 100.0, np.array([8.5, 0.0, 0.0]),
                 euler_to_dcm(0.01, -0.06, 1.9))
    dx = np.zeros(N_ERR)
    dx[ATT] = [0.02, -0.01, 0.3]
    out = corrected(s, dx)
    np.testing.assert_allclose(out.c_bn @ out.c_bn.T, np.eye(3), atol=1e-12)
    v_body = out.c_bn.T @ s.v_ned
    assert np.linalg.norm(v_body) == pytest.approx(8.5, rel=1e-12)
    assert dcm_to_euler(out.c_bn)[2] == pytest.approx(1.9 - 0.3, abs=0.02)
