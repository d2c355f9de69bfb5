import json
import subprocess
import sys
from pathlib import Path

import pytest

from roadgraph.cli import main, parse_bbox
from tests.conftest import DATA, SAMPLE_OSM

GH = DATA / "graphhopper"


@pytest.mark.parametrize(("name", "min_nodes", "min_edges"), [
    ("map-issue13.osm.gz", 20, 50),
    ("issue-70.osm.gz", 30, 60),
    ("andorra.osm.pbf", 700, 1500),
])
def test_import_peer_maps(tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str,
                          min_nodes: int, min_edges: int) -> None:
    db = tmp_path / "out.db"
    assert main(["import", str(GH / name), "-o", str(db), "--json", "-q"]) == 0
    assert capsys.readouterr().out == ""  # --quiet prints nothing
    assert main(["info", str(db), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["node_count"] >= min_nodes and info["edge_count"] >= min_edges
    assert info["source_name"] == name


def test_info_text(sample_db: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["info", str(sample_db)]) == 0
    out = capsys.readouterr().out
    assert "EPSG:32632" in out and "max adjacent-node distance" in out
    assert "consolidated within 8 m" in out


def test_consolidation_option_reduces_nodes(tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    src = str(GH / "issue-70.osm.gz")
    counts = []
    for tol in ("0", "15"):
        db = tmp_path / f"t{tol}.db"
        assert main(["import", src, "-o", str(db), "--consolidate-m", tol, "--json"]) == 0
        counts.append(json.loads(capsys.readouterr().out)["node_count"])
    assert counts[0] > counts[1]


def test_export_geojson(sample_db: Path, tmp_path: Path) -> None:
    out = tmp_path / "edges.geojson"
    assert main(["export", str(sample_db), "--geojson", str(out), "--nodes"]) == 0
    data = json.loads(out.read_text())
    kinds = {f["geometry"]["type"] for f in data["features"]}
    assert kinds == {"LineString", "Point"}
    assert main(["export", str(sample_db), "--geojson", str(out),
                 "--bbox", "7.420,43.730,7.425,43.735"]) == 0
    part = json.loads(out.read_text())["features"]
    assert 0 < len(part) < len(data["features"])
    assert {f["geometry"]["type"] for f in part} == {"LineString"}
    assert main(["export", str(sample_db), "--geojson", str(out), "--nodes",
                 "--bbox", "7.420,43.730,7.425,43.735"]) == 0
    points = [f["geometry"]["coordinates"] for f in json.loads(out.read_text())["features"]
              if f["geometry"]["type"] == "Point"]
    assert points and all(7.420 <= lon <= 7.425 and 43.730 <= lat <= 43.735
                          for lon, lat in points)  # --nodes with --bbox: those inside


@pytest.mark.parametrize(("args", "message"), [
    (["import", "{tmp}/missing.osm", "-o", "{tmp}/o.db"],
     "roadgraph: error: {tmp}/missing.osm: no such file\n"),
    (["import", str(SAMPLE_OSM), "-o", "{tmp}/no/dir/o.db"],
     "roadgraph: error: {tmp}/no/dir/o.db: cannot write here: No such file or directory\n"),
    (["import", str(SAMPLE_OSM), "-o", "{tmp}"],
     "roadgraph: error: {tmp}: is a folder; give a database file name\n"),
    (["info", "{tmp}/missing.db"],
     "roadgraph: error: {tmp}/missing.db: no such road-graph database\n"),
])
def test_errors_exact_messages(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                               args: list[str], message: str) -> None:
    argv = [a.format(tmp=tmp_path) for a in args]
    assert main(argv) == 1
    assert capsys.readouterr().err == message.format(tmp=tmp_path)
    assert not (tmp_path / "o.db").exists()


def test_place_without_network_says_so(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                       monkeypatch: pytest.MonkeyPatch) -> None:
    import osmnx as ox
    import requests

    def offline(*_: object, **__: object) -> None:
        raise requests.exceptions.ConnectionError("Failed to resolve 'nominatim'")

    monkeypatch.setattr(ox, "graph_from_place", offline)
    assert main(["import", "--place", "Monaco", "-o", str(tmp_path / "m.db")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("roadgraph: error: place 'Monaco': cannot reach the OpenStreetMap "
                          "servers (offline?)")
    assert not (tmp_path / "m.db").exists()


def test_unknown_place(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                       monkeypatch: pytest.MonkeyPatch) -> None:
    import osmnx as ox

    def nothing(*_: object, **__: object) -> None:
        raise ox._errors.InsufficientResponseError("Nominatim geocoder returned 0 results")

    monkeypatch.setattr(ox, "graph_from_place", nothing)
    assert main(["import", "--place", "Atlantis", "-o", str(tmp_path / "m.db")]) == 1
    assert "place 'Atlantis': no such place, or no drivable road there" in capsys.readouterr().err


@pytest.mark.parametrize(("text", "error"), [
    ("1,2,3", "expected four numbers"),
    ("a,b,c,d", "must be numbers"),
    ("2,0,1,1", "need -180 <= W < E <= 180"),
    ("0,0,1,nan", "values must be finite"),
])
def test_bad_bbox(text: str, error: str) -> None:
    with pytest.raises(ValueError, match=error):
        parse_bbox(text)


def test_usage_errors_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["import", "x.osm", "-o", "o.db", "--consolidate-m", "-5"])
    assert exc.value.code == 2
    assert "must be between 0 and 100 metres" in capsys.readouterr().err
    assert main(["import", "-o", "o.db"]) == 2


def test_console_script_help() -> None:
    result = subprocess.run([sys.executable, "-m", "roadgraph.cli", "import", "--help"],
                            capture_output=True, text=True, check=True)
    for option in ("--place", "--bbox", "--network", "--consolidate-m", "--json", "--quiet"):
        assert option in result.stdout


def test_builder_option(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                        sample_db: Path) -> None:
    """``--builder arrays`` on the sample map: the same summary as osmnx's (the default for
    a map this small), and ``info`` says which built it."""
    db = tmp_path / "arrays.db"
    assert main(["import", str(SAMPLE_OSM), "-o", str(db), "--builder", "arrays",
                 "--json"]) == 0
    mine = json.loads(capsys.readouterr().out)
    assert main(["info", str(sample_db), "--json"]) == 0
    theirs = json.loads(capsys.readouterr().out)
    for key in ("node_count", "edge_count", "junction_count", "dead_end_count",
                "osm_ways_kept", "osm_missing_node_refs", "epsg", "bbox_wgs84"):
        assert mine[key] == pytest.approx(theirs[key]), key
    assert mine["road_length_m"] == pytest.approx(theirs["road_length_m"], abs=1e-3)
    assert mine["osmnx_version"] == "" and theirs["osmnx_version"]
    assert main(["info", str(db)]) == 0
    assert "with roadgraph" in capsys.readouterr().out
    with pytest.raises(SystemExit) as usage:
        main(["import", str(SAMPLE_OSM), "-o", str(db), "--builder", "networkx"])
    assert usage.value.code == 2
    assert "invalid choice: 'networkx'" in capsys.readouterr().err
