"""The UrbanNav error recording: parsed as recorded, replayed at the right times with its
gaps, and carried onto a simulated drive."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from navsvc.sim.gnss_replay import GnssErrorRecording, parse_urbannav, replay_error
from navsvc.sim.simulate import DriveSpec, simulate_drive
from roadgraph import RoadGraph

URBANNAV = Path(__file__).resolve().parent.parent / "data" / "urbannav"


@pytest.fixture(scope="module")
def recording() -> GnssErrorRecording:
    return parse_urbannav((URBANNAV / "spp_fixes.csv").read_text(),
                          (URBANNAV / "groundTruth_TST.csv").read_text())


def test_parsed_as_its_provenance_says(recording: GnssErrorRecording) -> None:
    assert recording.duration_s == 485  # tow 46701-47185
    assert sum(recording.present) == 211
    size = np.hypot(recording.east_m, recording.north_m)[list(recording.present)]
    assert np.median(size) == pytest.approx(4.2, abs=0.05)
    assert math.sqrt(np.mean(size ** 2)) == pytest.approx(12.9, abs=0.05)
    assert size.max() == pytest.approx(55.8, abs=0.05)
    assert not any(recording.present[:112])  # no fix for the first 112 s (tow 46813)


def test_one_fix_by_hand() -> None:
    spp = ("gps_week,tow_s,lat,lon,height_m,q,ns,sdn_m,sde_m,sdu_m,truth_lat,truth_lon,"
           "truth_height_m\n"
           "2051,101.000,10.0001,20.0,0,5,8,1,1,1,10.0,20.0,0\n"  # 1e-4 deg north
           "2051,105.000,10.0,20.0,0,5,8,1,1,1,,,\n")  # outside the truth window
    truth = "2051,100,10.0,20.0,0\n2051,101,10.0,20.0,0\n2051,102,10.0,20.0,0\n"
    r = parse_urbannav(spp, truth)
    assert r.present == (False, True, False)
    assert r.north_m[1] == pytest.approx(11.06, abs=0.01)  # 1e-4 deg of latitude at 10 deg
    assert r.east_m[1] == 0.0


def test_replay_reproduces_the_recording_at_whole_seconds(
        recording: GnssErrorRecording) -> None:
    offset = 100
    t = np.arange(0.0, 300.0)
    covered, err = replay_error(recording, t, offset)
    k = np.arange(offset, offset + 300)
    assert covered.tolist() == [recording.present[i] for i in k]
    expected = np.column_stack([recording.east_m, recording.north_m])[k]
    assert np.array_equal(err[covered], expected[covered])
    assert not err[~covered].any()


def test_replay_between_seconds_and_across_the_end() -> None:
    r = GnssErrorRecording("hand", east_m=(0.0, 10.0, 20.0, 0.0), north_m=(1.0, 1.0, 1.0, 0.0),
                           present=(True, True, False, False))
    covered, err = replay_error(r, np.array([0.0, 0.5, 1.5, 2.5, 4.25]), offset_s=0)
    assert covered.tolist() == [True, True, True, False, True]
    assert err.tolist() == [[0.0, 1.0], [5.0, 1.0], [10.0, 1.0], [0.0, 0.0], [2.5, 1.0]]


def test_a_recording_needs_a_fix() -> None:
    with pytest.raises(ValueError, match="recording 'empty' has no fix"):
        GnssErrorRecording("empty", (0.0,), (0.0,), (False,))


def test_drive_carries_the_recorded_error_and_its_gaps(sample_graph: RoadGraph,
                                                       recording: GnssErrorRecording) -> None:
    spec = DriveSpec(duration_s=200.0, seed=3, tunnels_block_gps=False,
                     gps_error_replay=recording, gps_error_replay_offset_s=150)
    records = simulate_drive(sample_graph, spec)
    truth = {round(r["t"], 1): r for r in records if r["kind"] == "truth"}
    gps = [r for r in records if r["kind"] == "gps"]
    k = [int(round(r["t"])) + 150 for r in gps]
    assert k == [i for i in range(150, 350) if recording.present[i]]  # the gaps as outages

    def local(r: dict[str, float]) -> tuple[float, float]:
        return sample_graph.frame.to_local(r["lon"], r["lat"])

    err = np.array([np.subtract(local(r), local(truth[round(r["t"], 1)])) for r in gps])
    expected = np.column_stack([recording.east_m, recording.north_m])[k]
    assert np.abs(err - expected).max() < 1e-3


def test_offset_drawn_from_the_seed(sample_graph: RoadGraph,
                                    recording: GnssErrorRecording) -> None:
    def times(seed: int) -> list[float]:
        spec = DriveSpec(duration_s=120.0, seed=seed, gps_error_replay=recording,
                         tunnels_block_gps=False)
        return [r["t"] for r in simulate_drive(sample_graph, spec) if r["kind"] == "gps"]

    assert times(1) == times(1)
    assert len({tuple(times(s)) for s in (1, 2, 3, 4)}) > 1
