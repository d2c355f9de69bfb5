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
from array import array
from collections import Counter
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import networkx as nx
import numba
import numpy as np
import numpy.typing as npt
import osmium
from tqdm import tqdm

from roadgraph.errors import MapSourceError, NoDrivableRoadError
from roadgraph.geometry import FloatArray, unique_sorted

IntArray = npt.NDArray[np.int64]

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
# The tags is_drivable reads.
_FILTER_KEYS = ("highway", "area", "access", "motor_vehicle", "motorcar", "service")

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


# The way tags the intersection graph reads (osmnx keeps these among its useful tags).
WAY_TAGS = ("name", "highway", "oneway", "junction", "maxspeed", "lanes", "tunnel", "bridge")
WayTags = tuple[str | None, ...]  # the values of WAY_TAGS, None when absent


@dataclass(frozen=True, eq=False)
class RoadPieces:
    """The roads of a local file, flat: each piece is a way, or the part of a clipped way
    inside the extract, as a run of node references; and the positions of those nodes."""

    way_ids: IntArray  # the OSM ways of the network (pieces name them by index)
    way_tags: list[WayTags]  # per way
    piece_way: IntArray  # each piece's way, as an index into way_ids
    piece_start: IntArray  # piece k's references are refs[piece_start[k]:piece_start[k + 1]]
    refs: IntArray  # OSM node ids, every one in node_ids
    node_ids: IntArray  # the nodes the pieces use, sorted
    node_lonlat: FloatArray  # (n, 2) WGS84 degrees

    def pieces(self) -> list[tuple[int, tuple[int, ...]]]:
        """``(way id, refs)`` of each piece (small maps: the osmnx builder)."""
        ids, start, refs = self.way_ids.tolist(), self.piece_start.tolist(), self.refs.tolist()
        return [(ids[w], tuple(refs[start[k]:start[k + 1]]))
                for k, w in enumerate(self.piece_way.tolist())]


@dataclass(frozen=True)
class OsmRead:
    """The raw graph of a local file, with the report of what was read."""

    graph: nx.MultiDiGraph
    report: ReadReport


@dataclass
class _Ways:
    """Pass 1: the network's ways, their references (flat) and tags."""

    ids: array[int] = field(default_factory=lambda: array("q"))
    start: array[int] = field(default_factory=lambda: array("q", [0]))
    refs: array[int] = field(default_factory=lambda: array("q"))
    tags: list[WayTags] = field(default_factory=list)
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
    """Read a local OSM file, clipped or not, into osmnx's raw graph and a
    :class:`ReadReport` (the osmnx builder; :func:`read_roads` feeds the default one).

    ``stage`` is called with the name of each step as it starts (the importer's progress bar).
    """
    roads, report = read_roads(path, network, progress=progress, stage=stage)
    return OsmRead(graph=graph_from_roads(path, roads), report=report)


def read_roads(path: Path, network: str = "drive", *, progress: bool = False,
               stage: Stage | None = None) -> tuple[RoadPieces, ReadReport]:
    """Read a local OSM file, clipped or not, into :class:`RoadPieces` and a
    :class:`ReadReport`, in two streaming passes: memory grows with the roads, not the file.
    """
    _check_network(network)
    _check_file(path)
    _check_kind(path)
    step = stage or (lambda _: None)
    deleted = _josm_deleted_ids(path)
    step("reading ways")
    ways = _scan_ways(path, network, deleted, progress)
    _check_some_ways(path, network, ways)
    refs = np.frombuffer(ways.refs, dtype=np.int64)
    step("reading nodes")
    node_ids, lonlat, invalid = _read_nodes(path, _needed_nodes(refs, deleted), progress)
    roads, cut, outside, missing = _clip(ways, refs, node_ids, lonlat)
    report = ReadReport(
        ways_kept=len(unique_sorted(roads.piece_way)), ways_cut=cut,
        ways_dropped_outside=outside, ways_dropped_one_node=ways.one_node,
        ways_not_in_network=sum(ways.other.values()), missing_node_refs=missing,
        negative_ids=ways.negative + int(np.count_nonzero(node_ids < 0)),
        josm_deleted=len(deleted), invalid_locations=invalid,
    )
    if len(roads.piece_way) == 0:
        raise NoDrivableRoadError(
            f"{path}: no drivable road inside the extract: each of the {len(ways.ids)} "
            f"{network} ways has fewer than two of its nodes in the file "
            f"({missing} node references missing)")
    log.info("%s: %s", path, report)
    return roads, report


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


