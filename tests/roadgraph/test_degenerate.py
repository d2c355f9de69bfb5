"""Degenerate inputs to `roadgraph import`: each one a clear message naming the file.

Through the CLI's ``main``, asserting the exit status and stderr exactly. What imports and what
is refused:

- a map whose roads never meet (no junction), a single road, only closed rings: imported, with a
  warning. A few dead-end roads are a legal map (a hamlet, a test map, a ring road): the matcher
  can match on them; only turns need a junction, and the warning says so.
- only ways of one node, roads none of them drivable, no road at all, every road outside the
  extract, every road shorter than the consolidation tolerance: refused, as there is nothing to
  match on (the last with the option that keeps them).
- road nodes with an invalid location: taken as missing (the way is cut there), with a warning.
- duplicate node or way ids, change files, history files: refused, as the file is not one moment
  of the map and any graph built from it would be wrong.
- negative ids (objects new in a JOSM file): imported, with a warning that their ids are not
  OpenStreetMap's; objects JOSM marks deleted are left out.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from roadgraph.cli import main
from roadgraph.store import read_network
from tests.conftest import DATA

R = {"highway": "residential"}
ERR = "roadgraph: error: {path}: "
WARN = "roadgraph: warning: {path}: "


def _node(i: int, lat: float, lon: float, attrs: str = 'version="1"') -> str:
    return f'<node id="{i}" lat="{lat}" lon="{lon}" {attrs}/>'


def _way(i: int, refs: list[int], tags: dict[str, str], attrs: str = 'version="1"') -> str:
    nds = "".join(f'<nd ref="{r}"/>' for r in refs)
    return f'<way id="{i}" {attrs}>{nds}' + "".join(
        f'<tag k="{k}" v="{v}"/>' for k, v in tags.items()) + "</way>"


def _osm(*items: str, root: str = 'osm version="0.6"') -> str:
    return f'<?xml version="1.0"?><{root}>' + "".join(items) + f"</{root.split()[0]}>"


SQUARE = [_node(1, 43.700, 7.400), _node(2, 43.700, 7.401), _node(3, 43.701, 7.401),
          _node(4, 43.701, 7.400)]

CASES: dict[str, tuple[str, str, int, str]] = {
    # name: (file name, content, exit status, stderr after "roadgraph: ...: {path}: ")
    "no_junction": ("apart.osm", _osm(*SQUARE, _way(10, [1, 2], R), _way(11, [3, 4], R)), 0,
                    WARN + "no junction (no node where three roads meet): imported, but "
                    "there is no road to turn onto\n"),
    "single_way": ("one.osm", _osm(*SQUARE, _way(10, [1, 2, 3], R)), 0,
                   WARN + "a single road: imported, but there is no other road to turn onto\n"),
    "one_closed_loop": ("ring.osm", _osm(*SQUARE, _way(10, [1, 2, 3, 4, 1], R)), 0,
                        WARN + "a single road: imported, but there is no other road to turn "
                        "onto\n"),
    "only_closed_loops": ("rings.osm", _osm(
        *SQUARE, _node(5, 43.710, 7.400), _node(6, 43.710, 7.401), _node(7, 43.711, 7.401),
        _way(10, [1, 2, 3, 1], {"highway": "primary", "junction": "roundabout"}),
        _way(11, [5, 6, 7, 5], R)), 0,
        WARN + "no junction (no node where three roads meet): imported, but there is no road "
        "to turn onto\n"),
    "only_one_node_ways": ("dots.osm", _osm(*SQUARE, _way(10, [1], R), _way(11, [2, 2], R)), 1,
                           ERR + "no drivable road: each of the 2 drive ways has only one "
                           "node\n"),
    "roads_none_drivable": ("park.osm", _osm(
        *SQUARE, _way(10, [1, 2], {"highway": "footway"}), _way(11, [2, 3], {"highway": "steps"}),
        _way(12, [3, 4], {"highway": "footway"}), _way(13, [4, 1], {"highway": "service"})), 1,
        ERR + "no drivable road (network 'drive') in the file: its 4 highway ways are not for "
        "cars (footway 2, steps 1, service 1); --network drive_service keeps service roads\n"),
    "no_road_at_all": ("buildings.osm", _osm(*SQUARE, _way(10, [1, 2, 3, 4, 1],
                                                            {"building": "yes"})), 1,
                       ERR + "no drivable road (network 'drive') in the file: no way is tagged "
                       "highway=*\n"),
    "empty_file": ("empty.osm", _osm(), 1,
                   ERR + "no drivable road (network 'drive') in the file: no way is tagged "
                   "highway=*\n"),
    "every_road_outside": ("edge.osm", _osm(SQUARE[0], _way(10, [1, 2], R),
                                            _way(11, [8, 9], R)), 1,
                           ERR + "no drivable road inside the extract: each of the 2 drive ways "
                           "has fewer than two of its nodes in the file (3 node references "
                           "missing)\n"),
    "roads_shorter_than_consolidation": ("dot.osm", _osm(
        _node(1, 43.7, 7.4), _node(2, 43.7, 7.4), _way(10, [1, 2], R)), 1,
        ERR + "no road left after merging the nodes within 8 m of each other: every road is "
        "shorter than that; import with --consolidate-m 0\n"),
    "invalid_location": ("polar.osm", _osm(
        _node(1, 95.0, 7.4), *SQUARE[1:], _way(10, [1, 2, 3], R)), 0,
        WARN + "1 road nodes with an invalid location (beyond 90 degrees of latitude or 180 of "
        "longitude), taken as missing\n"
        + WARN + "clipped extract: 1 node references missing from the file; 1 ways cut at the "
        "edge, 0 dropped (fewer than two nodes inside); roads end at the extract's edge\n"
        + WARN + "a single road: imported, but there is no other road to turn onto\n"),
    "duplicate_node_id": ("dup-node.osm", _osm(*SQUARE, SQUARE[1], _way(10, [1, 2, 3], R)), 1,
                          ERR + "node 2 appears twice: duplicate ids (two extracts "
                          "concatenated? combine them with osmium merge)\n"),
    "duplicate_way_id": ("dup-way.osm", _osm(*SQUARE, _way(10, [1, 2], R), _way(10, [3, 4], R)),
                         1, ERR + "way 10 appears twice: duplicate ids (two extracts "
                         "concatenated? combine them with osmium merge)\n"),
    "negative_ids_josm": ("josm.osm", _osm(
        _node(-1, 43.700, 7.400, "action='modify' visible='true'"),
        _node(-2, 43.700, 7.401, ""), _node(-3, 43.701, 7.401, ""), _node(-4, 43.701, 7.402, ""),
        _node(-5, 43.702, 7.402, ""),
        _way(-10, [-1, -2, -3], R, ""), _way(-11, [-2, -4], R, ""),
        _way(-12, [-4, -5], R, "action='delete'"),
        root="osm version='0.6' upload='false' generator='JOSM'"), 0,
        WARN + "6 nodes and ways with negative ids (new objects in a JOSM file, not yet in "
        "OpenStreetMap): imported, but their ids are not OpenStreetMap's\n"
        + WARN + "objects marked deleted by JOSM left out: 1\n"),
    "change_file": ("diff.osc", _osm(
        "<create>", *SQUARE, _way(10, [1, 2], R), "</create>",
        root='osmChange version="0.6"'), 1,
        ERR + "an OSM change file (osmChange), not an extract: apply it to an extract first "
        "(osmium apply-changes EXTRACT.osm.pbf diff.osc -o NEW.osm.pbf)\n"),
    "change_file_named_osm": ("diff.osm", _osm(
        "<modify>", *SQUARE, _way(10, [1, 2], R), "</modify>",
        root='osmChange version="0.6"'), 1,
        ERR + "an OSM change file (osmChange), not an extract: apply it to an extract first "
        "(osmium apply-changes EXTRACT.osm.pbf diff.osm -o NEW.osm.pbf)\n"),
    "history_versions": ("past.osm", _osm(
        *SQUARE, _node(2, 43.7001, 7.401, 'version="2"'), _way(10, [1, 2, 3], R)), 1,
        ERR + "an OSM history file (node 2 appears in versions 1 and 2), not an extract: take "
        "one moment of it first (osmium time-filter past.osm -o EXTRACT.osm.pbf)\n"),
    "history_deleted_object": ("gone.osm", _osm(
        *SQUARE, _way(10, [1, 2], R), _way(11, [3, 4], R, 'version="2" visible="false"')), 1,
        ERR + "an OSM history file (way 11 is marked deleted (visible=false)), not an extract: "
        "take one moment of it first (osmium time-filter gone.osm -o EXTRACT.osm.pbf)\n"),
    "history_named_osh": ("past.osh", _osm(*SQUARE, _way(10, [1, 2, 3], R)), 1,
                          ERR + "an OSM history file (named .osh), not an extract: take one "
                          "moment of it first (osmium time-filter past.osh -o "
                          "EXTRACT.osm.pbf)\n"),
}


def _run(tmp_path: Path, source: Path, capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    code = main(["import", str(source), "-o", str(tmp_path / "out.db"), "-q"])
    out = capsys.readouterr()
    assert out.out == ""
    return code, out.err


@pytest.mark.parametrize("case", CASES)
def test_degenerate_input(tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str) -> None:
    name, content, status, message = CASES[case]
    source = tmp_path / name
    source.write_text(content)
    code, err = _run(tmp_path, source, capsys)
    assert (code, err) == (status, message.format(path=source))
    assert (tmp_path / "out.db").exists() == (status == 0)


def test_history_pbf_given_as_extract(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A history PBF (header flag), renamed .osm.pbf: made by osmium cat -F osh."""
    source = DATA / "roadgraph" / "history-as-extract.osm.pbf"
    code, err = _run(tmp_path, source, capsys)
    assert code == 1
    assert err == (f"roadgraph: error: {source}: an OSM history file (its header says it holds "
                   "several versions of objects), not an extract: take one moment of it first "
                   "(osmium time-filter history-as-extract.osm.pbf -o EXTRACT.osm.pbf)\n")


