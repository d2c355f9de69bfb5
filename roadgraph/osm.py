"""Reading OpenStreetMap data into a raw networkx graph (I/O).

Local files (``.osm``, ``.osm.gz``, ``.osm.bz2``, ``.osm.pbf``) are read offline with pyosmium in
two passes: the ways of the requested network first (``osmnx.graph_from_xml`` would otherwise
keep buildings and land use too), then the nodes they reference. The roads are then handed to
osmnx through a temporary OSM XML file. A ``.graphml`` file is a graph osmnx already built and
saved (``osmnx.save_graphml``); it is taken as it is, without filtering. ``--place`` and
``--bbox`` go through osmnx's Overpass download and need a network.

Clipped extracts (``osmium extract --strategy simple``, a bounding-box cut, many city extracts)
keep ways whose nodes lie partly outside the file. Such a way is cut at the extract's edge: the
references to missing nodes are dropped and the way is split where a gap opens, each piece of two
or more nodes keeping the way's id and tags; a way left with fewer than two nodes is dropped.
:class:`ReadReport` counts what was kept, cut and dropped, for the import summary.

Refused with a message naming the file: change files (``.osc``), history files (several
versions of an object), duplicate node or way ids, and files without a drivable road. Objects a
JOSM file marks ``action="delete"`` are left out (libosmium reads them as live objects).

The result is osmnx's unsimplified graph in WGS84; :mod:`roadgraph.build` turns it into the
intersection graph.
"""

from __future__ import annotations

import bz2
import gzip
import hashlib
import io
import logging
import re
import tempfile
from collections import Counter
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import networkx as nx
import osmium
from tqdm import tqdm

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

# Node tags osmnx keeps (osmnx.settings.useful_tags_node).
_NODE_TAGS = ("highway", "junction", "railway", "ref")
_CHANGE_SUFFIXES = (".osc", ".osc.gz", ".osc.bz2")
_HISTORY_SUFFIXES = (".osh", ".osh.gz", ".osh.bz2", ".osh.pbf")
_JOSM_DELETE = re.compile(rb"<(node|way)\b[^>]*\baction=[\"']delete[\"'][^>]*>")
_ID_ATTR = re.compile(rb"\bid=[\"'](-?\d+)[\"']")

Stage = Callable[[str], None]


@dataclass(frozen=True)
class ReadReport:
    """What reading an OSM file kept and dropped, and why (the import summary's source part)."""

    ways_kept: int  # ways of the network in the graph, whole or cut
    ways_cut: int  # of those, cut at the extract's edge (some node references missing)
    ways_dropped_outside: int  # fewer than two of the way's nodes in the file
    ways_dropped_one_node: int  # a way of a single node (malformed)
    ways_not_in_network: int  # highway=* ways of other classes (footway, steps, private...)
    missing_node_refs: int  # references from network ways to nodes not in the file
    negative_ids: int  # nodes and ways with negative ids (new in JOSM, not in OpenStreetMap)
    josm_deleted: int  # objects a JOSM file marks action="delete", left out
    invalid_locations: int = 0  # road nodes outside +-90 deg / +-180 deg, taken as missing


@dataclass(frozen=True)
class OsmRead:
    """The raw graph of a local file, with the report of what was read."""

    graph: nx.MultiDiGraph
    report: ReadReport


@dataclass
class _Ways:
    """Pass 1: the network's ways, their references and tags."""

    refs: dict[int, tuple[int, ...]] = field(default_factory=dict)
    tags: dict[int, dict[str, str]] = field(default_factory=dict)
    versions: dict[int, int] = field(default_factory=dict)
    other: Counter[str] = field(default_factory=Counter)  # highway class of non-network ways
    one_node: int = 0
    negative: int = 0


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
    return read_osm(path, network).graph


