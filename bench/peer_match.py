"""The peer map matchers on GPS fixes alone, offline: OSRM's ``match`` service and Valhalla
Meili's ``trace_attributes`` (``shape_match: map_snap``), one matched road per fix.

Runs under ``.venv-peers``'s Python 3.12 (``bench/peers/setup.sh`` builds it and the map
files); imports neither navsvc nor roadgraph. ``bench/matching_eval.py`` calls it as a
subprocess.

    .venv-peers/bin/python bench/peer_match.py bench/.cache/peers/monaco traces.json out.json

Input: ``{"traces": {id: [{"t": s, "lat": deg, "lon": deg, "sigma_m": m}, ...]}}``.
Output: ``{"osrm": {id: [fix, ...]}, "valhalla": {id: [...]}, "meta": {...}}``, one entry per
input fix, in order::

    {"how": ..., "lat": deg, "lon": deg, "way_id": OSM way, "bearing_deg": travel direction on
     the matched segment, "road": what the peer says identifies the directed road}

``how`` tells where the fix came from, and ``lat``/``lon``/``way_id`` are null when unmatched:

* OSRM (``gaps: split``, ``tidy: true``, ``radiuses`` = each fix's ``sigma_m``, timestamps,
  ``annotations: nodes``): ``"tracepoint"`` when OSRM returned a tracepoint for the fix;
  ``"on_leg"`` when tidy dropped it (or OSRM skipped it) between two tracepoints of one
  matching, and the fix is projected onto that leg's path; ``"near_end"`` when it lies
  before a matching's first or after its last tracepoint (tidy drops fixes there too, and a
  gap split ends a matching), within TIDY_S of it: onto that tracepoint's OSM segment;
  ``"unmatched"`` otherwise.
  A leg's ``annotation.nodes`` are the OSM nodes from the segment holding its first
  tracepoint to the segment holding its last; ``road`` is ``{"nodes": [from, to]}``, the OSM
  segment the fix is on in the direction of travel; the way is the OSM way holding both
  nodes consecutively (from the map's .osm.pbf, read with pyosmium).
* Valhalla (costing ``auto``, ``gps_accuracy`` = the trace's median ``sigma_m``, defaults
  otherwise): ``"matched"``, ``"interpolated"`` (closer than ``interpolation_distance`` to the
  previous fix: put on the matched path) or ``"unmatched"``, as Meili's ``matched_points``
  say; ``road`` is ``{"edge_id", "begin_shape_index", "end_shape_index"}`` of the matched
  edge (its ``way_id`` is the OSM way), and the bearing is that of the shape segment nearest
  the matched point.
"""

from __future__ import annotations

import json
import math
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import osmium
import osrm
import valhalla

Fix = dict[str, Any]
EARTH_RADIUS_M = 6371008.8
TIDY_S = 5.0  # OSRM's tidy keeps a fix at least every 5 s (and every 15 m)


# --- the map's OSM segments (for OSRM's node ids) ---------------------------------------
class Segments:
    """OSM node coordinates and the way of each pair of consecutive nodes of a road."""

    def __init__(self, pbf: Path) -> None:
        self.lonlat: dict[int, tuple[float, float]] = {}
        self.way: dict[tuple[int, int], int] = {}
        for w in osmium.FileProcessor(str(pbf)).with_locations().with_filter(
                osmium.filter.KeyFilter("highway")):
            if not w.is_way():
                continue
            refs = []
            for n in w.nodes:
                if n.location.valid():
                    self.lonlat[n.ref] = (n.location.lon, n.location.lat)
                refs.append(n.ref)
            for a, b in zip(refs[:-1], refs[1:]):
                self.way.setdefault((a, b), w.id)
                self.way.setdefault((b, a), w.id)

    def way_of(self, a: int, b: int) -> int | None:
        return self.way.get((a, b))


# --- small geometry on the sphere, locally flat -----------------------------------------
def _xy(lon: float, lat: float, lat0: float) -> tuple[float, float]:
    k = math.pi / 180.0 * EARTH_RADIUS_M
    return lon * k * math.cos(math.radians(lat0)), lat * k


def _bearing_deg(a: tuple[float, float], b: tuple[float, float]) -> float:
    """Compass bearing from lon/lat ``a`` to ``b``."""
    ax, ay = _xy(*a, a[1])
    bx, by = _xy(*b, a[1])
    return math.degrees(math.atan2(bx - ax, by - ay)) % 360.0


def _project(p: tuple[float, float], polyline: list[tuple[float, float]]
             ) -> tuple[int, tuple[float, float]]:
    """The segment of a lon/lat polyline nearest a lon/lat point, and the projected point."""
    lat0 = p[1]
    px, py = _xy(*p, lat0)
    best = (math.inf, 0, polyline[0])
    for j, (a, b) in enumerate(zip(polyline[:-1], polyline[1:])):
        ax, ay = _xy(*a, lat0)
        bx, by = _xy(*b, lat0)
        dx, dy = bx - ax, by - ay
        f = ((px - ax) * dx + (py - ay) * dy) / (dx * dx + dy * dy) if dx or dy else 0.0
        f = min(max(f, 0.0), 1.0)
        qx, qy = ax + f * dx, ay + f * dy
        d = math.hypot(px - qx, py - qy)
        if d < best[0]:
            best = (d, j, (a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1])))
    return best[1], best[2]


