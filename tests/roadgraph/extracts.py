"""Cutting a bounding box out of an OSM file the ways people do, to make clipped test extracts.

``cut(src, dst, bbox, strategy)`` with the strategies of ``osmium extract`` (simple,
complete_ways, smart; osmium-tool's manual, "Strategies"), written in pyosmium so that the tests
need no osmium-tool; ``cut_xml_text`` cuts the XML as text the way a script or a careless
bounding-box query does: the nodes inside, every way with a node inside, its ``<nd>`` references
left as they are.
"""

from __future__ import annotations

import gzip
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import osmium

Bbox = tuple[float, float, float, float]  # west, south, east, north
STRATEGIES = ("simple", "complete_ways", "smart")


def _inside(bbox: Bbox, lon: float, lat: float) -> bool:
    west, south, east, north = bbox
    return west <= lon <= east and south <= lat <= north


@dataclass
class _Data:
    """A whole (small) OSM file as plain values."""

    nodes: dict[int, tuple[float, float, int, dict[str, str]]] = field(default_factory=dict)
    ways: dict[int, tuple[list[int], int, dict[str, str]]] = field(default_factory=dict)
    relations: dict[int, tuple[list[tuple[str, int, str]], int, dict[str, str]]] = field(
        default_factory=dict)


def _load(src: Path) -> _Data:
    data = _Data()
    obj: Any
    for obj in osmium.FileProcessor(str(src)):
        tags = dict(obj.tags)
        if obj.is_node():
            data.nodes[obj.id] = (obj.location.lon, obj.location.lat, obj.version, tags)
        elif obj.is_way():
            data.ways[obj.id] = ([n.ref for n in obj.nodes], obj.version, tags)
        elif obj.is_relation():
            data.relations[obj.id] = (
                [(m.type, m.ref, m.role) for m in obj.members], obj.version, tags)
    return data


def cut(src: Path, dst: Path, bbox: Bbox, strategy: str) -> None:
    """``osmium extract --bbox W,S,E,N --strategy STRATEGY src -o dst``, in pyosmium."""
    data = _load(src)
    inside = {i for i, (lon, lat, _, _) in data.nodes.items() if _inside(bbox, lon, lat)}
    way_ids = {i for i, (refs, _, _) in data.ways.items() if any(r in inside for r in refs)}
    if strategy == "smart":
        way_ids |= _multipolygon_ways(data, inside)
    node_ids = set(inside)
    if strategy in ("complete_ways", "smart"):
        node_ids |= {r for i in way_ids for r in data.ways[i][0]}
    with osmium.SimpleWriter(str(dst), overwrite=True) as writer:
        for i in sorted(node_ids):
            lon, lat, version, tags = data.nodes[i]
            writer.add_node(osmium.osm.mutable.Node(id=i, location=(lon, lat), version=version,
                                                    tags=tags))
        for i in sorted(way_ids):
            refs, version, tags = data.ways[i]
            writer.add_way(osmium.osm.mutable.Way(id=i, nodes=refs, version=version, tags=tags))
        for i, (members, version, tags) in sorted(data.relations.items()):
            if any(ref in (node_ids if kind == "n" else way_ids if kind == "w" else ())
                   for kind, ref, _ in members):
                writer.add_relation(osmium.osm.mutable.Relation(
                    id=i, members=members, version=version, tags=tags))


def _multipolygon_ways(data: _Data, inside: set[int]) -> set[int]:
    """Member ways of the multipolygons with a node inside (osmium's smart strategy)."""
    found: set[int] = set()
    for members, _, tags in data.relations.values():
        if tags.get("type") != "multipolygon":
            continue
        ways = [ref for kind, ref, _ in members if kind == "w" and ref in data.ways]
        if any(r in inside for w in ways for r in data.ways[w][0]):
            found.update(ways)
    return found


_ELEMENT = re.compile(r"\s*<(node|way|relation)\b[^>]*?(?:/>|>.*?</\1>)", re.S)
_ID = re.compile(r'id="(-?\d+)"')
_LATLON = re.compile(r'lat="([-\d.]+)" lon="([-\d.]+)"')
_ND = re.compile(r'<nd ref="(-?\d+)"')


def cut_xml_text(src_gz: Path, dst: Path, bbox: Bbox) -> None:
    """Keep the ``<node>``s inside the box and the ``<way>``s with one of them, as text."""
    text = gzip.decompress(src_gz.read_bytes()).decode()
    elements = list(_ELEMENT.finditer(text))
    inside: set[str] = set()
    kept: list[str] = []
    for element in elements:
        kind, body = element.group(1), element.group(0)
        if kind == "node":
            latlon, ident = _LATLON.search(body), _ID.search(body)
            assert latlon is not None and ident is not None
            if _inside(bbox, float(latlon.group(2)), float(latlon.group(1))):
                inside.add(ident.group(1))
                kept.append(body)
        elif kind == "way" and any(r in inside for r in _ND.findall(body)):
            kept.append(body)
    head, tail = text[: elements[0].start()], text[elements[-1].end():]
    dst.write_text(head + "".join(kept) + tail)
