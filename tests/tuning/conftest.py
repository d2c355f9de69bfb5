"""Two short seeded drives on the sample map, and a mistuned profile to tune away from."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from navsvc.sim.simulate import DriveSpec, simulate_drive
from navsvc.tuning.replay import TuneDrive
from navsvc.wire.jsonl import write_records
from roadgraph import RoadGraph

SEEDS = (1, 4)  # 60 s each, with GPS from the start (seed 3 starts in a tunnel)
# GPS trusted as 1 m fixes with no slowly changing error: on these drives 0.857 against the
# defaults' 0.880 (measured with the filter of December 2026; the robust GPS handling of
# issue 15 made the filter forgiving: it cost 0.23 before). Tuning should win it back: hill
# climbing reaches 0.909 and the GA 0.904 in the tests' 10 evaluations
MISTUNED = {"fusion.gps_uere_m": 1.0, "fusion.gps_bias_share": 0.0}
TUNED = "fusion.gps_uere_m,fusion.gps_bias_share"


@pytest.fixture(scope="session")
def drive_files(sample_graph: RoadGraph, tmp_path_factory: pytest.TempPathFactory
                ) -> list[Path]:
    folder = tmp_path_factory.mktemp("drives")
    paths = []
    for seed in SEEDS:
        path = folder / f"drive{seed}.jsonl"
        write_records(path, simulate_drive(sample_graph, DriveSpec(duration_s=60.0, seed=seed)))
        paths.append(path)
    return paths


@pytest.fixture(scope="session")
def drives(drive_files: list[Path]) -> list[TuneDrive]:
    from navsvc.wire.jsonl import read_records

    return [TuneDrive(str(p), tuple(read_records(p))) for p in drive_files]


@pytest.fixture()
def mistuned(tmp_path: Path) -> Path:
    path = tmp_path / "mistuned.json"
    path.write_text(json.dumps({"parameters": MISTUNED}))
    return path