def _unmatched() -> Fix:
    return {"how": "unmatched", "lat": None, "lon": None, "way_id": None, "bearing_deg": None,
            "road": None}


# --- OSRM --------------------------------------------------------------------------------
def _plain(x: Any) -> Any:
    """osrm's result objects as plain Python (its numbers are all floats)."""
    if x is None or isinstance(x, (str, int, float, bool)):
        return x
    if type(x).__name__ == "Object":
        return {k: _plain(x[k]) for k in x}
    return [_plain(v) for v in x]


def osrm_match(engine: osrm.OSRM, segments: Segments, fixes: list[Fix]
               ) -> tuple[list[Fix], int]:
    """Each fix's match, and how many matchings OSRM split the trace into."""
    params = osrm.MatchParameters(
        coordinates=[(f["lon"], f["lat"]) for f in fixes],
        timestamps=[int(round(f["t"])) for f in fixes],
        radiuses=[float(f["sigma_m"]) for f in fixes],
        gaps="split", tidy=True, annotations=["nodes"], geometries="geojson", overview="false")
    try:
        res = _plain(engine.Match(params))
    except RuntimeError:  # "NoMatch" and the like
        return [_unmatched() for _ in fixes], 0
    legs = [[[int(n) for n in leg["annotation"]["nodes"]] for leg in m["legs"]]
            for m in res["matchings"]]
    tps = res["tracepoints"]
    out = [_unmatched() for _ in fixes]
    for i, tp in enumerate(tps):
        if tp is None:
            continue
        m, w = int(tp["matchings_index"]), int(tp["waypoint_index"])
        nodes = legs[m][w][:2] if w < len(legs[m]) else legs[m][w - 1][-2:] if legs[m] else []
        out[i] = _osrm_fix("tracepoint", tuple(tp["location"]), nodes, segments)
    _osrm_fill_legs(fixes, tps, legs, segments, out)
    return out, len(legs)


def _osrm_fill_legs(fixes: list[Fix], tps: list[Any], legs: list[list[list[int]]],
                    segments: Segments, out: list[Fix]) -> None:
    """Fixes without a tracepoint: between two tracepoints of one matching, onto that leg's
    path; within TIDY_S after a matching's last tracepoint or before its first (tidy's
    window), onto that tracepoint's segment."""
    kept = [i for i, tp in enumerate(tps) if tp is not None]
    for i, k in zip(kept[:-1], kept[1:]):
        a, b = tps[i], tps[k]
        m, w = int(a["matchings_index"]), int(a["waypoint_index"])
        if k == i + 1:
            continue
        if int(b["matchings_index"]) != m or int(b["waypoint_index"]) != w + 1:
            _osrm_near_ends(fixes, tps, legs, segments, out, i, k)
            continue
        nodes = legs[m][w]
        path = [tuple(a["location"])] + [segments.lonlat[n] for n in nodes[1:-1]] + \
            [tuple(b["location"])]
        for j in range(i + 1, k):
            seg, where = _project((fixes[j]["lon"], fixes[j]["lat"]), path)
            out[j] = _osrm_fix("on_leg", where, nodes[seg:seg + 2], segments)
    if kept:
        _osrm_near_ends(fixes, tps, legs, segments, out, -1, kept[0])
        _osrm_near_ends(fixes, tps, legs, segments, out, kept[-1], len(fixes))


def _osrm_near_ends(fixes: list[Fix], tps: list[Any], legs: list[list[list[int]]],
                    segments: Segments, out: list[Fix], i: int, k: int) -> None:
    """Fixes strictly between tracepoints i (a matching's last, or -1) and k (the next
    matching's first, or len): within TIDY_S of either, onto that tracepoint's segment."""
    for j in range(i + 1, k):
        near = [n for n in (i, k) if 0 <= n < len(fixes)
                and abs(fixes[j]["t"] - fixes[n]["t"]) <= TIDY_S]
        if not near:
            continue
        n = min(near, key=lambda n: abs(fixes[j]["t"] - fixes[n]["t"]))
        nodes = out[n]["road"]["nodes"] if out[n]["road"] else []
        ends = [segments.lonlat.get(x) for x in nodes]
        if len(nodes) < 2 or None in ends:
            continue
        _, where = _project((fixes[j]["lon"], fixes[j]["lat"]), ends)
        out[j] = _osrm_fix("near_end", where, nodes, segments)