def _counter(progress: bool, what: str, total: int | None = None) -> tqdm[None]:
    """A count of objects read; with a bar and an estimate only when the total is known (the
    road nodes: as many as the ways reference, fewer only in a clipped extract)."""
    fmt = "{desc}: {n_fmt} [{elapsed}, {rate_fmt}]" if total is None else \
        "{desc}: {percentage:3.0f}% {n_fmt}/{total_fmt} [{elapsed}<{remaining}, {rate_fmt}]"
    return tqdm(desc=f"  {what} read", bar_format=fmt, total=total,
                unit=" objects", leave=False, position=1, mininterval=0.5,
                disable=None if progress else True)


def _scan_ways(path: Path, network: str, deleted: frozenset[tuple[str, int]],
               progress: bool) -> _Ways:
    """Pass 1: the ``highway=*`` ways, those of the network kept with references and tags."""
    ways = _Ways()
    seen: dict[int, int] = {}
    interned: dict[WayTags, WayTags] = {}
    with _counter(progress, "highway ways") as bar:
        for way in _objects(path, osmium.osm.WAY, (osmium.filter.KeyFilter("highway"),)):
            bar.update()
            _check_unique(path, "way", way, seen)
            if ("way", way.id) in deleted:
                continue
            tags = way.tags
            found = {k: v for k in _FILTER_KEYS if (v := tags.get(k)) is not None}
            if not is_drivable(found, network):
                ways.other[found.get("highway", "")] += 1
                continue
            ways.negative += way.id < 0
            refs = _refs(way)
            if len(set(refs)) < 2:
                ways.one_node += 1
                continue
            ways.ids.append(way.id)
            ways.refs.extend(refs)
            ways.start.append(len(ways.refs))
            values = tuple(found.get(k) if k in _FILTER_KEYS else tags.get(k) for k in WAY_TAGS)
            ways.tags.append(interned.setdefault(values, values))
    return ways


def _refs(way: Any) -> list[int]:
    """A way's node references (through pyosmium's list directly: its iterator costs twice
    as much, a generator step and a wrapper per reference)."""
    nodes = way.nodes
    raw, data = nodes._list, nodes._pyosmium_data
    get = raw.get
    return [get(data, i).ref for i in range(raw.size(data))]


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
    if ways.ids:
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


def _needed_nodes(refs: IntArray, deleted: frozenset[tuple[str, int]]) -> IntArray:
    needed = unique_sorted(refs)
    gone = [i for kind, i in deleted if kind == "node"]
    return needed[~np.isin(needed, gone)] if gone else needed


def _read_nodes(path: Path, needed: IntArray, progress: bool
                ) -> tuple[IntArray, FloatArray, int]:
    """Pass 2: the needed nodes present in the file, sorted by id, and their locations.

    Also the number of those with an invalid location (left out, as if missing). libosmium
    filters the nodes and writes them as OPL text to a temporary file, which a compiled loop
    parses: pyosmium's objects cost 5 µs a node from Python, this 0.2. Memory: 32 bytes a
    road node, whatever else the file holds.
    """
    negative = bool(needed.size) and int(needed[0]) < 0
    with tempfile.TemporaryDirectory(prefix="roadgraph-") as tmp, \
            _counter(progress, "road nodes", total=len(needed)) as bar:
        opl = Path(tmp) / "nodes.opl"
        try:
            writer = osmium.WriteHandler(str(opl))
            # libosmium's id filter takes unsigned ids only: with negative ids, filter after
            chain = [] if negative else [osmium.filter.IdFilter(needed)]
            osmium.apply(osmium.io.Reader(str(path), osmium.osm.NODE), *chain, writer)
            writer.close()
        except RuntimeError as exc:  # libosmium: truncated or malformed PBF/XML
            raise MapSourceError(f"{path}: unreadable OSM data: {exc}") from exc
        ids, versions, visible, lon_e7, lat_e7, valid = _parse_opl_nodes(
            np.fromfile(opl, dtype=np.uint8))
        bar.update(len(ids))
    order = np.argsort(ids, kind="stable")
    ids, versions, visible = ids[order], versions[order], visible[order]
    lon_e7, lat_e7, valid = lon_e7[order], lat_e7[order], valid[order]
    if not np.all(visible):
        node = int(ids[np.flatnonzero(~visible)[0]])
        raise _history_file_error(path, f"node {node} is marked deleted (visible=false)")
    _check_unique_nodes(path, ids, versions)
    keep = np.isin(ids, needed) if negative else np.ones(len(ids), dtype=bool)
    valid &= (np.abs(lon_e7) <= 1_800_000_000) & (np.abs(lat_e7) <= 900_000_000)
    invalid = int(np.count_nonzero(keep & ~valid))
    keep &= valid
    lonlat = np.column_stack([lon_e7[keep] / 1e7, lat_e7[keep] / 1e7])
    return ids[keep], lonlat, invalid


