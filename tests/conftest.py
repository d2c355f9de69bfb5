"""Shared fixtures: the bundled sample map imported once per test session."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import settings

from roadgraph import RoadGraph, import_map

ROOT = Path(__file__).resolve().parent.parent
SAMPLE_OSM = ROOT / "maps" / "monaco.osm.gz"
DATA = Path(__file__).resolve().parent / "data"


@pytest.fixture(scope="session")
def sample_db(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The bundled Monaco extract imported into a road-graph database."""
    db = tmp_path_factory.mktemp("maps") / "monaco.db"
    import_map(db, source=SAMPLE_OSM)
    return db


@pytest.fixture(scope="session")
def sample_graph(sample_db: Path) -> RoadGraph:
    return RoadGraph.open(sample_db)


# numba compiles the filter kernels on first use (then caches them): no per-example deadline
settings.register_profile("navsvc", deadline=None)
settings.load_profile("navsvc")