def _osrm_fix(how: str, lonlat: tuple[float, float], nodes: list[int],
              segments: Segments) -> Fix:
    if len(nodes) < 2:
        return {**_unmatched(), "how": how, "lat": lonlat[1], "lon": lonlat[0]}
    a, b = nodes
    ends = segments.lonlat.get(a), segments.lonlat.get(b)
    bearing = _bearing_deg(*ends) if None not in ends and ends[0] != ends[1] else None
    return {"how": how, "lat": lonlat[1], "lon": lonlat[0], "way_id": segments.way_of(a, b),
            "bearing_deg": bearing, "road": {"nodes": [a, b]}}


# --- Valhalla Meili ---------------------------------------------------------------------
VALHALLA_ATTRIBUTES = [
    "edge.id", "edge.way_id", "edge.begin_shape_index", "edge.end_shape_index",
    "matched.point", "matched.type", "matched.edge_index", "matched.distance_along_edge",
    "shape"]


def valhalla_match(actor: valhalla.Actor, fixes: list[Fix]) -> list[Fix]:
    request = {
        "shape": [{"lat": f["lat"], "lon": f["lon"], "time": f["t"]} for f in fixes],
        "costing": "auto", "shape_match": "map_snap", "shape_format": "polyline6",
        "trace_options": {"gps_accuracy": statistics.median(f["sigma_m"] for f in fixes)},
        "filters": {"attributes": VALHALLA_ATTRIBUTES, "action": "include"}}
    try:
        res = actor.trace_attributes(request)
    except (valhalla.ValhallaError, RuntimeError):
        return [_unmatched() for _ in fixes]
    shape = _decode_polyline6(res.get("shape", ""))
    edges = res.get("edges", [])
    out = []
    for p in res.get("matched_points", []):
        i = p.get("edge_index")
        if p.get("type") == "unmatched" or i is None or not 0 <= i < len(edges):
            out.append(_unmatched())
            continue
        e = edges[i]
        b, c = e["begin_shape_index"], e["end_shape_index"]
        where = (p["lon"], p["lat"])
        seg, _ = _project(where, shape[b:c + 1]) if c > b else (0, where)
        bearing = _bearing_deg(shape[b + seg], shape[b + seg + 1]) if c > b else None
        out.append({"how": p["type"], "lat": p["lat"], "lon": p["lon"], "way_id": e["way_id"],
                    "bearing_deg": bearing,
                    "road": {"edge_id": e.get("id"), "begin_shape_index": b,
                             "end_shape_index": c}})
    return out if len(out) == len(fixes) else [_unmatched() for _ in fixes]


def _decode_polyline6(encoded: str) -> list[tuple[float, float]]:
    """Google's polyline algorithm at 1e-6 degrees, as (lon, lat)."""
    coords, index, lat, lon = [], 0, 0, 0
    while index < len(encoded):
        for which in (0, 1):
            shift = result = 0
            while True:
                byte = ord(encoded[index]) - 63
                index += 1
                result |= (byte & 0x1F) << shift
                shift += 5
                if byte < 0x20:
                    break
            delta = ~(result >> 1) if result & 1 else result >> 1
            if which == 0:
                lat += delta
            else:
                lon += delta
        coords.append((lon / 1e6, lat / 1e6))
    return coords


# --- the run ----------------------------------------------------------------------------
def main(cache: Path, traces_path: Path, out_path: Path) -> None:
    traces: dict[str, list[Fix]] = json.loads(traces_path.read_text())["traces"]
    started = time.perf_counter()
    segments = Segments(cache / "map.osm.pbf")
    engine = osrm.OSRM(storage_config=str(cache / "map.osrm"), algorithm="MLD",
                       use_shared_memory=False)
    actor = valhalla.Actor(str(cache / "valhalla.json"))
    loaded = time.perf_counter()
    result: dict[str, Any] = {"osrm": {}, "valhalla": {}}
    seconds = {"osrm": 0.0, "valhalla": 0.0}
    matchings = {}
    for trace_id, fixes in traces.items():
        t0 = time.perf_counter()
        result["osrm"][trace_id], matchings[trace_id] = osrm_match(engine, segments, fixes)
        t1 = time.perf_counter()
        result["valhalla"][trace_id] = valhalla_match(actor, fixes)
        seconds["osrm"] += t1 - t0
        seconds["valhalla"] += time.perf_counter() - t1
    result["meta"] = {"load_s": loaded - started, "match_s": seconds,
                      "osrm_matchings": matchings,
                      "fixes": sum(len(f) for f in traces.values()),
                      "osrm_version": "osrm-bindings " + _version("osrm-bindings"),
                      "valhalla_version": "pyvalhalla " + _version("pyvalhalla")}
    out_path.write_text(json.dumps(result))


def _version(dist: str) -> str:
    from importlib.metadata import version
    return version(dist)


if __name__ == "__main__":
    if len(sys.argv) != 4:
        sys.exit(__doc__.split("\n\n")[2])
    main(Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3]))
