import bz2
import gzip
from pathlib import Path

import osmium
import pytest

from roadgraph.errors import MapSourceError, NoDrivableRoadError
from roadgraph.osm import is_drivable, read_osm_file
from tests.conftest import DATA, SAMPLE_OSM


@pytest.mark.parametrize(("tags", "network", "expected"), [
    ({"highway": "residential"}, "drive", True),
    ({"highway": "primary", "oneway": "yes"}, "drive", True),
    ({"highway": "footway"}, "drive", False),
    ({"highway": "steps"}, "drive", False),
    ({"building": "yes"}, "drive", False),
    ({"highway": "residential", "access": "private"}, "drive", False),
    ({"highway": "residential", "motor_vehicle": "no"}, "drive", False),
    ({"highway": "pedestrian", "area": "yes"}, "drive", False),
    ({"highway": "service"}, "drive", False),
    ({"highway": "service"}, "drive_service", True),
    ({"highway": "service", "service": "parking_aisle"}, "drive_service", False),
])
def test_drivable_filter(tags: dict[str, str], network: str, expected: bool) -> None:
    assert is_drivable(tags, network) is expected


def _xml(path: Path) -> bytes:
    return gzip.decompress(path.read_bytes())


def test_reads_every_supported_format(tmp_path: Path) -> None:
    plain = tmp_path / "monaco.osm"
    plain.write_bytes(_xml(SAMPLE_OSM))
    bz = tmp_path / "monaco.osm.bz2"
    bz.write_bytes(bz2.compress(plain.read_bytes()))
    pbf = tmp_path / "monaco.osm.pbf"
    with osmium.SimpleWriter(str(pbf)) as writer:
        for obj in osmium.FileProcessor(str(plain)):
            writer.add(obj)
    sizes = {(g.number_of_nodes(), g.number_of_edges())
             for g in (read_osm_file(p) for p in (SAMPLE_OSM, plain, bz, pbf))}
    assert len(sizes) == 1
    nodes, edges = sizes.pop()
    assert nodes > 1000 and edges > 2000


def test_keeps_only_roads() -> None:
    graph = read_osm_file(SAMPLE_OSM)
    highways = {str(d["highway"]) for _, _, d in graph.edges(data=True)}
    assert "footway" not in highways and "steps" not in highways
    assert {"primary", "secondary", "residential"} <= highways


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(MapSourceError, match=r"nope\.osm\.pbf: no such file"):
        read_osm_file(tmp_path / "nope.osm.pbf")


def test_folder_is_not_a_file(tmp_path: Path) -> None:
    with pytest.raises(MapSourceError, match="not a regular file"):
        read_osm_file(tmp_path)


def test_truncated_pbf(tmp_path: Path) -> None:
    data = (DATA / "graphhopper" / "andorra.osm.pbf").read_bytes()
    bad = tmp_path / "cut.osm.pbf"
    bad.write_bytes(data[: len(data) // 2])
    with pytest.raises(MapSourceError, match=r"cut\.osm\.pbf: unreadable OSM data: PBF error"):
        read_osm_file(bad)


def test_truncated_xml(tmp_path: Path) -> None:
    data = _xml(SAMPLE_OSM)
    bad = tmp_path / "cut.osm"
    bad.write_bytes(data[: len(data) // 2])
    with pytest.raises(MapSourceError, match=r"cut\.osm: unreadable OSM data: XML parsing error"):
        read_osm_file(bad)


def test_not_osm_at_all(tmp_path: Path) -> None:
    bad = tmp_path / "junk.osm.pbf"
    bad.write_bytes(b"this is not a protocol buffer" * 10)
    with pytest.raises(MapSourceError, match="unreadable OSM data"):
        read_osm_file(bad)


def test_no_drivable_road(tmp_path: Path) -> None:
    src = tmp_path / "paths.osm"
    src.write_text(
        '<?xml version="1.0"?><osm version="0.6">'
        '<node id="1" lat="43.7" lon="7.4" version="1"/>'
        '<node id="2" lat="43.71" lon="7.41" version="1"/>'
        '<way id="10" version="1"><nd ref="1"/><nd ref="2"/><tag k="highway" v="footway"/></way>'
        '</osm>')
    with pytest.raises(NoDrivableRoadError, match=r"paths\.osm: no drivable road"):
        read_osm_file(src)