def read_osm(path: Path, network: str = "drive", *, progress: bool = False,
             stage: Stage | None = None) -> OsmRead:
    """Read a local OSM file, clipped or not, into a raw graph and a :class:`ReadReport`.

    ``stage`` is called with the name of each step as it starts (the importer's progress bar).
    """
    _check_network(network)
    _check_file(path)
    _check_kind(path)
    step = stage or (lambda _: None)
    deleted = _josm_deleted_ids(path)
    step("reading ways")
    ways = _scan_ways(path, network, deleted, progress)
    _check_some_ways(path, network, ways)
    step("reading nodes")
    nodes, negative_nodes, invalid = _read_nodes(path, _needed_nodes(ways, deleted), progress)
    pieces, cut, outside, missing = _clip(ways, nodes)
    report = ReadReport(
        ways_kept=len({way_id for way_id, _ in pieces}), ways_cut=cut,
        ways_dropped_outside=outside, ways_dropped_one_node=ways.one_node,
        ways_not_in_network=sum(ways.other.values()), missing_node_refs=missing,
        negative_ids=ways.negative + negative_nodes, josm_deleted=len(deleted),
        invalid_locations=invalid,
    )
    if not pieces:
        raise NoDrivableRoadError(
            f"{path}: no drivable road inside the extract: each of the {len(ways.refs)} "
            f"{network} ways has fewer than two of its nodes in the file "
            f"({missing} node references missing)")
    log.info("%s: %s", path, report)
    step("building the raw graph (osmnx)")
    return OsmRead(graph=_graph_from_pieces(path, pieces, ways, nodes), report=report)


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


def _change_file_error(path: Path) -> MapSourceError:
    return MapSourceError(
        f"{path}: an OSM change file (osmChange), not an extract: apply it to an extract "
        f"first (osmium apply-changes EXTRACT.osm.pbf {path.name} -o NEW.osm.pbf)")


def _history_file_error(path: Path, detail: str) -> MapSourceError:
    return MapSourceError(
        f"{path}: an OSM history file ({detail}), not an extract: take one moment of it "
        f"first (osmium time-filter {path.name} -o EXTRACT.osm.pbf)")


def _check_kind(path: Path) -> None:
    """Refuse change and history files, which libosmium reads without complaint."""
    name = path.name.lower()
    if name.endswith(_CHANGE_SUFFIXES):
        raise _change_file_error(path)
    if name.endswith(_HISTORY_SUFFIXES):
        raise _history_file_error(path, "named .osh")
    try:
        reader = osmium.io.Reader(str(path), osmium.osm.NOTHING)
        multiple = reader.header().has_multiple_object_versions
        reader.close()
    except RuntimeError as exc:  # libosmium: unknown format, bad compression
        raise MapSourceError(f"{path}: unreadable OSM data: {exc}") from exc
    if multiple:
        if b"<osmChange" in _head(path):
            raise _change_file_error(path)
        raise _history_file_error(path, "its header says it holds several versions of objects")


def _open_text(path: Path) -> io.BufferedIOBase:
    name = path.name.lower()
    if name.endswith(".gz"):
        return gzip.open(path, "rb")
    if name.endswith(".bz2"):
        return bz2.open(path, "rb")
    return path.open("rb")


def _head(path: Path, size: int = 4096) -> bytes:
    if path.name.lower().endswith(".pbf"):
        return b""
    try:
        with _open_text(path) as f:
            return f.read(size)
    except (OSError, EOFError):
        return b""


def _josm_deleted_ids(path: Path) -> frozenset[tuple[str, int]]:
    """``("node"|"way", id)`` of the objects a JOSM XML file marks ``action="delete"``."""
    if b"JOSM" not in _head(path, 1024):
        return frozenset()
    found = set()
    with _open_text(path) as f:
        for line in f:
            for match in _JOSM_DELETE.finditer(line):
                ident = _ID_ATTR.search(match.group(0))
                if ident is not None:
                    found.add((match.group(1).decode(), int(ident.group(1))))
    return frozenset(found)


