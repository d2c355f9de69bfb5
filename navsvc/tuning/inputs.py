"""Reading what ``navsvc tune`` tunes on: drive files and known routes (I/O edge).

* a drive: JSON Lines of packets (``navsvc simulate`` writes them with truth records);
* a route (``--route``, for a drive without truth): a GPX track or route of the roads driven,
  or the OSM way ids of those roads (a JSON list, or integers separated by commas, spaces or
  new lines); the route is the union of the map's edges on those ways.

Errors name the file (and line).
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import shapely

from navsvc.errors import ConfigError
from navsvc.tuning.replay import TuneDrive
from navsvc.wire.jsonl import read_records
from navsvc.wire.traces import read_trace
from roadgraph import RoadGraph


def read_route(graph: RoadGraph, path: Path) -> shapely.Geometry:
    """The route in ``path`` as a geometry in the map's metres."""
    if path.suffix.lower() == ".gpx":
        fixes = read_trace(path)
        lonlat = np.array([(f.lon_deg, f.lat_deg) for f in fixes], dtype=np.float64)
        xy = graph.frame.coords_to_local(lonlat)
        return shapely.linestrings(xy) if len(xy) > 1 else shapely.points(xy[0])
    ways = _way_ids(path)
    lines = [shapely.linestrings(e.coords) for e in graph.edges if set(e.osm_way_ids) & ways]
    if not lines:
        raise ConfigError(f"{path}: no road of the map {graph.map_id!r} is on these OSM ways")
    return shapely.multilinestrings(lines)


def _way_ids(path: Path) -> set[int]:
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the route ({exc.strerror})") from None
    if text.lstrip().startswith("["):
        try:
            values = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ConfigError(f"{path}:{exc.lineno}: not JSON ({exc.msg})") from None
        if not all(isinstance(v, int) and not isinstance(v, bool) for v in values):
            raise ConfigError(f"{path}: expected a JSON list of OSM way ids (integers)")
        ways = set(values)
    else:
        ways = set()
        for number, line in enumerate(text.splitlines(), start=1):
            for token in re.split(r"[,\s]+", line.strip()):
                if not token:
                    continue
                if not token.isdigit():
                    raise ConfigError(f"{path}:{number}: {token!r} is not an OSM way id "
                                      "(use a .gpx file for a track)")
                ways.add(int(token))
    if not ways:
        raise ConfigError(f"{path}: the route names no OSM way")
    return ways


def read_drives(graph: RoadGraph, drives: Sequence[Path], routes: Sequence[str]
                ) -> list[TuneDrive]:
    """The drives, each with its route when one is given (``-``: the drive has truth)."""
    if routes and len(routes) != len(drives):
        raise ConfigError(f"--route is given {len(routes)} times for {len(drives)} drives: "
                          "give one per drive, '-' for a drive with truth records")
    out = []
    for i, path in enumerate(drives):
        records = tuple(read_records(path))
        route_name = routes[i] if routes else "-"
        route = None if route_name == "-" else read_route(graph, Path(route_name))
        drive = TuneDrive(str(path), records, route)
        if route is None and not drive.has_truth:
            raise ConfigError(f"{path}: the drive has no truth records; give its route with "
                              "--route (a GPX, or the OSM way ids driven)")
        out.append(drive)
    return out
