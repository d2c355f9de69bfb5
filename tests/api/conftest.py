"""One server for the API tests of a module, on a private copy of the sample map."""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.api.server import Server, start_server


@pytest.fixture(scope="module")
def server(sample_db: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    folder = tmp_path_factory.mktemp("server")
    db = folder / "monaco.db"
    shutil.copy(sample_db, db)
    s = start_server(db, folder / "server.log")
    yield s
    s.stop()


@pytest.fixture()
def db(sample_db: Path, tmp_path: Path) -> Path:
    """A private copy of the sample map, for a test that starts its own servers."""
    copy = tmp_path / "monaco.db"
    shutil.copy(sample_db, copy)
    return copy
