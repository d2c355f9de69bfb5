"""`roadgraph import`: OSM source → intersection graph → road-graph database (I/O).

The output path is checked before any work, and the database is written atomically by the
store, so a failed import leaves nothing behind and never damages an existing database.
:func:`import_warnings` says what a user should know about a map that did import (a clipped
extract, no junction, JOSM's negative ids).
"""

from __future__ import annotations

import dataclasses
import logging
from datetime import UTC, datetime
from pathlib import Path

import networkx as nx
from tqdm import tqdm

from roadgraph.build import DEFAULT_CONSOLIDATE_M, MapInfo, build_network
from roadgraph.intersections import build_intersection_graph
from roadgraph.osm import (
    ReadReport,
    Stage,
    download_graph,
    file_sha256,
    graph_from_roads,
    read_graphml,
    read_roads,
)
from roadgraph.store import check_writable, write_map, write_network

log = logging.getLogger(__name__)

# The steps of an import from a local OSM file, in order (the progress bar's total); the
# third shows the builder's own steps after a colon.
_FILE_STEPS = ("reading ways", "reading nodes", "building the intersection graph",
               "writing the database")
BUILDERS = ("auto", "arrays", "osmnx")
# "auto" builds with osmnx up to this many road nodes (about 400 MB with osmnx, which holds
# about 2 kB per OSM node), with roadgraph's array builder above: osmnx numbers the
# consolidated nodes in the order GEOS returns the merged buffers, which the array builder
# does not reproduce, and maps imported before keep their node ids.
AUTO_OSMNX_MAX_NODES = 200_000


def import_map(
    output: Path,
    *,
    source: Path | None = None,
    place: str | None = None,
    bbox: tuple[float, float, float, float] | None = None,
    network: str = "drive",
    consolidate_m: float = DEFAULT_CONSOLIDATE_M,
    progress: bool = False,
    builder: str = "auto",
) -> MapInfo:
    """Import one map from a local file, a place name or a bounding box; return its summary.

    A local OSM file is read in two streaming passes, then built by osmnx (small maps) or by
    roadgraph's array builder (bounded memory, any size: :mod:`roadgraph.intersections`),
    which gives the same graph up to the numbering of nodes and parallel edges
    (``tests/roadgraph/test_intersections.py``); ``builder`` forces one. Downloads and
    ``.graphml`` graphs always go through osmnx.
    """
    if (source is None) == (place is None and bbox is None) or (place and bbox):
        raise ValueError("give exactly one of SOURCE, --place or --bbox")
    if builder not in BUILDERS:
        raise ValueError(f"unknown builder {builder!r}; choose from {BUILDERS}")
    check_writable(output)
    osm_file = source is not None and source.suffix != ".graphml"
    # Steps take very different times: the step's name and number and the time so far; a
    # percentage and an estimate only inside a step whose total is known (nodes, edges).
    names = _FILE_STEPS if osm_file else ("read", "building the intersection graph",
                                          "writing the database")
    total = len(names)
    steps = tqdm(total=total, desc="import", bar_format="{desc} [{elapsed}]", leave=False,
                 disable=None if progress else True, position=0)

    def stage(name: str) -> None:
        steps.update()
        steps.set_description_str(f"import, step {steps.n}/{total}: {name}")

    def substage(name: str) -> None:
        steps.set_description_str(f"import, step {steps.n}/{total}: "
                                  f"building the intersection graph: {name}")

    created = datetime.now(UTC).isoformat(timespec="seconds")
    with steps:
        if osm_file:
            assert source is not None
            info = _import_file(output, source, network, consolidate_m, progress, stage,
                                substage, created, builder)
        else:
            info = _import_with_osmnx(output, source, place, bbox, network, consolidate_m,
                                      stage, created)
    log.info("wrote %s: %d nodes, %d edges", output, info.node_count, info.edge_count)
    return info


