"""Differential: roadgraph's array builder against the osmnx builder it replaces as the
default, on the real bundled maps, with and without consolidation.

Same nodes (by the OSM nodes merged into each), same edges between them (parallel edges
matched by length), same lengths, bearings and geometry within a micrometre, same tags; the
only freedom is in the order of values osmnx keeps as a set (a merged edge's name parts, its
ways, the highway class and speed limit it shows first).
"""

from __future__ import annotations

import dataclasses
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

from roadgraph.build import EdgeRecord, RoadNetwork, build_network
from roadgraph.intersections import build_intersection_graph
from roadgraph.osm import WAY_TAGS, read_osm, read_roads
from roadgraph.store import read_network, write_map
from tests.conftest import DATA, SAMPLE_OSM

MAPS = {"monaco": SAMPLE_OSM, "andorra": DATA / "graphhopper" / "andorra.osm.pbf",
        "istanbul": DATA / "graphhopper" / "map-issue13.osm.gz",
        "novi-sad": DATA / "graphhopper" / "issue-70.osm.gz"}
TOL_M = 1e-6


def _built(source: Path, consolidate_m: float, tmp_path: Path) -> RoadNetwork:
    roads, _ = read_roads(source)
    built = build_intersection_graph(roads, consolidate_m=consolidate_m, network="drive")
    db = tmp_path / "new.db"
    write_map(db, built.info, built.arrays, built.attributes)
    return read_network(db)


def _by_ends(net: RoadNetwork) -> dict[tuple[tuple[int, ...], tuple[int, ...]],
                                       list[EdgeRecord]]:
    osm = {n.id: tuple(sorted(n.osm_ids)) for n in net.nodes}
    out: dict[tuple[tuple[int, ...], tuple[int, ...]], list[EdgeRecord]] = defaultdict(list)
    for e in net.edges:
        out[(osm[e.u], osm[e.v])].append(e)
    return {k: sorted(v, key=lambda e: (round(e.length_m, 4), e.coords.size)) for k, v in
            out.items()}


def _way_tags(source: Path) -> dict[int, dict[str, str | None]]:
    roads, _ = read_roads(source)
    return {w: dict(zip(WAY_TAGS, t)) for w, t in zip(roads.way_ids.tolist(), roads.way_tags)}


def _same_edge(a: EdgeRecord, b: EdgeRecord, tags: dict[int, dict[str, str | None]]) -> None:
    assert a.length_m == pytest.approx(b.length_m, abs=TOL_M)
    assert a.coords.shape == b.coords.shape
    np.testing.assert_allclose(a.coords, b.coords, atol=TOL_M, rtol=0)
    np.testing.assert_allclose(a.lonlat, b.lonlat, atol=1e-11, rtol=0)
    assert a.bearing_start_rad == pytest.approx(b.bearing_start_rad, abs=1e-9)
    assert a.bearing_end_rad == pytest.approx(b.bearing_end_rad, abs=1e-9)
    assert set(a.osm_way_ids) == set(b.osm_way_ids)
    assert set((a.name or "").split("; ")) == set((b.name or "").split("; "))
    assert (a.oneway, a.lanes, a.tunnel, a.bridge) == (b.oneway, b.lanes, b.tunnel, b.bridge)
    ways = [tags[w] for w in a.osm_way_ids]
    assert {a.highway, b.highway} <= {t["highway"] for t in ways}
    assert {a.maxspeed, b.maxspeed} <= {t["maxspeed"] for t in ways} | {None}
    assert (a.maxspeed is None) == (b.maxspeed is None)


@pytest.mark.parametrize("consolidate_m", [8.0, 0.0])
@pytest.mark.parametrize("name", list(MAPS))
def test_array_builder_equals_osmnx_builder(name: str, consolidate_m: float,
                                            tmp_path: Path) -> None:
    source = MAPS[name]
    old = build_network(read_osm(source).graph, consolidate_m=consolidate_m)
    new = _built(source, consolidate_m, tmp_path)
    assert len(new.nodes) == len(old.nodes) and len(new.edges) == len(old.edges)
    old_nodes = {tuple(sorted(n.osm_ids)): n for n in old.nodes}
    new_nodes = {tuple(sorted(n.osm_ids)): n for n in new.nodes}
    assert new_nodes.keys() == old_nodes.keys()
    for key, n in new_nodes.items():
        o = old_nodes[key]
        assert (n.x_m, n.y_m) == pytest.approx((o.x_m, o.y_m), abs=TOL_M)
        assert (n.lon_deg, n.lat_deg) == pytest.approx((o.lon_deg, o.lat_deg), abs=1e-11)
        assert n.degree == o.degree
    old_edges, new_edges = _by_ends(old), _by_ends(new)
    assert new_edges.keys() == old_edges.keys()
    tags = _way_tags(source)
    for ends, edges in new_edges.items():
        assert len(edges) == len(old_edges[ends])
        for a, b in zip(edges, old_edges[ends]):
            _same_edge(a, b, tags)
    skip = {"osmnx_version", "created_utc", "total_length_m", "road_length_m"}
    new_info, old_info = dataclasses.asdict(new.info), dataclasses.asdict(old.info)
    for field, value in old_info.items():
        if field not in skip:
            assert new_info[field] == pytest.approx(value, abs=1e-6), field
    assert new.info.total_length_m == pytest.approx(old.info.total_length_m, abs=1e-3)
    assert new.info.road_length_m == pytest.approx(old.info.road_length_m, abs=1e-3)
