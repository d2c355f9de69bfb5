"""Evaluation metrics on hand-made truth and estimates with known errors."""

import math

import pytest

from navsvc.sim.evaluate import evaluate
from roadgraph import LocalFrame

FRAME = LocalFrame.for_point(7.42, 43.73)
X0, Y0 = FRAME.to_local(7.42, 43.73)


def _ll(x: float, y: float) -> tuple[float, float]:
    """Metres east and north of a point in Monaco → (lat, lon)."""
    lon, lat = FRAME.to_wgs84(X0 + x, Y0 + y)
    return lat, lon


def _drive(gps_gap: tuple[float, float] = (50.0, 70.0)) -> list[dict]:
    records = []
    for i in range(1001):  # 100 s north at 10 m/s; road (1, 2) then (2, 3) from 50 s
        t = i / 10
        lat, lon = _ll(0.0, 10.0 * t)
        road = (1, 2) if t < 50 else (2, 3)
        records.append({"t": t, "kind": "truth", "lat": lat, "lon": lon, "heading_deg": 0.0,
                        "speed_mps": 10.0, "osm_way_id": 1, "u": road[0], "v": road[1]})
    for t in range(100):
        if gps_gap[0] < t < gps_gap[1]:
            continue
        lat, lon = _ll(4.0, 10.0 * t)  # 4 m east of the truth
        records.append({"t": float(t), "kind": "gps", "lat": lat, "lon": lon})
    return records


def _estimates(offset_east_m: float, heading_deg: float, edge_from: float) -> list[dict]:
    out = []
    for t in range(100):
        lat, lon = _ll(offset_east_m, 10.0 * t)
        edge = {"u": 1, "v": 2} if t < edge_from else {"u": 2, "v": 3}
        out.append({"t": float(t), "lat": lat, "lon": lon, "fused_lat": lat, "fused_lon": lon,
                    "heading_deg": heading_deg, "edge": edge})
    return out


def test_known_offsets() -> None:
    e = evaluate(_drive(), _estimates(3.0, 2.0, edge_from=50))
    assert e.fused.rms_m == pytest.approx(3.0, abs=0.01)
    assert e.fused.max_m == pytest.approx(3.0, abs=0.01)
    assert e.raw_gps.rms_m == pytest.approx(4.0, abs=0.01)
    assert e.fused_to_raw_ratio == pytest.approx(0.75, abs=0.01)
    assert e.heading_rms_deg == pytest.approx(2.0, abs=1e-6)
    (outage,) = e.outages
    assert (outage.start_s, outage.end_s) == (50.0, 70.0)
    assert outage.distance_m == pytest.approx(200.0, rel=1e-3)
    assert outage.drift_pct == pytest.approx(1.5, abs=0.01)
    assert e.on_right_road_share == 1.0
    assert (e.intersections_correct, e.intersections_total) == (1, 1)


def test_ratio_compares_fused_and_raw_at_the_same_epochs() -> None:
    """An estimate 40 m off in the GPS gap counts in the fused RMS over the drive, not in
    the ratio: raw GPS has no error there to compare it with."""
    estimates = _estimates(3.0, 0.0, edge_from=50)
    for r in estimates:
        if 50.0 < r["t"] < 70.0:
            r["fused_lat"], r["fused_lon"] = _ll(40.0, 10.0 * r["t"])
    e = evaluate(_drive(), estimates)
    assert e.fused.rms_m > 15.0
    assert e.fused_at_gps.rms_m == pytest.approx(3.0, abs=0.01)
    assert e.raw_at_fused.n == e.raw_gps.n == 81
    assert e.fused_to_raw_ratio == pytest.approx(0.75, abs=0.01)


def test_heading_wraps_and_wrong_road_counts() -> None:
    e = evaluate(_drive(), _estimates(0.0, 358.0, edge_from=60))
    assert e.heading_rms_deg == pytest.approx(2.0, abs=1e-6)
    assert e.on_right_road_share == pytest.approx(0.91)  # t=50 s is at the intersection
    assert (e.intersections_correct, e.intersections_total) == (1, 1)  # most of 50-100 s
    e = evaluate(_drive(), _estimates(0.0, 0.0, edge_from=80))
    assert (e.intersections_correct, e.intersections_total) == (0, 1)


def test_standing_on_the_intersection_does_not_decide_the_road_taken() -> None:
    """The car stops on the node for 50 s, already on the next road by the truth; a run that
    stays on the old road while standing and takes the right one on leaving is correct."""
    drive = []
    for i in range(1301):
        t = i / 10
        y = 10.0 * min(t, 50.0) + 10.0 * max(t - 100.0, 0.0)
        road = (1, 2) if t < 50 else (2, 3)
        lat, lon = _ll(0.0, y)
        drive.append({"t": t, "kind": "truth", "lat": lat, "lon": lon, "heading_deg": 0.0,
                      "speed_mps": 0.0 if 50 <= t < 100 else 10.0, "u": road[0],
                      "v": road[1]})

    def run(moved_on: tuple[int, int]) -> list[dict]:
        out = []
        for r in drive[::10]:
            edge = (1, 2) if r["t"] < 101 else moved_on
            out.append({"t": r["t"], "lat": r["lat"], "lon": r["lon"], "fused_lat": r["lat"],
                        "fused_lon": r["lon"], "heading_deg": 0.0,
                        "edge": {"u": edge[0], "v": edge[1]}})
        return out

    e = evaluate(drive, run(moved_on=(2, 3)))
    assert (e.intersections_correct, e.intersections_total) == (1, 1)
    e = evaluate(drive, run(moved_on=(2, 7)))
    assert (e.intersections_correct, e.intersections_total) == (0, 1)
    # the drive ends while the car still stands on the node: the road was not traversed
    standing = [r for r in drive if r["t"] < 99.0]
    e = evaluate(standing, [r for r in run(moved_on=(2, 3)) if r["t"] < 99.0])
    assert e.intersections_total == 0


def test_no_edges_means_no_road_share() -> None:
    est = _estimates(1.0, 0.0, 50)
    for r in est:
        r["edge"] = None
    e = evaluate(_drive(), est)
    assert e.on_right_road_share is None and e.intersections_total == 0
    assert math.isfinite(e.fused.rms_m)


def test_drive_without_truth_is_refused() -> None:
    with pytest.raises(ValueError, match="no truth"):
        evaluate([{"t": 0, "kind": "gps", "lat": 0, "lon": 0}], [])