def _objects(path: Path, entity: osmium.osm.osm_entity_bits,
             filters: tuple[osmium.BaseFilter, ...]) -> Iterator[Any]:
    """The file's objects of one kind (``Any``: pyosmium's union of kinds has no narrowing)."""
    try:
        processor = osmium.FileProcessor(str(path), entity)
        for f in filters:
            processor = processor.with_filter(f)
        yield from processor
    except RuntimeError as exc:  # libosmium: truncated or malformed PBF/XML, bad compression
        raise MapSourceError(f"{path}: unreadable OSM data: {exc}") from exc


def _counter(progress: bool, what: str) -> tqdm[None]:
    """A count of objects read, without a total or an estimate: neither is known in advance."""
    return tqdm(desc=f"  {what} read", bar_format="{desc}: {n_fmt} [{elapsed}, {rate_fmt}]",
                unit=" objects", leave=False, position=1, mininterval=0.5,
                disable=None if progress else True)


def _scan_ways(path: Path, network: str, deleted: frozenset[tuple[str, int]],
               progress: bool) -> _Ways:
    """Pass 1: the ``highway=*`` ways, those of the network kept with references and tags."""
    ways = _Ways()
    seen: dict[int, int] = {}
    with _counter(progress, "highway ways") as bar:
        for way in _objects(path, osmium.osm.WAY, (osmium.filter.KeyFilter("highway"),)):
            bar.update()
            _check_unique(path, "way", way, seen)
            if ("way", way.id) in deleted:
                continue
            tags = dict(way.tags)
            if not is_drivable(tags, network):
                ways.other[tags.get("highway", "")] += 1
                continue
            ways.negative += way.id < 0
            refs = tuple(n.ref for n in way.nodes)
            if len(set(refs)) < 2:
                ways.one_node += 1
                continue
            ways.refs[way.id], ways.tags[way.id] = refs, tags
    return ways


def _check_unique(path: Path, kind: str, obj: Any, seen: dict[int, int]) -> None:
    """Refuse a repeated id (a history file when the versions differ) or a deleted object."""
    if obj.deleted:
        raise _history_file_error(path, f"{kind} {obj.id} is marked deleted (visible=false)")
    if obj.id in seen:
        if seen[obj.id] != obj.version:
            raise _history_file_error(
                path, f"{kind} {obj.id} appears in versions {seen[obj.id]} and {obj.version}")
        raise MapSourceError(
            f"{path}: {kind} {obj.id} appears twice: duplicate ids (two extracts concatenated? "
            "combine them with osmium merge)")
    seen[obj.id] = obj.version


def _check_some_ways(path: Path, network: str, ways: _Ways) -> None:
    if ways.refs:
        return
    if ways.one_node:
        raise NoDrivableRoadError(
            f"{path}: no drivable road: each of the {ways.one_node} {network} ways has only "
            "one node")
    if not ways.other:
        raise NoDrivableRoadError(
            f"{path}: no drivable road (network {network!r}) in the file: no way is tagged "
            "highway=*")
    classes = ", ".join(f"{name or '?'} {n}" for name, n in ways.other.most_common(6))
    hint = "; --network drive_service keeps service roads" \
        if network == "drive" and "service" in ways.other else ""
    raise NoDrivableRoadError(
        f"{path}: no drivable road (network {network!r}) in the file: its "
        f"{sum(ways.other.values())} highway ways are not for cars ({classes}){hint}")


def _needed_nodes(ways: _Ways, deleted: frozenset[tuple[str, int]]) -> set[int]:
    needed = {ref for refs in ways.refs.values() for ref in refs}
    return needed - {i for kind, i in deleted if kind == "node"}


