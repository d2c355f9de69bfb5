"""Reading OpenStreetMap data into a raw networkx graph (I/O).

Local files (``.osm``, ``.osm.gz``, ``.osm.bz2``, ``.osm.pbf``) are read offline with pyosmium,
keeping only the ways of the requested network (``osmnx.graph_from_xml`` would otherwise keep
buildings and land use too), then handed to osmnx. A ``.graphml`` file is a graph osmnx already
built and saved (``osmnx.save_graphml``); it is taken as it is, without filtering.
``--place`` and ``--bbox`` go through osmnx's Overpass download and need a network.

The result is osmnx's unsimplified graph in WGS84; :mod:`roadgraph.build` turns it into the
intersection graph.
"""

from __future__ import annotations

import hashlib
import logging
import tempfile
from collections.abc import Mapping
from pathlib import Path

import networkx as nx
import osmium

from roadgraph.errors import MapSourceError, NoDrivableRoadError

log = logging.getLogger(__name__)


# Highway classes a car drives on (osmnx's "drive" network; "drive_service" adds service roads).
_DRIVE_HIGHWAYS = frozenset(
    """motorway motorway_link trunk trunk_link primary primary_link secondary secondary_link
    tertiary tertiary_link unclassified residential living_street road""".split()
)
# Tag values that exclude a way from any drivable network, as osmnx's filters do.
_EXCLUDED = {
    "area": {"yes"},
    "access": {"private", "no"},
    "motor_vehicle": {"no", "private"},
    "motorcar": {"no", "private"},
}
_EXCLUDED_SERVICE = {"drive": set(), "drive_service": {"emergency_access", "parking",
                                                       "parking_aisle", "private"}}

NETWORK_TYPES = ("drive", "drive_service")


def is_drivable(tags: Mapping[str, str], network: str = "drive") -> bool:
    """Whether a way with these OSM tags belongs to the network (``drive``/``drive_service``)."""
    highway = tags.get("highway")
    if highway is None:
        return False
    if any(tags.get(key) in values for key, values in _EXCLUDED.items()):
        return False
    if highway == "service" and network == "drive_service":
        return tags.get("service") not in _EXCLUDED_SERVICE[network]
    return highway in _DRIVE_HIGHWAYS


def file_sha256(path: Path) -> str:
    """SHA-256 of a file, hex-encoded (recorded in the database for provenance)."""
    digest = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def read_osm_file(path: Path, network: str = "drive") -> nx.MultiDiGraph:
    """Read a local OSM file into osmnx's unsimplified WGS84 graph of the drivable roads."""
    import osmnx as ox  # slow to import (1 s): the service, which never imports, goes without

    _check_network(network)
    _check_file(path)
    with tempfile.TemporaryDirectory(prefix="roadgraph-") as tmp:
        filtered = Path(tmp) / "roads.osm"
        kept = _filter_roads(path, filtered, network)
        if kept == 0:
            raise NoDrivableRoadError(f"{path}: no drivable road (network {network!r}) in the file")
        log.info("%s: kept %d %s ways", path, kept, network)
        try:
            return ox.graph_from_xml(filtered, simplify=False, retain_all=True)
        except Exception as exc:  # osmnx raises bare ValueError/KeyError on odd content
            raise MapSourceError(f"{path}: osmnx could not build a graph: {exc}") from exc


def read_graphml(path: Path) -> nx.MultiDiGraph:
    """Read a graph saved by ``osmnx.save_graphml`` (WGS84; simplified or not)."""
    import osmnx as ox

    _check_file(path)
    try:
        graph: nx.MultiDiGraph = ox.load_graphml(path)
    except Exception as exc:  # XML errors, missing attributes, bad literals
        raise MapSourceError(f"{path}: not an osmnx GraphML graph: {exc}") from exc
    if str(graph.graph.get("crs", "")).lower() not in ("epsg:4326", "wgs84"):
        raise MapSourceError(f"{path}: GraphML graph must be in epsg:4326 (WGS84), "
                             f"not {graph.graph.get('crs')!r}")
    return graph


def _check_file(path: Path) -> None:
    if not path.exists():
        raise MapSourceError(f"{path}: no such file")
    if not path.is_file():
        raise MapSourceError(f"{path}: not a regular file")


def _filter_roads(src: Path, dst: Path, network: str) -> int:
    """Copy the network's ways, and the nodes they reference, from ``src`` to an OSM XML file."""
    kept = 0
    try:
        with osmium.BackReferenceWriter(str(dst), ref_src=str(src), overwrite=True) as writer:
            ways = osmium.FileProcessor(str(src), osmium.osm.WAY).with_filter(
                osmium.filter.KeyFilter("highway")
            )
            for way in ways:
                if is_drivable(dict(way.tags), network):
                    writer.add(way)
                    kept += 1
    except RuntimeError as exc:  # libosmium: truncated or malformed PBF/XML, bad compression
        raise MapSourceError(f"{src}: unreadable OSM data: {exc}") from exc
    return kept


def download_graph(
    *, place: str | None = None, bbox: tuple[float, float, float, float] | None = None,
    network: str = "drive",
) -> nx.MultiDiGraph:
    """Download the network for a place name or a ``(west, south, east, north)`` box via osmnx."""
    import osmnx as ox

    _check_network(network)
    what = f"place {place!r}" if place is not None else f"bbox {bbox}"
    try:
        if place is not None:
            return ox.graph_from_place(place, network_type=network, simplify=False,
                                       retain_all=True)
        if bbox is not None:
            return ox.graph_from_bbox(bbox, network_type=network, simplify=False,
                                      retain_all=True)
    except ox._errors.InsufficientResponseError as exc:
        raise NoDrivableRoadError(
            f"{what}: no such place, or no drivable road there ({exc})") from exc
    except (TypeError, ValueError) as exc:  # osmnx: geocoder found nothing or not a polygon
        raise MapSourceError(f"{what}: unknown or unusable place: {exc}") from exc
    except OSError as exc:  # requests' ConnectionError is an OSError
        raise MapSourceError(
            f"{what}: cannot reach the OpenStreetMap servers (offline?): {exc}. "
            "Import a local .osm/.osm.pbf file instead."
        ) from exc
    raise ValueError("download_graph needs place or bbox")


def _check_network(network: str) -> None:
    if network not in NETWORK_TYPES:
        raise MapSourceError(f"unknown network type {network!r}; choose from {NETWORK_TYPES}")