def _written(tmp_path: Path, case: str, capsys: pytest.CaptureFixture[str]) -> Path:
    name, content, _, _ = CASES[case]
    (tmp_path / name).write_text(content)
    assert _run(tmp_path, tmp_path / name, capsys)[0] == 0
    return tmp_path / "out.db"


def test_rings_keep_one_node_each(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """osmnx's simplification drops a ring meeting no road; ours keeps it as a self-loop."""
    net = read_network(_written(tmp_path, "only_closed_loops", capsys))
    assert sorted(n.osm_ids for n in net.nodes) == [(1,), (5,)]
    assert all(e.u == e.v for e in net.edges)
    # the roundabout is one way; the residential ring goes both ways
    assert sorted(len(e.coords) for e in net.edges) == [4, 4, 4]
    assert net.info.junction_count == 0 and net.info.dead_end_count == 0


def test_josm_file_leaves_out_deleted_objects(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    net = read_network(_written(tmp_path, "negative_ids_josm", capsys))
    way_ids = {i for e in net.edges for i in e.osm_way_ids}
    assert way_ids == {-10, -11}
    assert net.info.osm_negative_ids == 6 and net.info.osm_josm_deleted == 1


@pytest.mark.parametrize("case", [c for c, (_, _, status, _) in CASES.items() if status == 0])
def test_imported_degenerate_maps_have_a_summary(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str],
                                                 case: str) -> None:
    db = _written(tmp_path, case, capsys)
    assert main(["info", str(db)]) == 0
    out = capsys.readouterr().out
    assert "junctions" in out and "missing node refs" in out