@numba.njit(cache=True)
def _parse_int(buf: npt.NDArray[np.uint8], i: int) -> tuple[int, int]:  # pragma: no cover
    """The integer starting at ``buf[i]`` (optional sign) and the position after it."""
    sign = 1
    if buf[i] == 45:  # '-'
        sign, i = -1, i + 1
    value = 0
    while i < buf.size and 48 <= buf[i] <= 57:
        value = value * 10 + (buf[i] - 48)
        i += 1
    return sign * value, i


@numba.njit(cache=True)
def _parse_e7(buf: npt.NDArray[np.uint8], i: int) -> tuple[int, int, bool]:  # pragma: no cover
    """A coordinate in units of 1e-7 degree (libosmium's), the position after it, and
    whether there was one."""
    if i >= buf.size or not (buf[i] == 45 or 48 <= buf[i] <= 57):
        return 0, i, False
    sign = 1
    if buf[i] == 45:
        sign, i = -1, i + 1
    whole, i = _parse_int(buf, i)
    frac, digits = 0, 0
    if i < buf.size and buf[i] == 46:  # '.'
        i += 1
        while i < buf.size and 48 <= buf[i] <= 57:
            if digits < 7:
                frac = frac * 10 + (buf[i] - 48)
                digits += 1
            i += 1
    while digits < 7:
        frac *= 10
        digits += 1
    return sign * (whole * 10_000_000 + frac), i, True


@numba.njit(cache=True)
def _parse_opl_nodes(buf: npt.NDArray[np.uint8]):  # type: ignore[no-untyped-def] # pragma: no cover
    """Id, version, visible, lon and lat (1e-7 degree) and location validity of each node line
    of libosmium's OPL output (``n<id> v<version> d<V|D> ... x<lon> y<lat>``)."""
    lines = 0
    for b in buf:
        lines += b == 10
    ids = np.empty(lines, dtype=np.int64)
    versions = np.empty(lines, dtype=np.int64)
    visible = np.empty(lines, dtype=np.bool_)
    lon = np.zeros(lines, dtype=np.int64)
    lat = np.zeros(lines, dtype=np.int64)
    valid = np.zeros(lines, dtype=np.bool_)
    n, i = 0, 0
    while i < buf.size:
        if buf[i] != 110:  # 'n': not a node line (none expected)
            while i < buf.size and buf[i] != 10:
                i += 1
            i += 1
            continue
        ids[n], i = _parse_int(buf, i + 1)
        has_x = has_y = False
        versions[n], visible[n] = 0, True
        while i < buf.size and buf[i] != 10:
            if buf[i] == 32 and i + 1 < buf.size:
                c = buf[i + 1]
                if c == 118:  # 'v'
                    versions[n], i = _parse_int(buf, i + 2)
                    continue
                if c == 100:  # 'd'
                    visible[n] = buf[i + 2] != 68  # 'D'
                elif c == 120:  # 'x'
                    lon[n], i, has_x = _parse_e7(buf, i + 2)
                    continue
                elif c == 121:  # 'y'
                    lat[n], i, has_y = _parse_e7(buf, i + 2)
                    continue
            i += 1
        valid[n] = has_x and has_y
        n += 1
        i += 1
    return ids[:n], versions[:n], visible[:n], lon[:n], lat[:n], valid[:n]


