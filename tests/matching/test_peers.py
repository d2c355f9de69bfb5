"""`navsvc match` on the peer suites: FMM's Stockholm trips, mappymatch's Denver traces and
the Newson–Krumm Seattle trace (see tests/data/README.md for sources and licences)."""

import csv
import json
import time
from pathlib import Path

import osmnx as ox
import pytest
import shapely

from navsvc.cli import main
from navsvc.errors import TraceError
from navsvc.wire.route import match_trace
from navsvc.wire.traces import read_trace
from roadgraph import RoadGraph, import_map
from tests.conftest import DATA

FMM = DATA / "fmm"
MAPPYMATCH = DATA / "mappymatch"
SEATTLE = DATA / "newson-krumm" / "seattle.csv"


@pytest.fixture(scope="module")
def stockholm_db(tmp_path_factory: pytest.TempPathFactory) -> Path:
    # no consolidation: node ids stay OSM ids, so edges compare one to one with FMM's
    db = tmp_path_factory.mktemp("fmm") / "stockholm.db"
    import_map(db, source=FMM / "stockholm.graphml", consolidate_m=0.0)
    return db


@pytest.fixture(scope="module")
def denver_db(tmp_path_factory: pytest.TempPathFactory) -> Path:
    db = tmp_path_factory.mktemp("mappymatch") / "denver.db"
    import_map(db, source=MAPPYMATCH / "osmnx_drive_graph.graphml", consolidate_m=0.0)
    return db


def run_match(trace: Path, db: Path, tmp_path: Path, *extra: str) -> dict:
    out = tmp_path / "route.json"
    assert main(["match", str(trace), "--map", str(db), "-o", str(out), *extra]) == 0
    return json.loads(out.read_text())


def route_edges(route: dict) -> list[tuple[int, int, int]]:
    return [(e["u"], e["v"], e["key"]) for s in route["segments"] for e in s["edges"]]


def fmm_trips(tmp_path: Path) -> list[tuple[Path, list[tuple[int, int, int]]]]:
    """Each FMM trip as a GeoJSON trace, with FMM's matched path as (u, v, key) edges."""
    graph = ox.load_graphml(FMM / "stockholm.graphml")
    by_fid = {int(d["fid"]): (u, v, k) for u, v, k, d in graph.edges(keys=True, data=True)}
    trips = {row["id"]: shapely.from_wkt(row["geom"])
             for row in csv.DictReader((FMM / "trips.csv").open(), delimiter=";")}
    out = []
    for row in csv.DictReader((FMM / "mr.txt").open(), delimiter=";"):
        points = [{"type": "Feature", "properties": {},
                   "geometry": {"type": "Point", "coordinates": list(c)}}
                  for c in trips[row["id"]].coords]
        trace = tmp_path / f"trip{row['id']}.geojson"
        trace.write_text(json.dumps({"type": "FeatureCollection", "features": points}))
        out.append((trace, [by_fid[int(f)] for f in row["cpath"].split(",")]))
    return out


def test_fmm_stockholm_edge_by_edge(stockholm_db: Path, tmp_path: Path) -> None:
    # FMM's GPS error for these hand-drawn trips is 0.0005 degrees, about 30-55 m here
    for trace, expected in fmm_trips(tmp_path):
        assert route_edges(run_match(trace, stockholm_db, tmp_path, "--sigma", "30")) == expected


def test_fmm_stockholm_at_default_sigma_mostly_agrees(stockholm_db: Path, tmp_path: Path) -> None:
    # at 10 m the sparse hand-drawn points pull the route round a block: most edges still agree
    for trace, expected in fmm_trips(tmp_path):
        ours = route_edges(run_match(trace, stockholm_db, tmp_path))
        assert sum(e in ours for e in expected) / len(expected) >= 0.8


def assert_sound(route: dict, max_distance_m: float) -> None:
    """One contiguous route that every matched point lies on, close to its point."""
    (segment,) = route["segments"]
    edges = segment["edges"]
    assert edges and all(a["v"] == b["u"] for a, b in zip(edges[:-1], edges[1:]))
    on_route = {(e["u"], e["v"], e["key"]) for e in edges}
    for p in route["points"]:
        if p["matched"]:
            m = p["matched"]
            assert (m["edge"]["u"], m["edge"]["v"], m["edge"]["key"]) in on_route
            assert m["distance_m"] <= max_distance_m


def test_mappymatch_denver_trace(denver_db: Path, tmp_path: Path) -> None:
    route = run_match(MAPPYMATCH / "test_trace.geojson", denver_db, tmp_path)
    assert_sound(route, max_distance_m=10.0)
    assert all(p["matched"] for p in route["points"])
    # the route is about as long as the trace (16 points over ~840 m)
    assert abs(route["length_m"] - route["trace_length_m"]) <= 0.05 * route["trace_length_m"]


@pytest.mark.parametrize("variant", ["trace_bad_start.geojson",
                                     "test_trace_stationary_points.geojson"])
def test_mappymatch_bad_start_and_stationary_points_change_nothing(
        variant: str, denver_db: Path, tmp_path: Path) -> None:
    clean_route = run_match(MAPPYMATCH / "test_trace.geojson", denver_db, tmp_path)
    route = run_match(MAPPYMATCH / variant, denver_db, tmp_path)
    assert_sound(route, max_distance_m=10.0)
    assert route_edges(route) == route_edges(clean_route)


def test_mappymatch_bad_start_point_is_left_unmatched(denver_db: Path, tmp_path: Path) -> None:
    route = run_match(MAPPYMATCH / "trace_bad_start.geojson", denver_db, tmp_path)
    assert route["points"][0]["matched"] is None  # 3.7 km south of the map
    assert all(p["matched"] for p in route["points"][1:])


def test_mappymatch_trace_counts() -> None:
    # mappymatch's own tests/test_trace.py
    assert len(read_trace(MAPPYMATCH / "sample_trace_1.csv")) == 1053
    assert len(read_trace(MAPPYMATCH / "test_trace.gpx")) == 778


def test_trace_east_of_the_map_is_a_clear_error(denver_db: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["match", str(MAPPYMATCH / "test_trace.gpx"), "--map", str(denver_db)]) == 1
    assert "no point of the trace is within 30 m of a road of the map 'denver'" in \
        capsys.readouterr().err


def test_seattle_trace_reads_whole_and_fails_fast_off_the_map(sample_graph: RoadGraph) -> None:
    fixes = read_trace(SEATTLE)
    assert len(fixes) == 7531
    assert all(a.t < b.t for a, b in zip(fixes[:-1], fixes[1:]))
    start = time.perf_counter()
    with pytest.raises(TraceError, match="no point of the trace"):
        match_trace(sample_graph, fixes)  # Monaco: nowhere near Seattle
    assert time.perf_counter() - start < 30.0  # no hang: one index query per point