def _import_file(output: Path, source: Path, network: str, consolidate_m: float,
                 progress: bool, stage: Stage, substage: Stage, created: str,
                 builder: str) -> MapInfo:
    roads, report = read_roads(source, network, progress=progress, stage=stage)
    log.info("read %d OSM nodes, %d pieces of ways", len(roads.node_ids), len(roads.piece_way))
    stage("building the intersection graph")
    if builder == "osmnx" or (builder == "auto" and len(roads.node_ids) <= AUTO_OSMNX_MAX_NODES):
        substage("osmnx")
        raw = graph_from_roads(source, roads)
        del roads
        net = build_network(raw, consolidate_m=consolidate_m, network=network,
                            source=str(source))
        info = _with_report(dataclasses.replace(
            net.info, source_name=source.name, source_sha256=file_sha256(source),
            created_utc=created), report)
        stage("writing the database")
        write_network(dataclasses.replace(net, info=info), output)
        return info
    built = build_intersection_graph(roads, consolidate_m=consolidate_m, network=network,
                                     source=str(source), step=substage)
    del roads
    info = _with_report(dataclasses.replace(
        built.info, source_name=source.name, source_sha256=file_sha256(source),
        created_utc=created), report)
    stage("writing the database")
    with tqdm(total=info.edge_count, desc="  edges written", unit=" edges", leave=False,
              position=1, mininterval=0.5, disable=None if progress else True) as bar:
        write_map(output, info, built.arrays, built.attributes,
                  progress=lambda n: bar.update(n - bar.n))
    return info


def _import_with_osmnx(output: Path, source: Path | None, place: str | None,
                       bbox: tuple[float, float, float, float] | None, network: str,
                       consolidate_m: float, stage: Stage, created: str) -> MapInfo:
    """A ``.graphml`` graph or a download, through osmnx."""
    raw, report, name, sha = _read_source(source, place, bbox, network, stage)
    log.info("read %d OSM nodes, %d edges", raw.number_of_nodes(), raw.number_of_edges())
    stage("building the intersection graph")
    net = build_network(raw, consolidate_m=consolidate_m, network=network,
                        source=str(source) if source is not None else name)
    info = _with_report(dataclasses.replace(
        net.info, source_name=name, source_sha256=sha, created_utc=created), report)
    net = dataclasses.replace(net, info=info)
    stage("writing the database")
    write_network(net, output)
    return info


def _read_source(
    source: Path | None, place: str | None, bbox: tuple[float, float, float, float] | None,
    network: str, stage: Stage,
) -> tuple[nx.MultiDiGraph, ReadReport | None, str, str]:
    """The raw graph of a .graphml file or a download, its name and SHA-256."""
    stage("read")
    if source is not None:
        return read_graphml(source), None, source.name, file_sha256(source)
    raw = download_graph(place=place, bbox=bbox, network=network)
    return raw, None, (f"place:{place}" if place else f"bbox:{bbox}"), ""


def _with_report(info: MapInfo, report: ReadReport | None) -> MapInfo:
    """The summary with what reading the file kept and dropped (local OSM files only)."""
    if report is None:
        return info
    return dataclasses.replace(
        info, osm_ways_kept=report.ways_kept, osm_ways_cut=report.ways_cut,
        osm_ways_dropped_outside=report.ways_dropped_outside,
        osm_ways_dropped_one_node=report.ways_dropped_one_node,
        osm_ways_not_in_network=report.ways_not_in_network,
        osm_missing_node_refs=report.missing_node_refs,
        osm_negative_ids=report.negative_ids, osm_josm_deleted=report.josm_deleted,
        osm_invalid_locations=report.invalid_locations,
    )


def import_warnings(info: MapInfo) -> list[str]:
    """What a user should know about a map that imported, one sentence each."""
    warnings = []
    if info.osm_invalid_locations:
        warnings.append(f"{info.osm_invalid_locations} road nodes with an invalid location "
                        "(beyond 90 degrees of latitude or 180 of longitude), taken as missing")
    if info.osm_missing_node_refs:
        warnings.append(
            f"clipped extract: {info.osm_missing_node_refs} node references missing from the "
            f"file; {info.osm_ways_cut} ways cut at the edge, {info.osm_ways_dropped_outside} "
            "dropped (fewer than two nodes inside); roads end at the extract's edge")
    if info.osm_ways_dropped_one_node:
        warnings.append(f"{info.osm_ways_dropped_one_node} ways of a single node dropped")
    if info.osm_ways_kept == 1:
        warnings.append("a single road: imported, but there is no other road to turn onto")
    elif info.junction_count == 0:
        warnings.append("no junction (no node where three roads meet): imported, but there is "
                        "no road to turn onto")
    if info.osm_negative_ids:
        warnings.append(
            f"{info.osm_negative_ids} nodes and ways with negative ids (new objects in a JOSM "
            "file, not yet in OpenStreetMap): imported, but their ids are not OpenStreetMap's")
    if info.osm_josm_deleted:
        warnings.append(f"objects marked deleted by JOSM left out: {info.osm_josm_deleted}")
    return warnings