def _check_unique_nodes(path: Path, ids: IntArray, versions: IntArray) -> None:
    """Refuse a node id read twice: a history file when the versions differ."""
    twice = np.flatnonzero(ids[1:] == ids[:-1])
    if twice.size == 0:
        return
    k = int(twice[0])
    node, a, b = int(ids[k]), int(versions[k]), int(versions[k + 1])
    if a != b:
        raise _history_file_error(path, f"node {node} appears in versions {a} and {b}")
    raise MapSourceError(
        f"{path}: node {node} appears twice: duplicate ids (two extracts concatenated? "
        "combine them with osmium merge)")


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


def _clip(ways: _Ways, refs: IntArray, node_ids: IntArray, lonlat: FloatArray
          ) -> tuple[RoadPieces, int, int, int]:
    """The pieces of every way inside the extract, and the counts: cut, dropped, missing."""
    start = np.frombuffer(ways.start, dtype=np.int64)
    at = np.minimum(np.searchsorted(node_ids, refs), max(len(node_ids) - 1, 0))
    present = node_ids[at] == refs if len(node_ids) else np.zeros(len(refs), dtype=bool)
    way_of_ref = np.repeat(np.arange(len(start) - 1), np.diff(start))
    lost = np.bincount(way_of_ref[~present], minlength=len(start) - 1)
    whole = lost == 0
    piece_way: list[int] = []
    piece_len: list[int] = []
    chunks: list[IntArray] = []
    cut = outside = 0

    def inside(ref: int) -> bool:
        k = int(np.searchsorted(node_ids, ref))
        return k < len(node_ids) and int(node_ids[k]) == ref

    for w in range(len(start) - 1):
        lo, hi = int(start[w]), int(start[w + 1])
        if whole[w]:
            piece_way.append(w)
            piece_len.append(hi - lo)
            chunks.append(refs[lo:hi])
            continue
        parts = clip_refs(tuple(refs[lo:hi].tolist()), inside)
        cut += bool(parts)
        outside += not parts
        for part in parts:
            piece_way.append(w)
            piece_len.append(len(part))
            chunks.append(np.asarray(part, dtype=np.int64))
    flat = np.concatenate(chunks) if chunks else np.empty(0, dtype=np.int64)
    used = unique_sorted(flat)
    keep = np.isin(node_ids, used)
    roads = RoadPieces(
        way_ids=np.frombuffer(ways.ids, dtype=np.int64).copy(), way_tags=ways.tags,
        piece_way=np.asarray(piece_way, dtype=np.int64),
        piece_start=np.cumsum([0, *piece_len]).astype(np.int64), refs=flat,
        node_ids=node_ids[keep], node_lonlat=lonlat[keep])
    return roads, cut, outside, int(lost.sum())


def graph_from_roads(path: Path, roads: RoadPieces) -> nx.MultiDiGraph:
    """osmnx's raw graph of the pieces; each piece is a way of its own, numbered 1, 2, ..."""
    import osmnx as ox  # slow to import (1 s): the service, which never imports, goes without

    pieces = roads.pieces()
    with tempfile.TemporaryDirectory(prefix="roadgraph-") as tmp:
        xml = Path(tmp) / "roads.osm"
        with osmium.SimpleWriter(str(xml)) as writer:
            for ref, (lon, lat) in zip(roads.node_ids.tolist(), roads.node_lonlat.tolist()):
                writer.add_node(osmium.osm.mutable.Node(
                    id=ref, location=osmium.osm.Location(lon, lat)))
            for number, ((_, refs), w) in enumerate(zip(pieces, roads.piece_way.tolist()),
                                                    start=1):
                tags = {k: v for k, v in zip(WAY_TAGS, roads.way_tags[w]) if v is not None}
                writer.add_way(osmium.osm.mutable.Way(id=number, nodes=list(refs), tags=tags))
        try:
            graph: nx.MultiDiGraph = ox.graph_from_xml(xml, simplify=False, retain_all=True)
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
