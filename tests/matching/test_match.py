"""`navsvc match` against GraphHopper's own test expectations, and bad traces."""

import json
import math
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from navsvc.cli import main
from navsvc.errors import TraceError
from navsvc.matching.hmm import HmmConfig
from navsvc.wire.route import match_trace
from navsvc.wire.traces import TraceFix, clean, parse_trace
from roadgraph import RoadGraph, import_map
from tests.conftest import DATA

GH = DATA / "graphhopper"
EXPECTED = {t["gpx"].rsplit("/", 1)[-1]: t
            for t in json.loads((GH / "expected.json").read_text())["tracks"]}
MAPS = {"issue-13.gpx": "map-issue13.osm.gz", "issue-127.gpx": "map-issue13.osm.gz",
        "issue-70.gpx": "issue-70.osm.gz", "andorra_for_map_matching.gpx": "andorra.osm.pbf"}


@pytest.fixture(scope="module")
def gh_maps(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("gh")
    out = {}
    for source in set(MAPS.values()):
        out[source] = folder / (source.split(".")[0] + ".db")
        import_map(out[source], source=GH / source)
    return out


def run_match(gpx: str, gh_maps: dict[str, Path], tmp_path: Path, sigma: float) -> dict:
    out = tmp_path / "route.json"
    assert main(["match", str(GH / gpx), "--map", str(gh_maps[MAPS[gpx]]), "-o", str(out),
                 "--sigma", str(sigma)]) == 0
    return json.loads(out.read_text())


@pytest.mark.parametrize("gpx", list(MAPS))
def test_graphhopper_expectations(gpx: str, gh_maps: dict[str, Path], tmp_path: Path) -> None:
    track = EXPECTED[gpx]
    for a in track["assertions"]:
        route = run_match(gpx, gh_maps, tmp_path, a["sigma_m"])
        (segment,) = route["segments"]
        if "match_length_equals_gpx_length_m" in a:
            tolerance = a["match_length_equals_gpx_length_m"]["tolerance_m"]
            assert abs(route["length_m"] - track["our_gpx_length_m"]) <= tolerance
        if "streets" in a:
            assert [s for s in segment["streets"] if s] == a["streets"]
        if "match_length_over_gpx_length_max" in a:
            assert route["length_m"] / track["our_gpx_length_m"] <= \
                a["match_length_over_gpx_length_max"]
            assert segment["edges"]  # edge matches non-empty
        # consecutive edges are contiguous, every matched point lies on a route edge
        edges = segment["edges"]
        assert all(x["v"] == y["u"] for x, y in zip(edges[:-1], edges[1:]))
        on_route = {(e["u"], e["v"], e["key"]) for e in edges}
        for p in route["points"]:
            if p["matched"]:
                m = p["matched"]["edge"]
                assert (m["u"], m["v"], m["key"]) in on_route


def test_two_identical_points_issue_127(gh_maps: dict[str, Path], tmp_path: Path) -> None:
    route = run_match("issue-127.gpx", gh_maps, tmp_path, 10.0)
    assert route["length_m"] == 0.0 and len(route["segments"]) == 1
    assert all(p["matched"] for p in route["points"])


def test_far_outside_the_map_is_a_clear_error(sample_graph: RoadGraph) -> None:
    with pytest.raises(TraceError, match="no point of the trace is within 30 m"):
        match_trace(sample_graph, [TraceFix(0, 0.0, 0.0), TraceFix(1, 0.001, 0.0)])


def test_empty_and_too_many_points(sample_graph: RoadGraph) -> None:
    with pytest.raises(TraceError, match="no points"):
        parse_trace("lat,lon\n", "csv")
    fixes = [TraceFix(i, 43.73 + i * 1e-6, 7.42) for i in range(30)]
    with pytest.raises(TraceError, match="limit is 20"):
        match_trace(sample_graph, fixes, HmmConfig(max_points=20))


def test_unsorted_and_duplicates_are_sorted_and_dropped() -> None:
    fixes = [TraceFix(2, 1, 1), TraceFix(1, 0, 0), TraceFix(2, 1, 1), TraceFix(3, 2, 2)]
    assert clean(fixes) == [TraceFix(1, 0, 0), TraceFix(2, 1, 1), TraceFix(3, 2, 2)]


def test_gap_the_graph_cannot_bridge_splits(tmp_path: Path) -> None:
    import networkx as nx

    from tests.roadgraph.test_graph import FRAME
    g = nx.MultiDiGraph()
    x0, y0 = FRAME.to_local(7.42, 43.73)
    for n, dx in enumerate((0, 300, 1000, 1300)):  # two roads with no link between them
        g.add_node(n, x=x0 + dx, y=y0)
    g.add_edge(0, 1, name="west road")
    g.add_edge(2, 3, name="east road")
    graph = RoadGraph.from_networkx(g, FRAME)
    fixes = []
    for i, dx in enumerate((20, 120, 220, 1020, 1120, 1220)):
        lon, lat = FRAME.to_wgs84(x0 + dx, y0 + 2.0)
        fixes.append(TraceFix(float(i), lat, lon))
    route = match_trace(graph, fixes)
    assert [s["streets"] for s in route["segments"]] == [["west road"], ["east road"]]
    assert route["segments"][0]["length_m"] == pytest.approx(200.0, abs=0.5)


def test_formats_agree() -> None:
    gpx = ('<gpx><trk><trkseg><trkpt lat="43.73" lon="7.42"><time>2024-01-01T00:00:00Z'
           '</time></trkpt><trkpt lat="43.731" lon="7.421"><time>2024-01-01T00:00:01Z</time>'
           '</trkpt></trkseg></trk></gpx>')
    csv = "time,lat,lon\n2024-01-01T00:00:00Z,43.73,7.42\n2024-01-01T00:00:01Z,43.731,7.421\n"
    geo = json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "geometry": {"type": "Point", "coordinates": [7.42, 43.73]},
         "properties": {"time": "2024-01-01T00:00:00Z"}},
        {"type": "Feature", "geometry": {"type": "Point", "coordinates": [7.421, 43.731]},
         "properties": {"time": "2024-01-01T00:00:01Z"}}]})
    t0 = 1704067200.0
    jsonl = f'{{"t": {t0}, "kind": "gps", "lat": 43.73, "lon": 7.42}}\n' \
            f'{{"t": {t0 + 1}, "kind": "imu", "yaw_rate_dps": 1}}\n' \
            f'{{"t": {t0 + 1}, "lat": 43.731, "lon": 7.421}}\n'
    expected = [TraceFix(t0, 43.73, 7.42), TraceFix(t0 + 1, 43.731, 7.421)]
    for text, fmt in ((gpx, "gpx"), (csv, "csv"), (geo, "geojson"), (jsonl, "jsonl")):
        assert parse_trace(text, fmt) == expected, fmt


