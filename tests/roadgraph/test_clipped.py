"""Clipped extracts: ways cut at the extract's edge, and the graph inside the box unchanged.

"The graph inside the box equals the full map's graph clipped to the box", precisely: shrink the
box by ``MARGIN_M`` on every side; then every edge of the clipped import whose geometry lies
wholly inside the shrunk box matches an edge of the full import (same set of OSM way ids, same
direction, both ends within 1 m, Hausdorff distance within 1 m), and every edge of the full
import wholly inside the shrunk box matches an edge of the clipped import. The margin absorbs
what a cut legitimately changes near the edge: a junction whose road leaves the box by a segment
whose far node is outside loses that road (so its two other roads merge into one edge), and
junction consolidation sees fewer nodes; on this box no difference reaches 50 m inside.
"""

from __future__ import annotations

import io
import json
import math
import shutil
import sqlite3
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import osmium
import pytest
import shapely

from roadgraph import import_map
from roadgraph.build import EdgeRecord
from roadgraph.cli import main
from roadgraph.osm import clip_refs, is_drivable
from roadgraph.store import read_info, read_network
from tests.conftest import DATA, SAMPLE_OSM
from tests.roadgraph.extracts import STRATEGIES, Bbox, cut, cut_xml_text

BOX: Bbox = (7.4185, 43.7305, 7.4275, 43.7375)  # Monaco's centre, 720 m x 780 m
MARGIN_M = 50.0
OSMIUM_115_SIMPLE = DATA / "roadgraph" / "monaco-simple-osmium-1.15.osm.pbf"


def _shrink(bbox: Bbox, margin_m: float) -> Bbox:
    dlat = margin_m / 111_320.0
    dlon = dlat / math.cos(math.radians((bbox[1] + bbox[3]) / 2.0))
    return bbox[0] + dlon, bbox[1] + dlat, bbox[2] - dlon, bbox[3] - dlat


def _inside(edge: EdgeRecord, bbox: Bbox) -> bool:
    lon, lat = edge.lonlat[:, 0], edge.lonlat[:, 1]
    return bool(np.all((lon >= bbox[0]) & (lon <= bbox[2]) & (lat >= bbox[1]) & (lat <= bbox[3])))


def _same(a: EdgeRecord, b: EdgeRecord, tol_m: float = 1.0) -> bool:
    return (set(a.osm_way_ids) == set(b.osm_way_ids)
            and bool(np.all(np.abs(a.coords[[0, -1]] - b.coords[[0, -1]]) <= tol_m))
            and shapely.hausdorff_distance(shapely.linestrings(a.coords),
                                           shapely.linestrings(b.coords)) <= tol_m)


def _unmatched(edges: tuple[EdgeRecord, ...], others: tuple[EdgeRecord, ...],
               bbox: Bbox) -> tuple[list[tuple[int, ...]], int]:
    """Way ids of the edges inside ``bbox`` without a match in ``others``, and how many."""
    inside = [e for e in edges if _inside(e, bbox)]
    return [e.osm_way_ids for e in inside if not any(_same(e, o) for o in others)], len(inside)


def _assert_same_inside(clipped_db: Path, full_db: Path) -> None:
    clipped, full = read_network(clipped_db).edges, read_network(full_db).edges
    box = _shrink(BOX, MARGIN_M)
    extra, n_clipped = _unmatched(clipped, full, box)
    lost, n_full = _unmatched(full, clipped, box)
    assert extra == [] and lost == []
    assert n_clipped == n_full > 50


