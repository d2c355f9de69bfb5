"""Fusion on real data: the comma2k19 example segment (60 s, highway), against its truth.

Gyro + odometer, steering + odometer, and the strapdown INS on the phone's 6-axis IMU with and
without wheel speed (the feedback, feedforward and direct integrations; RK4 mechanisation
beside first order); the u-blox fixes at 10 Hz, thinned to 1 Hz, and at 1 Hz with a 20 s outage
(20-40 s). Errors of the fused track beside the raw fixes.

    python bench/comma2k19.py [--data tests/data/comma2k19]
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from report import print_table, write_json

from navsvc.fusion.ins import Integration
from navsvc.session import VehicleSession, config_from_options
from navsvc.sim.comma2k19 import WHEELBASE_M, Gnss, read_segment
from navsvc.sim.evaluate import evaluate
from navsvc.wire.positions import position_json

ROOT = Path(__file__).resolve().parent.parent
SCENARIOS = {"GNSS 10 Hz": Gnss(10.0), "GNSS 1 Hz": Gnss(1.0),
             "1 Hz, 20 s outage": Gnss(1.0, outage=(20.0, 20.0))}
KINDS: dict[str, tuple[dict[str, Any], set[str]]] = {
    "gyro_odometer": ({"sensors": "gyro_odometer"}, {"imu", "odometer", "gps"}),
    "steering_odometer": ({"sensors": "steering_odometer"}, {"steering", "odometer", "gps"}),
    "strapdown rk4": ({"sensors": "strapdown", "ins_mechanisation": "rk4"}, {"imu", "gps"}),
}
for _integration in Integration:  # the paper's three integrations, with and without wheels
    _options = {"sensors": "strapdown", "ins_integration": _integration.value}
    KINDS[f"strapdown {_integration.value}"] = (_options, {"imu", "gps"})
    KINDS[f"strapdown {_integration.value} + wheel speed"] = (_options,
                                                              {"imu", "odometer", "gps"})


def run(data: Path, gnss: Gnss, name: str) -> dict[str, Any]:
    drive = read_segment(data, gnss)
    options, kinds = KINDS[name]
    session = VehicleSession(config_from_options({**options, "wheelbase_m": WHEELBASE_M}))
    result = session.add_records([r for r in drive if r["kind"] in kinds])
    assert session.frame is not None
    out = [position_json(p, session.frame) for p in result.positions]
    e = evaluate(drive, out)
    outage = e.outages[0] if e.outages else None
    return {"fused_rms_m": e.fused.rms_m, "fused_p95_m": e.fused.p95_m,
            "raw_gps_rms_m": e.raw_gps.rms_m, "ratio": e.fused_to_raw_ratio,
            "heading_rms_deg": e.heading_rms_deg,
            "outage_end_error_m": outage.end_error_m if outage else None,
            "outage_distance_m": outage.distance_m if outage else None,
            "outage_drift_pct": outage.drift_pct if outage else None}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, default=ROOT / "tests" / "data" / "comma2k19")
    args = parser.parse_args()
    rows, table = [], []
    for name, gnss in SCENARIOS.items():
        for sensors in KINDS:
            r = {"scenario": name, "sensors": sensors, **run(args.data, gnss, sensors)}
            rows.append(r)
            table.append([name, sensors, r["fused_rms_m"], r["fused_p95_m"],
                          r["raw_gps_rms_m"], r["ratio"], r["heading_rms_deg"],
                          "-" if r["outage_end_error_m"] is None else r["outage_end_error_m"],
                          "-" if r["outage_drift_pct"] is None else r["outage_drift_pct"]])
    print_table("comma2k19 example segment: fused error against global_pose",
                ["GNSS", "sensors", "fused RMS m", "fused 95% m", "raw GNSS RMS m", "ratio",
                 "heading RMS deg", "outage end error m", "drift %"], table)
    write_json("comma2k19", {"rows": rows})


if __name__ == "__main__":
    main()