def _read_nodes(path: Path, needed: set[int], progress: bool
                ) -> tuple[dict[int, tuple[float, float, dict[str, str]]], int, int]:
    """Pass 2: location and osmnx's node tags of each needed node present in the file.

    Also the number of those with a negative id, and of those with an invalid location.
    """
    nodes: dict[int, tuple[float, float, dict[str, str]]] = {}
    seen: dict[int, int] = {}
    invalid = 0
    # libosmium's id filter takes unsigned ids only: with negative ids, filter here
    negative = any(i < 0 for i in needed)
    filters = () if negative else (osmium.filter.IdFilter(needed),)
    with _counter(progress, "road nodes") as bar:
        for node in _objects(path, osmium.osm.NODE, filters):
            bar.update()
            if negative and node.id not in needed:
                continue
            _check_unique(path, "node", node, seen)
            if not node.location.valid():
                invalid += 1
                continue
            tags = {k: node.tags[k] for k in _NODE_TAGS if k in node.tags}
            nodes[node.id] = (node.location.lon, node.location.lat, tags)
    return nodes, sum(1 for i in nodes if i < 0), invalid


def clip_refs(refs: tuple[int, ...], present: Callable[[int], bool]) -> list[tuple[int, ...]]:
    """The runs of a way's references whose nodes are present, each of two nodes or more.

    A closed way (first reference = last) is a ring: a run through its closing node is one piece.
    """
    closed = len(refs) > 2 and refs[0] == refs[-1]
    if closed and all(present(r) for r in refs):
        return [refs]
    if closed:
        ring = refs[:-1]
        start = next(i for i, r in enumerate(ring) if not present(r))
        refs = ring[start:] + ring[:start]
    runs: list[list[int]] = [[]]
    for ref in refs:
        if present(ref):
            runs[-1].append(ref)
        elif runs[-1]:
            runs.append([])
    return [tuple(run) for run in runs if len(set(run)) >= 2]


def _clip(ways: _Ways, nodes: Mapping[int, object]) -> tuple[list[tuple[int, tuple[int, ...]]],
                                                             int, int, int]:
    """Pieces ``(way id, refs)`` of every way, and the counts: cut, dropped, missing refs."""
    pieces: list[tuple[int, tuple[int, ...]]] = []
    cut = outside = missing = 0
    for way_id, refs in ways.refs.items():
        lost = sum(1 for r in refs if r not in nodes)
        if lost == 0:
            pieces.append((way_id, refs))
            continue
        missing += lost
        parts = clip_refs(refs, nodes.__contains__)
        cut += bool(parts)
        outside += not parts
        pieces.extend((way_id, part) for part in parts)
    return pieces, cut, outside, missing


def _graph_from_pieces(path: Path, pieces: list[tuple[int, tuple[int, ...]]], ways: _Ways,
                       nodes: Mapping[int, tuple[float, float, dict[str, str]]]
                       ) -> nx.MultiDiGraph:
    """osmnx's raw graph of the pieces; each piece is a way of its own, numbered 1, 2, ..."""
    import osmnx as ox  # slow to import (1 s): the service, which never imports, goes without

    with tempfile.TemporaryDirectory(prefix="roadgraph-") as tmp:
        roads = Path(tmp) / "roads.osm"
        used = sorted({ref for _, refs in pieces for ref in refs})
        with osmium.SimpleWriter(str(roads)) as writer:
            for ref in used:
                lon, lat, tags = nodes[ref]
                writer.add_node(osmium.osm.mutable.Node(
                    id=ref, location=osmium.osm.Location(lon, lat), tags=tags))
            for number, (way_id, refs) in enumerate(pieces, start=1):
                writer.add_way(osmium.osm.mutable.Way(id=number, nodes=list(refs),
                                                      tags=ways.tags[way_id]))
        try:
            graph: nx.MultiDiGraph = ox.graph_from_xml(roads, simplify=False, retain_all=True)
        except Exception as exc:  # osmnx raises bare ValueError/KeyError on odd content
            raise MapSourceError(f"{path}: osmnx could not build a graph: {exc}") from exc
    for _, _, data in graph.edges(data=True):
        data["osmid"] = pieces[int(data["osmid"]) - 1][0]
    return graph


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
