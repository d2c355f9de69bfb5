import dataclasses
import sqlite3
from pathlib import Path

import pytest

from roadgraph import RoadGraph, import_map
from roadgraph.errors import MapDatabaseError, SchemaVersionError
from roadgraph.store import read_edges_in_bbox, read_info, read_network, write_network


def test_round_trip_graph_in_equals_graph_out(sample_db: Path, tmp_path: Path) -> None:
    original = read_network(sample_db)
    copy = tmp_path / "copy.db"
    write_network(original, copy)
    back = read_network(copy)
    assert back.info == original.info
    assert back.nodes == original.nodes
    assert len(back.edges) == len(original.edges)
    assert all(a.same_as(b, tol_m=0.0) for a, b in zip(original.edges, back.edges))


def test_metadata(sample_db: Path) -> None:
    info = read_info(sample_db)
    assert info.epsg == 32632
    assert info.source_name == "monaco.osm.gz" and len(info.source_sha256) == 64
    w, s, e, n = info.bbox_wgs84
    assert 7.40 < w < e < 7.45 and 43.71 < s < n < 43.76
    assert 150 < info.node_count < 400 and 350 < info.edge_count < 800
    assert info.longest_edge_m >= info.max_adjacent_node_distance_m > 100
    assert info.consolidate_m == 8.0 and info.network == "drive"


def test_rtree_bbox_query_matches_a_scan(sample_db: Path) -> None:
    net = read_network(sample_db)
    bbox = (7.420, 43.730, 7.425, 43.735)
    expected = {(e.u, e.v, e.key) for e in net.edges
                if e.lonlat[:, 0].max() >= bbox[0] and e.lonlat[:, 0].min() <= bbox[2]
                and e.lonlat[:, 1].max() >= bbox[1] and e.lonlat[:, 1].min() <= bbox[3]}
    got = {(e.u, e.v, e.key) for e in read_edges_in_bbox(sample_db, bbox)}
    assert got == expected and len(got) > 5


def test_failed_write_leaves_nothing_and_keeps_the_old_database(
    sample_db: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    target = tmp_path / "map.db"
    target.write_bytes(sample_db.read_bytes())
    before = target.read_bytes()
    network = read_network(sample_db)

    def boom(*_: object) -> None:
        raise sqlite3.OperationalError("disk I/O error")

    monkeypatch.setattr("roadgraph.store._insert", boom)
    with pytest.raises(MapDatabaseError, match=r"map\.db: cannot write the database: disk I/O"):
        write_network(network, target)
    assert target.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.db"]


def test_failed_import_leaves_no_database(tmp_path: Path) -> None:
    bad = tmp_path / "bad.osm"
    bad.write_text("<osm><node")
    with pytest.raises(Exception, match="unreadable OSM data"):
        import_map(tmp_path / "out.db", source=bad)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.osm"]


def test_unwritable_output(tmp_path: Path) -> None:
    with pytest.raises(MapDatabaseError, match=r"out\.db: cannot write here"):
        import_map(tmp_path / "no" / "such" / "out.db", source=tmp_path / "x.osm")


def test_schema_version_mismatch(sample_db: Path, tmp_path: Path) -> None:
    old = tmp_path / "old.db"
    old.write_bytes(sample_db.read_bytes())
    with sqlite3.connect(old) as conn:
        conn.execute("PRAGMA user_version = 99")
    with pytest.raises(SchemaVersionError, match=r"old\.db: schema version 99"):
        RoadGraph.open(old)


def test_not_a_database(tmp_path: Path) -> None:
    junk = tmp_path / "junk.db"
    junk.write_text("hello")
    with pytest.raises(MapDatabaseError, match=r"junk\.db: not a road-graph database"):
        read_info(junk)
    empty = tmp_path / "empty.db"
    sqlite3.connect(empty).close()
    with pytest.raises(MapDatabaseError, match=r"empty\.db: not a road-graph database"):
        read_info(empty)
    with pytest.raises(MapDatabaseError, match=r"missing\.db: no such road-graph database"):
        read_info(tmp_path / "missing.db")


def test_info_is_frozen_data(sample_db: Path) -> None:
    info = read_info(sample_db)
    with pytest.raises(dataclasses.FrozenInstanceError):
        info.node_count = 0  # type: ignore[misc]


def test_a_version_1_database_still_opens(sample_db: Path, tmp_path: Path) -> None:
    """Written before the arrays table: opened from its rows, with the same answers."""
    old = tmp_path / "v1.db"
    old.write_bytes(sample_db.read_bytes())
    with sqlite3.connect(old) as conn:
        conn.execute("DROP TABLE arrays")
        conn.execute("PRAGMA user_version = 1")
    graph, new = RoadGraph.open(old), RoadGraph.open(sample_db)
    assert graph.info == new.info and len(graph.edges) == len(new.edges)
    node = new.nodes[0]
    assert graph.edges_near(node.x_m, node.y_m, 50.0) == new.edges_near(node.x_m, node.y_m, 50.0)