@pytest.mark.parametrize(("text", "fmt", "message"), [
    ("lat,lon\n43.7,abc\n", "csv", "trace:2: lat/lon"),
    ("x,y\n1,2\n", "csv", "trace:1: the header needs lat and lon"),
    ("<gpx><trkpt lat='95' lon='0'/></gpx>", "gpx", "point 1: lat=95.0"),
    ("<gpx><trkpt", "gpx", "not valid GPX"),
    ('{"type": "Polygon"}', "geojson", "expected a LineString"),
    ('{"lat": 1, "lon": 2}\n{oops\n', "jsonl", "trace:2: not JSON"),
    ("t,lat,lon\nyesterday,1,2\n", "csv", "neither seconds nor ISO 8601"),
])
def test_bad_traces_name_the_line(text: str, fmt: str, message: str) -> None:
    with pytest.raises(TraceError, match=message):
        parse_trace(text, fmt)


@given(st.lists(st.tuples(st.floats(-89, 89), st.floats(-179, 179),
                          st.floats(0, 1e9)), min_size=1, max_size=20))
def test_csv_round_trip(rows: list[tuple[float, float, float]]) -> None:
    text = "lat,lon,t\n" + "".join(f"{a!r},{b!r},{t!r}\n" for a, b, t in rows)
    parsed = parse_trace(text, "csv")
    assert [(f.lat_deg, f.lon_deg, f.t) for f in parsed] == rows
    assert all(math.isfinite(f.t) for f in parsed)
