"""`roadgraph`: import OpenStreetMap data into a road-graph database, describe it, export it.

Errors print one line naming the file (or place) and the problem, and exit with status 1;
usage errors exit with status 2.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from roadgraph.build import DEFAULT_CONSOLIDATE_M, MapInfo
from roadgraph.errors import RoadGraphError
from roadgraph.geojson import feature_collection
from roadgraph.importer import AUTO_OSMNX_MAX_NODES, BUILDERS, import_map, import_warnings
from roadgraph.osm import NETWORK_TYPES
from roadgraph.store import read_edges_in_bbox, read_info, read_network

Bbox = tuple[float, float, float, float]


def parse_bbox(text: str) -> Bbox:
    """Parse ``W,S,E,N`` in WGS84 degrees; raise ValueError saying what is wrong."""
    parts = text.split(",")
    if len(parts) != 4:
        raise ValueError(f"bbox {text!r}: expected four numbers W,S,E,N")
    try:
        west, south, east, north = (float(p) for p in parts)
    except ValueError:
        raise ValueError(f"bbox {text!r}: W,S,E,N must be numbers") from None
    if not all(math.isfinite(v) for v in (west, south, east, north)):
        raise ValueError(f"bbox {text!r}: values must be finite")
    if not (-180.0 <= west < east <= 180.0 and -90.0 <= south < north <= 90.0):
        raise ValueError(
            f"bbox {text!r}: need -180 <= W < E <= 180 and -90 <= S < N <= 90")
    return west, south, east, north


def _bbox_arg(text: str) -> Bbox:
    try:
        return parse_bbox(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _tolerance_arg(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(value) and 0.0 <= value <= 100.0):
        raise argparse.ArgumentTypeError(f"{text!r}: must be between 0 and 100 metres")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="roadgraph",
        description="Build and inspect road-graph databases (intersection graphs of "
                    "OpenStreetMap roads, stored in SQLite).",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log each step to stderr")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    imp = sub.add_parser(
        "import", help="import OSM data into a road-graph database",
        description="Read a local OSM file (.osm, .osm.gz, .osm.bz2, .osm.pbf) or an osmnx "
                    "GraphML graph (.graphml, taken as it is) offline, or "
                    "download a --place or --bbox through osmnx (needs a network), keep the "
                    "drivable roads, simplify to intersection nodes, consolidate complex "
                    "junctions, and write the database atomically (no file on failure).")
    imp.add_argument("source", nargs="?", type=Path,
                     help="local OSM or .graphml file; omit when using --place or --bbox")
    where = imp.add_mutually_exclusive_group()
    where.add_argument("--place", help='place name to download, e.g. "Monaco" (online)')
    where.add_argument("--bbox", type=_bbox_arg, metavar="W,S,E,N",
                       help="bounding box in WGS84 degrees to download (online)")
    imp.add_argument("-o", "--output", type=Path, required=True, metavar="DB",
                     help="road-graph database file to write (SQLite)")
    imp.add_argument("--network", choices=NETWORK_TYPES, default="drive",
                     help="which roads to keep: drive (public roads for cars) or drive_service "
                          "(also service roads); default: %(default)s")
    imp.add_argument("--consolidate-m", type=_tolerance_arg, default=DEFAULT_CONSOLIDATE_M,
                     metavar="M",
                     help="merge intersection nodes within M metres into one (0 disables); "
                          "default: %(default)s")
    imp.add_argument("--builder", choices=BUILDERS, default="auto",
                     help="for a local OSM file: osmnx's (about 2 kB of memory per OSM node) "
                          "or roadgraph's array builder (any size, bounded memory; the same "
                          "graph up to node numbers); auto: osmnx up to "
                          f"{AUTO_OSMNX_MAX_NODES:,} road nodes; default: %(default)s")
    imp.add_argument("--json", action="store_true", help="print the map summary as JSON")
    imp.add_argument("-q", "--quiet", action="store_true", help="no progress bar, no summary")

    info = sub.add_parser("info", help="describe a road-graph database",
                          description="Print node and edge counts, bounding box, CRS, longest "
                                      "edge and the longest distance between adjacent nodes.")
    info.add_argument("db", type=Path, metavar="DB", help="road-graph database file")
    info.add_argument("--json", action="store_true", help="print as JSON")

    exp = sub.add_parser("export", help="export a road-graph database as GeoJSON",
                         description="Write the edges (and optionally nodes) as a GeoJSON "
                                     "FeatureCollection in WGS84.")
    exp.add_argument("db", type=Path, metavar="DB", help="road-graph database file")
    exp.add_argument("--geojson", type=Path, required=True, metavar="OUT",
                     help="GeoJSON file to write ('-' for standard output)")
    exp.add_argument("--bbox", type=_bbox_arg, metavar="W,S,E,N",
                     help="only edges meeting this WGS84 box (uses the R*Tree index)")
    exp.add_argument("--nodes", action="store_true", help="include intersection nodes as points")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        return _COMMANDS[args.command](args)
    except RoadGraphError as exc:
        print(f"roadgraph: error: {exc}", file=sys.stderr)
        return 1


def _cmd_import(args: argparse.Namespace) -> int:
    try:
        info = import_map(args.output, source=args.source, place=args.place, bbox=args.bbox,
                          network=args.network, consolidate_m=args.consolidate_m,
                          progress=not args.quiet, builder=args.builder)
    except ValueError as exc:  # the importer's own argument check
        print(f"roadgraph: error: {exc}", file=sys.stderr)
        return 2
    source = args.source if args.source is not None else info.source_name
    for warning in import_warnings(info):
        print(f"roadgraph: warning: {source}: {warning}", file=sys.stderr)
    if not args.quiet:
        _print_info(info, args.output, as_json=args.json)
    return 0


def _cmd_info(args: argparse.Namespace) -> int:
    _print_info(read_info(args.db), args.db, as_json=args.json)
    return 0


def _cmd_export(args: argparse.Namespace) -> int:
    if args.bbox is not None:
        west, south, east, north = args.bbox
        nodes = [n for n in read_network(args.db).nodes
                 if west <= n.lon_deg <= east and south <= n.lat_deg <= north] \
            if args.nodes else []
        collection = feature_collection(read_edges_in_bbox(args.db, args.bbox), nodes)
    else:
        network = read_network(args.db)
        collection = feature_collection(network.edges, network.nodes if args.nodes else ())
    text = json.dumps(collection)
    if str(args.geojson) == "-":
        sys.stdout.write(text + "\n")
    else:
        try:
            args.geojson.write_text(text)
        except OSError as exc:
            raise RoadGraphError(f"{args.geojson}: cannot write: {exc.strerror}") from exc
    return 0


def info_dict(info: MapInfo, db: Path) -> dict[str, Any]:
    """The summary as JSON-ready data (the CRS as EPSG code and WKT)."""
    data = dataclasses.asdict(info)
    data["bbox_wgs84"] = list(info.bbox_wgs84)
    return {"map_id": db.stem, "path": str(db), **data}


def _print_info(info: MapInfo, db: Path, *, as_json: bool) -> None:
    if as_json:
        print(json.dumps(info_dict(info, db), indent=2))
        return
    w, s, e, n = info.bbox_wgs84
    crs = f"EPSG:{info.epsg}" if info.epsg else "custom (see --json)"
    rows = [
        ("map", f"{db.stem} ({db})"),
        ("source", f"{info.source_name}  sha256 {info.source_sha256[:16] or '-'}"),
        ("network", f"{info.network}, junctions consolidated within {info.consolidate_m:g} m"),
        ("CRS", crs),
        ("bbox (W,S,E,N)", f"{w:.6f},{s:.6f},{e:.6f},{n:.6f}"),
        ("nodes", f"{info.node_count}{_node_detail(info)}"),
        ("edges", f"{info.edge_count} ({info.total_length_m / 1000:.1f} km of directed road)"),
        *_summary_rows(info),
        ("longest edge", f"{info.longest_edge_m:.1f} m"),
        ("max adjacent-node distance", f"{info.max_adjacent_node_distance_m:.1f} m"),
        ("built", f"{info.created_utc or '-'} with "
                  f"{'osmnx ' + info.osmnx_version if info.osmnx_version else 'roadgraph'}"),
    ]
    width = max(len(k) for k, _ in rows)
    for key, value in rows:
        print(f"{key:<{width}}  {value}")


def _node_detail(info: MapInfo) -> str:
    if info.junction_count is None:
        return ""
    merged = "" if not info.junction_nodes_merged else \
        f"; {info.junction_nodes_merged} merged into nearby junctions"
    return f" ({info.junction_count} junctions, {info.dead_end_count} dead ends{merged})"


def _summary_rows(info: MapInfo) -> list[tuple[str, str]]:
    """The rows of the import summary recorded by this version (none for older databases)."""
    rows = []
    if info.road_length_m is not None:
        rows.append(("roads", f"{info.road_length_m / 1000:.1f} km (two-way roads counted once)"))
    if info.osm_ways_kept is None:
        return rows
    rows.append(("OSM ways kept", f"{info.osm_ways_kept} ({info.osm_ways_cut} cut at the "
                                  "extract's edge)"))
    rows.append(("OSM ways dropped",
                 f"{info.osm_ways_dropped_outside} outside the extract, "
                 f"{info.osm_ways_dropped_one_node} of one node, "
                 f"{info.osm_ways_not_in_network} not in the {info.network} network"))
    missing = info.osm_missing_node_refs
    rows.append(("missing node refs", f"{missing} ({'clipped' if missing else 'complete'} "
                                      "extract)"))
    if info.osm_negative_ids:
        rows.append(("negative ids", f"{info.osm_negative_ids} (new objects in a JOSM file)"))
    if info.osm_josm_deleted:
        rows.append(("JOSM deleted", f"{info.osm_josm_deleted} objects left out"))
    if info.osm_invalid_locations:
        rows.append(("invalid locations", f"{info.osm_invalid_locations} road nodes, taken as "
                                          "missing"))
    return rows


_COMMANDS = {"import": _cmd_import, "info": _cmd_info, "export": _cmd_export}

if __name__ == "__main__":
    sys.exit(main())
