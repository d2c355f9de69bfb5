"""Strapdown INS/GNSS on a real drive, against KF-GINS on the same input.

Data: rtklibexplorer's drive 0708 (consumer IMU at 100 Hz, RTK GNSS at 4 Hz, 549 s) in KF-GINS's
text formats, and KF-GINS's own results on it (``../shared/peers/rtklibexplorer-drive0708``;
see its PROVENANCE.md). Our filter starts from KF-GINS's own configuration file
(``kfgins_profileA.yaml``, read by ``navsvc.wire.kfgins.read_profile``): same initial state,
noise and lever arm.

- ``dec1hz``: 1 Hz GNSS in; scored on the withheld 4 Hz RTK epochs (horizontal RMS, 95 %, max).
- ``out0..out2``: 4 Hz GNSS with two 60 s windows removed each; scored by the largest
  horizontal error inside each window (the drift of a 60 s outage), also with the
  non-holonomic constraint (the drive has no wheel speed; KF-GINS uses no vehicle constraint).

Every integration (feedback, feedforward, direct) and mechanisation (first order, RK4) runs on
``dec1hz``, and feedback with first order on a flat earth too; every integration, first order,
runs the outages. µs per IMU epoch is the median of three runs. Positions are compared at the
GNSS antenna (lever arm applied to both filters' attitude).

    python bench/ins_eval.py [--data ../shared/peers/rtklibexplorer-drive0708]
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from pathlib import Path
from typing import Any

import numpy as np
from report import RESULTS, print_table, write_json

from navsvc.fusion.ins import (
    EarthModel,
    Integration,
    Mechanisation,
    euler_to_dcm,
    radii_m,
    replay,
)
from navsvc.wire.kfgins import gnss_fixes, read_gnss, read_imu, read_nav, read_profile

DEFAULT_DATA = RESULTS.parent.parent.parent / "shared" / "peers" / "rtklibexplorer-drive0708"
TIMED_RUNS = 3
OUTAGES = {"out0": (243400.0, 243580.0), "out1": (243460.0, 243640.0),
           "out2": (243520.0, 243700.0)}


def antenna_errors_m(track: np.ndarray, truth: np.ndarray,
                     lever_m: np.ndarray) -> np.ndarray:
    """Horizontal error at each truth epoch. track: t, lat, lon (rad), h, roll, pitch, yaw
    (rad); truth: t, lat, lon (deg)."""
    lat = np.interp(truth[:, 0], track[:, 0], track[:, 1])
    lon = np.interp(truth[:, 0], track[:, 0], track[:, 2])
    yaw = np.interp(truth[:, 0], track[:, 0], np.unwrap(track[:, 6]))
    out = []
    for i, (t, la, lo) in enumerate(truth[:, :3]):
        rm, rn = radii_m(lat[i])
        k = min(np.searchsorted(track[:, 0], t), len(track) - 1)
        lever = euler_to_dcm(track[k, 4], track[k, 5], yaw[i]) @ lever_m
        dn = (lat[i] - math.radians(la)) * rm + lever[0]
        de = (lon[i] - math.radians(lo)) * rn * math.cos(lat[i]) + lever[1]
        out.append(math.hypot(dn, de))
    return np.array(out)


def kfgins_track(nav: np.ndarray) -> np.ndarray:
    return np.column_stack([nav[:, 1], np.radians(nav[:, 2]), np.radians(nav[:, 3]), nav[:, 4],
                            np.radians(nav[:, 8]), np.radians(nav[:, 9]),
                            np.radians(nav[:, 10])])


def stats(errors: np.ndarray) -> dict[str, float]:
    return {"rms_m": float(np.sqrt(np.mean(errors**2))),
            "p95_m": float(np.percentile(errors, 95)), "max_m": float(errors.max())}


def outage_drifts(track: np.ndarray, gnss4: np.ndarray, starts: tuple[float, ...],
                  lever_m: np.ndarray) -> list[float]:
    drifts = []
    for start in starts:
        inside = gnss4[(gnss4[:, 0] >= start) & (gnss4[:, 0] < start + 60.0)]
        drifts.append(float(antenna_errors_m(track, inside, lever_m).max()))
    return drifts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    args = parser.parse_args()
    fmt, anchor = args.data / "kfgins-format", args.data / "kfgins-output"
    profile = read_profile(anchor / "kfgins_profileA.yaml")
    lever = np.array(profile.lever_arm_m)
    imu = read_imu(fmt / "imu_kfgins.txt")
    gnss4, gnss1 = read_gnss(fmt / "gnss_4hz.txt"), read_gnss(fmt / "gnss_1hz.txt")
    withheld = gnss4[~np.isin(np.round(gnss4[:, 0], 3), np.round(gnss1[:, 0], 3))
                     & (gnss4[:, 0] > profile.start_t + 1.0)]
    rows: list[dict[str, Any]] = []
    kf = kfgins_track(read_nav(anchor / "kfgins_A_dec1hz_10hz.nav"))
    rows.append({"filter": "KF-GINS", "mode": "feedback (21 states)", "mechanisation": "",
                 **stats(antenna_errors_m(kf, withheld, lever)), "us_per_epoch": 21.7})
    for integration in Integration:  # compile the kernels before any timing
        for mech in Mechanisation:
            replay(profile.filter(integration, mech), imu[:300], gnss_fixes(gnss1[:3]))
    variants = [(i, m, EarthModel.WGS84) for i in Integration for m in Mechanisation]
    variants.append((Integration.FEEDBACK, Mechanisation.FIRST_ORDER, EarthModel.FLAT))
    for integration, mech, earth in variants:
        timings = []
        for _ in range(TIMED_RUNS):  # the same track each time; the median time is quoted
            ins = profile.filter(integration, mech, earth)
            start = time.perf_counter()
            track = replay(ins, imu, gnss_fixes(gnss1))
            timings.append(1e6 * (time.perf_counter() - start) / len(track))
        us = statistics.median(timings)
        rows.append({"filter": "navsvc", "mode": integration.value,
                     "mechanisation": f"{mech.value}, {earth.value} earth",
                     **stats(antenna_errors_m(track, withheld, lever)), "us_per_epoch": us})
        print(rows[-1])
    drift_rows = []
    for run, starts in OUTAGES.items():
        kept = gnss4[~np.any([(gnss4[:, 0] >= s) & (gnss4[:, 0] < s + 60.0) for s in starts],
                             axis=0)]
        tracks = {f"navsvc_{i.value}_m": replay(profile.filter(i), imu, gnss_fixes(kept))
                  for i in Integration}
        tracks["navsvc_nhc_m"] = replay(profile.filter(), imu, gnss_fixes(kept),
                                        nhc_sigma_mps=0.1)
        tracks["kfgins_m"] = kfgins_track(read_nav(anchor / f"kfgins_A_{run}_10hz.nav"))
        drift_rows.append({"run": run, "starts": starts,
                           **{k: outage_drifts(track, gnss4, starts, lever)
                              for k, track in tracks.items()}})
        print(drift_rows[-1])
    print_table("drive 0708, 1 Hz GNSS, scored on the withheld 4 Hz RTK epochs (horizontal)",
                ["filter", "integration", "mechanisation", "RMS m", "95 % m", "max m",
                 "µs / IMU epoch"],
                [[r["filter"], r["mode"], r["mechanisation"], r["rms_m"], r["p95_m"],
                  r["max_m"], r["us_per_epoch"]] for r in rows])
    def rms(key: str) -> float:
        return math.sqrt(statistics.fmean(d * d for r in drift_rows for d in r[key]))

    keys = [f"navsvc_{i.value}_m" for i in Integration] + ["navsvc_nhc_m", "kfgins_m"]
    print_table("60 s GNSS outages: largest horizontal error in each window (m)",
                ["run", "windows", *(f"navsvc {i.value}" for i in Integration),
                 "navsvc feedback + non-holonomic", "KF-GINS"],
                [[r["run"], ", ".join(f"{s:.0f}" for s in r["starts"]),
                  *(", ".join(f"{d:.1f}" for d in r[k]) for k in keys)] for r in drift_rows]
                + [["RMS", "", *(rms(k) for k in keys)]])
    write_json("ins_eval", {"accuracy": rows, "outages": drift_rows})


if __name__ == "__main__":
    main()