@pytest.fixture(scope="module")
def extracts(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The box cut from the bundled map with each strategy, and as text from its XML."""
    folder = tmp_path_factory.mktemp("extracts")
    files = {s: folder / f"monaco-{s}.osm.pbf" for s in STRATEGIES}
    for strategy, path in files.items():
        cut(SAMPLE_OSM, path, BOX, strategy)
    files["xml-text"] = folder / "monaco-text.osm"
    cut_xml_text(SAMPLE_OSM, files["xml-text"], BOX)
    return files


@pytest.fixture(scope="module")
def full_db0(tmp_path_factory: pytest.TempPathFactory) -> Path:
    db = tmp_path_factory.mktemp("full") / "monaco0.db"
    import_map(db, source=SAMPLE_OSM, consolidate_m=0.0)
    return db


@pytest.mark.parametrize("strategy", [*STRATEGIES, "xml-text"])
def test_graph_inside_the_box_equals_the_full_map(extracts: dict[str, Path], sample_db: Path,
                                                  tmp_path: Path, strategy: str) -> None:
    db = tmp_path / "clipped.db"
    import_map(db, source=extracts[strategy])
    _assert_same_inside(db, sample_db)


def test_graph_inside_the_box_without_consolidation(extracts: dict[str, Path], full_db0: Path,
                                                    tmp_path: Path) -> None:
    db = tmp_path / "clipped.db"
    import_map(db, source=extracts["simple"], consolidate_m=0.0)
    _assert_same_inside(db, full_db0)


def _missing_refs(path: Path) -> tuple[int, int]:
    """Drivable ways with a reference to a node not in the file, and those references (naive)."""
    nodes = {n.id for n in osmium.FileProcessor(str(path), osmium.osm.NODE)}
    ways: list[list[int]] = []
    way: Any
    for way in osmium.FileProcessor(str(path), osmium.osm.WAY):
        if is_drivable(dict(way.tags)):
            ways.append([r.ref for r in way.nodes])
    missing = [sum(r not in nodes for r in refs) for refs in ways]
    return sum(m > 0 for m in missing), sum(missing)


@pytest.mark.parametrize("strategy", [*STRATEGIES, "xml-text"])
def test_summary_counts_missing_references(extracts: dict[str, Path], tmp_path: Path,
                                           strategy: str) -> None:
    info = import_map(tmp_path / "c.db", source=extracts[strategy])
    clipped_ways, missing = _missing_refs(extracts[strategy])
    assert info.osm_ways_cut is not None and info.osm_ways_dropped_outside is not None
    assert info.osm_missing_node_refs == missing
    assert info.osm_ways_cut + info.osm_ways_dropped_outside == clipped_ways
    if strategy in ("complete_ways", "smart"):
        assert missing == 0 and info.osm_ways_cut == 0
    else:  # 26 roads cross the box's edge; 6 only touch it with one node
        assert (missing, info.osm_ways_cut, info.osm_ways_dropped_outside) == (125, 26, 6)
    assert info == read_info(tmp_path / "c.db")


def test_osmium_tool_1_15_simple_extract(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                         ) -> None:
    """The extract Debian's osmium-tool 1.15 cuts with --strategy simple: the issue's failure.

    That version keeps only the ways whose first node is inside (osmium-tool PR #305 fixed it),
    so roads are missing inside the box too: only the import and its summary are checked.
    """
    db = tmp_path / "c.db"
    assert main(["import", str(OSMIUM_115_SIMPLE), "-o", str(db), "-q"]) == 0
    err = capsys.readouterr().err
    assert err == (f"roadgraph: warning: {OSMIUM_115_SIMPLE}: clipped extract: 66 node "
                   "references missing from the file; 12 ways cut at the edge, 4 dropped "
                   "(fewer than two nodes inside); roads end at the extract's edge\n")
    assert main(["info", str(db)]) == 0
    out = capsys.readouterr().out
    assert "missing node refs           66 (clipped extract)" in out
    assert "OSM ways kept               97 (12 cut at the extract's edge)" in out
    assert "OSM ways dropped            4 outside the extract, 0 of one node, 138 not in " \
           "the drive network" in out


@pytest.mark.skipif(shutil.which("osmium") is None, reason="osmium-tool not installed")
@pytest.mark.parametrize("strategy", STRATEGIES)
def test_cutter_matches_osmium_tool(extracts: dict[str, Path], tmp_path: Path,
                                    strategy: str) -> None:
    """Our pyosmium cutter keeps the objects osmium-tool keeps (its 1.15 simple bug aside)."""
    out = tmp_path / f"{strategy}.osm.pbf"
    west, south, east, north = BOX
    subprocess.run(["osmium", "extract", "-b", f"{west},{south},{east},{north}", "--strategy",
                    strategy, str(SAMPLE_OSM), "-o", str(out), "--no-progress"], check=True)

    def ids(path: Path, kind: osmium.osm.osm_entity_bits) -> set[int]:
        return {o.id for o in osmium.FileProcessor(str(path), kind)}

    ours, tool = extracts[strategy], out
    assert ids(ours, osmium.osm.NODE) == ids(tool, osmium.osm.NODE)
    if strategy == "simple":
        assert ids(tool, osmium.osm.WAY) <= ids(ours, osmium.osm.WAY)
    else:
        assert ids(ours, osmium.osm.WAY) == ids(tool, osmium.osm.WAY)


def _present(ids: str) -> Callable[[int], bool]:
    return lambda ref: ref in {int(c) for c in ids}


@pytest.mark.parametrize(("refs", "present", "pieces"), [
    ((1, 2, 3, 4), "1234", [(1, 2, 3, 4)]),
    ((1, 2, 3, 4), "234", [(2, 3, 4)]),  # cut at one end
    ((1, 2, 3, 4, 5), "1245", [(1, 2), (4, 5)]),  # leaves the box and comes back: split
    ((1, 2, 3, 4, 5), "135", []),  # no two consecutive nodes inside: dropped
    ((1, 2, 3, 4, 1), "1234", [(1, 2, 3, 4, 1)]),  # a whole ring stays closed
    ((1, 2, 3, 4, 1), "124", [(4, 1, 2)]),  # a cut ring: one piece through its closing node
    ((1, 2, 3, 4, 1), "1", []),
])
def test_clip_refs(refs: tuple[int, ...], present: str, pieces: list[tuple[int, ...]]) -> None:
    assert clip_refs(refs, _present(present)) == pieces


def test_info_of_a_database_without_the_summary_fields(sample_db: Path, tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]
                                                       ) -> None:
    """A database written before the summary fields still reads; its info omits them."""
    old = tmp_path / "old.db"
    shutil.copy(sample_db, old)
    with sqlite3.connect(old) as conn:
        fields = json.loads(conn.execute("SELECT value FROM meta WHERE key='info'").fetchone()[0])
        fields = {k: v for k, v in fields.items()
                  if not k.startswith("osm_") and k not in (
                      "road_length_m", "junction_count", "dead_end_count",
                      "junction_nodes_merged")}
        conn.execute("UPDATE meta SET value=? WHERE key='info'", (json.dumps(fields),))
    info = read_info(old)
    assert info.osm_missing_node_refs is None and info.road_length_m is None
    assert main(["info", str(old)]) == 0
    out = capsys.readouterr().out
    assert "missing node refs" not in out and "roads " not in out and "nodes       " in out


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_names_each_step_without_made_up_estimates(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """On a terminal: the step's number and name and the time so far; a percentage and an
    estimate only where the total is known (the road nodes the ways reference: in a clipped
    extract the bar stops short, by the references the summary reports missing; the edges to
    write)."""
    terminal = _Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    import_map(tmp_path / "c.db", source=OSMIUM_115_SIMPLE, progress=True, builder="arrays")
    shown = terminal.getvalue()
    build = "import, step 3/4: building the intersection graph: "
    steps = ["import, step 1/4: reading ways", "import, step 2/4: reading nodes",
             *(build + s for s in ("building the raw graph", "simplifying", "projecting",
                                   "consolidating junctions", "edge geometry and tags")),
             "import, step 4/4: writing the database"]
    assert all(step in shown for step in steps)
    assert [shown.index(s) for s in steps] == sorted(shown.index(s) for s in steps)
    parts = shown.replace("\n", "\r").split("\r")
    counted = ("road nodes read", "edges written")
    assert not any(("%" in p or "<" in p) for p in parts if not any(c in p for c in counted))
    assert "?step" not in shown
    for what in counted:
        assert any(what in p for p in parts)
