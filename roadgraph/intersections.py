"""From the roads of an OSM file to the intersection graph, on flat arrays (pure: no I/O).

The default builder of ``roadgraph import`` for local files. It builds the graph osmnx builds
(:func:`roadgraph.build.build_network`: ``graph_from_xml``, ``simplify_graph``,
``project_graph``, ``consolidate_intersections``) with the same rules, step by step, but over
NumPy arrays and compiled loops instead of a networkx graph of every OSM node, so that a map
of millions of edges builds in minutes and a few gigabytes (osmnx: about 2 kB per OSM node
and hours). ``tests/roadgraph/test_intersections.py`` checks on the real bundled maps that
both give the same graph.

The rules, as osmnx 2.1 has them:

1. Raw graph (``osmnx.graph._add_paths``): a way's consecutive repeated nodes are merged; it is
   one-way when ``oneway`` is yes/true/1/-1/reverse/T/F or it is a roundabout, reversed when
   ``oneway`` is -1/reverse/T; a two-way road has an edge each way.
2. Simplification (``osmnx.simplification``): a node is an endpoint when it is its own
   neighbour, has no edge in or none out, or has not exactly two neighbours with 2 or 4
   edges; edges are merged along the paths between endpoints. A ring that meets no other road
   keeps its smallest node as an endpoint (roadgraph's rule, :func:`build._simplify`).
3. Projection to the UTM zone of the centre of the simplified nodes' bounding box.
4. Consolidation: nodes whose ``consolidate_m`` buffers (64-gons) overlap form a cluster,
   split where the cluster's own edges do not connect it; a cluster of several nodes sits at
   the centroid of its buffers' union (a split part: the mean of its distinct points); edges
   within a cluster go, the others reach the new position from their old end.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
import numpy.typing as npt
import shapely
from pyproj import CRS
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from roadgraph.arrays import EdgeAttributes, GraphArrays, build_arrays
from roadgraph.build import MapInfo, _iter_numbers, _tag_yes
from roadgraph.errors import NoDrivableRoadError
from roadgraph.geometry import FloatArray, LocalFrame, unique_sorted, utm_crs_for
from roadgraph.osm import WAY_TAGS, RoadPieces
from roadgraph.spatial import IntArray

BoolArray = npt.NDArray[np.bool_]

_ONEWAY = frozenset({"yes", "true", "1", "-1", "reverse", "T", "F"})
_REVERSED = frozenset({"-1", "reverse", "T"})
_TAG = {name: i for i, name in enumerate(WAY_TAGS)}
_BUFFER_QUAD_SEGS = 16  # geopandas' buffer resolution, which osmnx's consolidation uses
Step = Callable[[str], None]


@dataclass(frozen=True, eq=False)
class BuiltGraph:
    """What the builder makes: the summary, the compact arrays and the edge attributes."""

    info: MapInfo
    arrays: GraphArrays
    attributes: EdgeAttributes


@dataclass(frozen=True, eq=False)
class _Edges:
    """Directed edges over node indices, each with its vertices (node indices) and the raw
    edges it merges (their ways give its tags)."""

    u: IntArray
    v: IntArray
    path_start: IntArray  # edge k's vertices are path[path_start[k]:path_start[k + 1]]
    path: IntArray
    way_start: IntArray  # edge k's ways are ways[way_start[k]:way_start[k + 1]], in order
    ways: IntArray


def build_intersection_graph(roads: RoadPieces, *, consolidate_m: float, network: str,
                             source: str = "the source", step: Step | None = None
                             ) -> BuiltGraph:
    """The intersection graph of the roads (see the module docstring for the rules)."""
    say = step or (lambda _: None)
    if consolidate_m < 0.0 or not math.isfinite(consolidate_m):
        raise ValueError(f"consolidate_m must be a finite number >= 0, got {consolidate_m}")
    say("building the raw graph")
    raw_u, raw_v, raw_way = raw_edges(roads)
    n_raw = len(roads.node_ids)
    say("simplifying")
    simple, kept = simplify(raw_u, raw_v, raw_way, n_raw)
    del raw_u, raw_v, raw_way
    lonlat = roads.node_lonlat
    lon, lat = _centre(lonlat[kept])
    frame = LocalFrame(utm_crs_for(lon, lat).to_wkt())
    say("projecting")
    xy = frame.coords_to_local(lonlat)
    if consolidate_m > 0.0:
        say("consolidating junctions")
        node_of, pos, members = consolidate(simple, kept, xy, consolidate_m)
        keep = (node_of[simple.u] != node_of[simple.v]) | (simple.u == simple.v)
        if not np.any(keep):
            raise NoDrivableRoadError(
                f"{source}: no road left after merging the nodes within {consolidate_m:g} m "
                "of each other: every road is shorter than that; import with --consolidate-m 0")
        node_ids = np.arange(len(pos), dtype=np.int64)
    else:
        node_of = np.full(n_raw, -1, dtype=np.int64)
        node_of[kept] = np.arange(len(kept))
        pos, members = xy[kept], _singletons(roads.node_ids[kept])
        keep = np.ones(len(simple.u), dtype=bool)
        node_ids = roads.node_ids[kept]
    say("edge geometry and tags")
    k = np.flatnonzero(keep)
    if len(k) == 0:
        raise NoDrivableRoadError(f"{source}: no drivable road")
    if len(k) < len(simple.u):
        simple = _select(simple, k)
    return _finish(roads, simple, node_of, node_ids, pos, members, xy, frame,
                   consolidate_m=consolidate_m, network=network, merged=len(kept) - len(pos))


def _singletons(ids: IntArray) -> tuple[IntArray, IntArray]:
    return np.arange(len(ids) + 1, dtype=np.int64), ids.astype(np.int64)


def _centre(lonlat: FloatArray) -> tuple[float, float]:
    lo, hi = lonlat.min(axis=0), lonlat.max(axis=0)
    return float((lo[0] + hi[0]) / 2.0), float((lo[1] + hi[1]) / 2.0)


# --- 1. raw graph -----------------------------------------------------------------------------
def way_directions(tags: list[tuple[str | None, ...]]) -> tuple[BoolArray, BoolArray]:
    """Per way: one-way (osmnx's values, or a roundabout), and reversed (``oneway=-1``)."""
    oneway = np.array([t[_TAG["oneway"]] in _ONEWAY or t[_TAG["junction"]] == "roundabout"
                       for t in tags], dtype=bool)
    backward = np.array([t[_TAG["oneway"]] in _REVERSED for t in tags], dtype=bool) & oneway
    return oneway, backward


def raw_edges(roads: RoadPieces) -> tuple[IntArray, IntArray, IntArray]:
    """osmnx's raw directed edges, in its order (per piece: along, then back for a two-way
    road), as node indices, with each edge's way index."""
    refs = np.searchsorted(roads.node_ids, roads.refs)
    start = roads.piece_start
    piece_of = np.repeat(np.arange(len(start) - 1), np.diff(start))
    keep = np.ones(len(refs), dtype=bool)
    keep[1:] = (refs[1:] != refs[:-1]) | (piece_of[1:] != piece_of[:-1])  # osmnx's groupby
    refs, piece_of = refs[keep], piece_of[keep]
    pair = np.flatnonzero(piece_of[1:] == piece_of[:-1])
    a, b, piece = refs[pair], refs[pair + 1], piece_of[pair]
    oneway, backward = way_directions(roads.way_tags)
    way = roads.piece_way[piece]
    flip = backward[way]
    u = np.where(flip, b, a)
    v = np.where(flip, a, b)
    order = np.where(flip, -pair, pair)  # a reversed way runs from its last pair
    two = ~oneway[way]
    u_all = np.concatenate([u, v[two]])
    v_all = np.concatenate([v, u[two]])
    block = np.concatenate([np.zeros(len(u), dtype=np.int64), np.ones(int(two.sum()),
                                                                         dtype=np.int64)])
    seq = np.concatenate([order, order[two]])
    piece_all = np.concatenate([piece, piece[two]])
    rank = np.lexsort((seq, block, piece_all))
    return u_all[rank], v_all[rank], np.concatenate([way, way[two]])[rank]


# --- 2. simplification --------------------------------------------------------------------------
def endpoints(u: IntArray, v: IntArray, n: int) -> BoolArray:
    """osmnx's endpoint rules 1-3 per node (bool array)."""
    out_deg = np.bincount(u, minlength=n)
    in_deg = np.bincount(v, minlength=n)
    loop = np.zeros(n, dtype=bool)
    loop[u[u == v]] = True
    a, b = np.minimum(u, v), np.maximum(u, v)
    pairs = unique_sorted((a * n + b)[a != b])
    neighbours = np.bincount(pairs // n, minlength=n) + np.bincount(pairs % n, minlength=n)
    degree = in_deg + out_deg
    through = (neighbours == 2) & ((degree == 2) | (degree == 4))
    ends: BoolArray = loop | (out_deg == 0) | (in_deg == 0) | ~through
    return ends


def _components(u: IntArray, v: IntArray, n: int) -> IntArray:
    graph = coo_matrix((np.ones(len(u), dtype=np.int8), (u, v)), shape=(n, n))
    labels: IntArray = connected_components(graph, directed=False)[1].astype(np.int64)
    return labels


def _anchor_rings(is_end: BoolArray, u: IntArray, v: IntArray, n: int
                  ) -> tuple[BoolArray, BoolArray]:
    """Endpoints, with the smallest node of each component that has none (a lone ring); and
    those anchors alone."""
    label = _components(u, v, n)
    has_end = np.zeros(label.max() + 1 if n else 0, dtype=bool)
    has_end[label[is_end]] = True
    used = np.zeros(n, dtype=bool)
    used[u] = used[v] = True
    first = np.full(len(has_end), n, dtype=np.int64)
    np.minimum.at(first, label, np.arange(n))
    anchors = first[~has_end]
    anchors = anchors[(anchors < n)]
    anchors = anchors[used[anchors]]
    out = is_end.copy()
    out[anchors] = True
    marked = np.zeros(n, dtype=bool)
    marked[anchors] = True
    return out, marked


def successor_rows(u: IntArray, v: IntArray, n: int) -> tuple[IntArray, IntArray, IntArray]:
    """Each node's distinct successors in order of their first edge, and that edge (osmnx
    takes the first of parallel edges' tags): rows ``start``."""
    key = u * n + v
    _, first = np.unique(key, return_index=True)
    first = first[np.lexsort((first, u[first]))]
    start = np.searchsorted(u[first], np.arange(n + 1)).astype(np.int64)
    return start, v[first].astype(np.int64), first.astype(np.int64)


def simplify(u: IntArray, v: IntArray, way: IntArray, n: int) -> tuple[_Edges, IntArray]:
    """osmnx's simplification of the raw edges: the merged edges, and the nodes kept."""
    is_end, anchors = _anchor_rings(endpoints(u, v, n), u, v, n)
    start, succ, first = successor_rows(u, v, n)
    paths, path_start, path_edges = _walk_paths(np.flatnonzero(is_end), is_end, start, succ,
                                                first)
    removed = np.zeros(n, dtype=bool)
    interior = np.ones(len(paths), dtype=bool)
    interior[path_start[:-1]] = False
    interior[path_start[1:] - 1] = False
    removed[paths[interior]] = True
    pu, pv = paths[path_start[:-1]], paths[path_start[1:] - 1]
    keep_path = ~removed[pu] & ~removed[pv]
    keep_raw = ~removed[u] & ~removed[v]
    edges = _merge_edges(u, v, way, keep_raw, paths, path_start, path_edges, keep_path)
    return _remove_rings(edges, np.flatnonzero(~removed), anchors, n)


def _merge_edges(u: IntArray, v: IntArray, way: IntArray, keep_raw: BoolArray,
                 paths: IntArray, path_start: IntArray, path_edges: IntArray,
                 keep_path: BoolArray) -> _Edges:
    """The simplified graph's edges: raw edges between kept nodes, then the merged paths."""
    raw = np.flatnonzero(keep_raw)
    counts = np.diff(path_start)
    kp = np.flatnonzero(keep_path)
    # merged paths: their vertices, and the ways of their raw edges (one per vertex pair)
    p_sel = np.repeat(keep_path, counts)
    p_flat, p_counts = paths[p_sel], counts[kp]
    e_sel = np.repeat(keep_path, counts - 1)
    w_flat, w_counts = way[path_edges[e_sel]], counts[kp] - 1
    eu = np.concatenate([u[raw], paths[path_start[:-1]][kp]])
    ev = np.concatenate([v[raw], paths[path_start[1:] - 1][kp]])
    path = np.concatenate([np.column_stack([u[raw], v[raw]]).ravel(), p_flat])
    path_counts = np.concatenate([np.full(len(raw), 2), p_counts])
    ways = np.concatenate([way[raw], w_flat])
    way_counts = np.concatenate([np.ones(len(raw), dtype=np.int64), w_counts])
    return _Edges(eu, ev, np.concatenate([[0], np.cumsum(path_counts)]).astype(np.int64),
                  path.astype(np.int64),
                  np.concatenate([[0], np.cumsum(way_counts)]).astype(np.int64),
                  ways.astype(np.int64))


def _remove_rings(edges: _Edges, kept: IntArray, anchors: BoolArray, n: int
                  ) -> tuple[_Edges, IntArray]:
    """osmnx's ``remove_rings`` on the simplified graph: components without an endpoint go
    (a node that was an endpoint before stays one: roadgraph's ring anchors)."""
    ends = endpoints(edges.u, edges.v, n) | anchors
    label = _components(edges.u, edges.v, n)
    has_end = np.zeros(label.max() + 1 if n else 0, dtype=bool)
    in_graph = np.zeros(n, dtype=bool)
    in_graph[kept] = True
    has_end[label[ends & in_graph]] = True
    good = has_end[label[edges.u]]
    if np.all(good):
        return edges, kept
    k = np.flatnonzero(good)
    return _select(edges, k), kept[has_end[label[kept]]]


def _select(edges: _Edges, k: IntArray) -> _Edges:
    pc, wc = np.diff(edges.path_start)[k], np.diff(edges.way_start)[k]
    p_sel = np.repeat(np.isin(np.arange(len(edges.u)), k), np.diff(edges.path_start))
    w_sel = np.repeat(np.isin(np.arange(len(edges.u)), k), np.diff(edges.way_start))
    return _Edges(edges.u[k], edges.v[k], np.concatenate([[0], np.cumsum(pc)]).astype(np.int64),
                  edges.path[p_sel], np.concatenate([[0], np.cumsum(wc)]).astype(np.int64),
                  edges.ways[w_sel])


@numba.njit(cache=True)
def _walk_paths(ends: IntArray, is_end: BoolArray, start: IntArray, succ: IntArray,
                first: IntArray) -> tuple[IntArray, IntArray, IntArray]:  # pragma: no cover
    """osmnx's ``_build_path`` from every endpoint through each successor that is not one:
    the paths' nodes (rows), and per consecutive pair the raw edge whose tags it takes."""
    mark = np.full(is_end.size, -1, dtype=np.int64)
    nodes = [np.int64(0)]
    edges = [np.int64(0)]
    nodes.clear()
    edges.clear()
    bounds = [0]
    walk = 0
    for e in ends:
        for k0 in range(start[e], start[e + 1]):
            s = succ[k0]
            if is_end[s]:
                continue
            path = [e, s]
            pe = [first[k0]]
            mark[e] = walk
            mark[s] = walk
            for k1 in range(start[s], start[s + 1]):
                t = succ[k1]
                if mark[t] != walk:
                    path.append(t)
                    pe.append(first[k1])
                    mark[t] = walk
                    _follow(t, e, walk, path, pe, mark, is_end, start, succ, first)
                    break
            walk += 1
            nodes.extend(path)
            edges.extend(pe)
            bounds.append(len(nodes))
    return (np.array(nodes, dtype=np.int64), np.array(bounds, dtype=np.int64),
            np.array(edges, dtype=np.int64))


@numba.njit(cache=True)
def _follow(cur: int, e: int, walk: int, path: list[int], pe: list[int], mark: IntArray,
            is_end: BoolArray, start: IntArray, succ: IntArray,
            first: IntArray) -> None:  # pragma: no cover - compiled
    """The rest of ``_build_path``'s walk from ``cur`` to the next endpoint, appended."""
    while not is_end[cur]:
        nxt, nk, count = -1, -1, 0
        for k2 in range(start[cur], start[cur + 1]):
            if mark[succ[k2]] != walk:
                count += 1
                nxt, nk = succ[k2], k2
        if count > 1:
            raise ValueError("impossible simplify pattern")
        if count == 0:  # back to the start (a loop), or osmnx's "unexpected pattern"
            for k3 in range(start[cur], start[cur + 1]):
                if succ[k3] == e:
                    path.append(e)
                    pe.append(first[k3])
                    break
            return
        path.append(nxt)
        pe.append(first[nk])
        mark[nxt] = walk
        cur = nxt


# --- 4. consolidation -----------------------------------------------------------------------------
def consolidate(edges: _Edges, kept: IntArray, xy: FloatArray, tolerance_m: float
                ) -> tuple[IntArray, FloatArray, tuple[IntArray, IntArray]]:
    """Clusters of kept nodes (osmnx's rules): each raw node's cluster (-1: not a node), the
    clusters' positions, and their OSM members as rows (node indices into ``kept`` order
    replaced by the caller's ids)."""
    n = len(xy)
    pts = xy[kept]
    m = len(kept)
    pairs = cKDTree(pts).query_pairs(2.0 * tolerance_m, output_type="ndarray")
    if len(pairs):
        d = np.hypot(*(pts[pairs[:, 0]] - pts[pairs[:, 1]]).T)
        sure = d <= 2.0 * tolerance_m * math.cos(math.pi / (4 * _BUFFER_QUAD_SEGS)) - 1e-9
        unsure = np.flatnonzero(~sure)
        if unsure.size:
            a = shapely.buffer(shapely.points(pts[pairs[unsure, 0]]), tolerance_m,
                               quad_segs=_BUFFER_QUAD_SEGS)
            b = shapely.buffer(shapely.points(pts[pairs[unsure, 1]]), tolerance_m,
                               quad_segs=_BUFFER_QUAD_SEGS)
            sure[unsure] = shapely.intersects(a, b)
        pairs = pairs[sure]
    buffer_cluster = _components(pairs[:, 0], pairs[:, 1], m) if len(pairs) else np.arange(m)
    local = np.full(n, -1, dtype=np.int64)
    local[kept] = np.arange(m)
    lu, lv = local[edges.u], local[edges.v]
    inside = (buffer_cluster[lu] == buffer_cluster[lv]) & (lu != lv)
    part = _components(lu[inside], lv[inside], m)
    # number the final clusters in the order of their first node (osmnx's factorize)
    _, first_at, cluster = np.unique(part, return_index=True, return_inverse=True)
    rank = np.empty(len(first_at), dtype=np.int64)
    rank[np.argsort(first_at, kind="stable")] = np.arange(len(first_at))
    cluster = rank[cluster.ravel()]
    size = np.bincount(cluster)
    pos = np.zeros((len(size), 2))
    single = size[cluster] == 1
    pos[cluster[single]] = pts[single]
    parts_per_buffer = np.zeros(buffer_cluster.max() + 1, dtype=np.int64)
    np.add.at(parts_per_buffer, buffer_cluster[first_at], 1)
    order = np.argsort(cluster, kind="stable")
    bounds = np.concatenate([[0], np.cumsum(size)])
    member_cluster = cluster[order]
    multi = size[member_cluster] > 1
    split = parts_per_buffer[buffer_cluster[order]] > 1
    whole = multi & ~split  # a cluster as osmnx's buffers made it: their union's centroid
    if np.any(whole):
        ids, dense = np.unique(member_cluster[whole], return_inverse=True)
        mp = shapely.multipoints(pts[order[whole]], indices=dense.ravel())
        union = shapely.buffer(mp, tolerance_m, quad_segs=_BUFFER_QUAD_SEGS)
        pos[ids] = shapely.get_coordinates(shapely.centroid(union))
    part_of = multi & split  # a part of a split cluster: the mean of its distinct points
    if np.any(part_of):
        c, p = member_cluster[part_of], pts[order[part_of]]
        o = np.lexsort((p[:, 1], p[:, 0], c))
        c, p = c[o], p[o]
        distinct = np.ones(len(c), dtype=bool)
        distinct[1:] = (c[1:] != c[:-1]) | np.any(p[1:] != p[:-1], axis=1)
        c, p = c[distinct], p[distinct]
        count = np.bincount(c, minlength=len(size))
        ids = unique_sorted(c)
        pos[ids, 0] = np.bincount(c, p[:, 0], minlength=len(size))[ids] / count[ids]
        pos[ids, 1] = np.bincount(c, p[:, 1], minlength=len(size))[ids] / count[ids]
    node_of = np.full(n, -1, dtype=np.int64)
    node_of[kept] = cluster
    return node_of, pos, (bounds.astype(np.int64), kept[order])


# --- records --------------------------------------------------------------------------------------
def _finish(roads: RoadPieces, edges: _Edges, node_of: IntArray,
            node_ids: IntArray, pos: FloatArray, members: tuple[IntArray, IntArray],
            xy: FloatArray, frame: LocalFrame, *, consolidate_m: float, network: str,
            merged: int) -> BuiltGraph:

    cu, cv = node_of[edges.u], node_of[edges.v]
    coords, coord_start = _edge_coords(edges, cu, cv, pos, xy)
    lengths, bearings = _lengths_bearings(coords, coord_start)
    # sort by (u id, v id), then number parallel edges
    order = np.lexsort((np.arange(len(cu)), node_ids[cv], node_ids[cu]))
    cu, cv = cu[order], cv[order]
    counts = np.diff(coord_start)[order]
    coords = _gather_rows(coords, coord_start, order)
    coord_start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    lengths, bearings = lengths[order], bearings[order]
    pair = cu * (len(pos) + 1) + cv
    newgroup = np.ones(len(pair), dtype=bool)
    newgroup[1:] = pair[1:] != pair[:-1]
    idx = np.arange(len(pair))
    key = idx - np.maximum.accumulate(np.where(newgroup, idx, 0))
    degree = _degrees(cu, cv, len(pos))
    node_lonlat = frame.coords_to_wgs84(pos)
    mstart, mnodes = members
    node_osm = roads.node_ids[mnodes] if consolidate_m > 0.0 else mnodes
    arrays = build_arrays(
        node_id=node_ids, node_xy=pos, node_lonlat=node_lonlat, node_degree=degree,
        node_osm_start=mstart, node_osm=node_osm.astype(np.int64), edge_u_id=node_ids[cu],
        edge_v_id=node_ids[cv], edge_key=key.astype(np.int64), edge_length_m=lengths,
        edge_bearing_rad=bearings, coord_start=coord_start, coords=coords)
    lonlat = frame.coords_to_wgs84(coords)
    attrs = _attributes(roads, edges, order, lonlat)
    info = _summary(arrays, attrs, frame, consolidate_m=consolidate_m, network=network,
                    merged=merged)
    return BuiltGraph(info, arrays, attrs)


def _gather_rows(coords: FloatArray, start: IntArray, order: IntArray) -> FloatArray:
    counts = np.diff(start)[order]
    first = start[:-1][order]
    offset = np.repeat(first - (np.cumsum(counts) - counts), counts)
    out: FloatArray = coords[np.arange(int(counts.sum())) + offset]
    return out


def _edge_coords(edges: _Edges, cu: IntArray, cv: IntArray, pos: FloatArray, xy: FloatArray
                 ) -> tuple[FloatArray, IntArray]:
    """Each edge's vertices: its new end positions around its path, consecutive duplicates
    (within 1 µm) dropped; a loop of one point keeps it twice."""
    out: tuple[FloatArray, IntArray] = _edge_coords_kernel(
        edges.path_start, edges.path, cu, cv, pos, np.ascontiguousarray(xy))
    return out


@numba.njit(cache=True)
def _edge_coords_kernel(path_start: IntArray, path: IntArray, cu: IntArray, cv: IntArray,
                        pos: FloatArray, xy: FloatArray
                        ) -> tuple[FloatArray, IntArray]:  # pragma: no cover - compiled
    m = cu.size
    out = np.empty((path.size + 2 * m, 2))
    start = np.empty(m + 1, dtype=np.int64)
    start[0] = 0
    n = 0
    for e in range(m):
        count = path_start[e + 1] - path_start[e] + 2
        first = n
        px, py = 0.0, 0.0
        for k in range(count):
            if k == 0:
                x, y = pos[cu[e], 0], pos[cu[e], 1]
            elif k == count - 1:
                x, y = pos[cv[e], 0], pos[cv[e], 1]
            else:
                node = path[path_start[e] + k - 1]
                x, y = xy[node, 0], xy[node, 1]
            if k == 0 or abs(x - px) > 1e-6 or abs(y - py) > 1e-6:
                out[n, 0], out[n, 1] = x, y
                n += 1
            px, py = x, y
        if n - first == 1:  # a self-loop reduced to one point: keep two
            out[n, 0], out[n, 1] = out[first, 0], out[first, 1]
            n += 1
        start[e + 1] = n
    return out[:n].copy(), start


@numba.njit(cache=True)
def _lengths_bearings_kernel(coords: FloatArray, start: IntArray, reach_m: float
                             ) -> tuple[FloatArray, FloatArray]:  # pragma: no cover
    m = start.size - 1
    lengths = np.empty(m)
    bearings = np.empty((m, 2))
    for e in range(m):
        lo, hi = start[e], start[e + 1]
        total = 0.0
        for i in range(lo, hi - 1):
            total += math.hypot(coords[i + 1, 0] - coords[i, 0], coords[i + 1, 1] - coords[i, 1])
        lengths[e] = total
        reach = min(reach_m, total)
        xa, ya = _point_at(coords, lo, hi, reach)
        xb, yb = _point_at(coords, lo, hi, total - reach)
        bearings[e, 0] = _bearing(coords[lo, 0], coords[lo, 1], xa, ya)
        bearings[e, 1] = _bearing(xb, yb, coords[hi - 1, 0], coords[hi - 1, 1])
    return lengths, bearings


@numba.njit(cache=True)
def _bearing(x0: float, y0: float, x1: float, y1: float) -> float:  # pragma: no cover
    b = math.atan2(x1 - x0, y1 - y0)
    if b < 0.0:
        b += 2.0 * math.pi
    return 0.0 if b >= 2.0 * math.pi else b


@numba.njit(cache=True)
def _point_at(coords: FloatArray, lo: int, hi: int, offset_m: float
              ) -> tuple[float, float]:  # pragma: no cover
    """:func:`roadgraph.geometry.point_at_offset` on vertices ``lo..hi-1`` (its position)."""
    nseg = hi - lo - 1
    cum = np.empty(nseg + 1)
    cum[0] = 0.0
    for i in range(nseg):
        cum[i + 1] = cum[i] + math.hypot(coords[lo + i + 1, 0] - coords[lo + i, 0],
                                         coords[lo + i + 1, 1] - coords[lo + i, 1])
    offset = min(max(offset_m, 0.0), cum[nseg])
    i = np.searchsorted(cum, offset, side="right") - 1
    i = min(max(i, 0), nseg - 1)
    # the nearest segment with a length (itself first)
    j = i
    found = False
    for step in range(nseg):
        for c in (i - step, i + step):
            if not found and 0 <= c < nseg and (coords[lo + c + 1, 0] != coords[lo + c, 0] or
                                                coords[lo + c + 1, 1] != coords[lo + c, 1]):
                j = c
                found = True
        if found:
            break
    seg = cum[j + 1] - cum[j]
    frac = 0.0 if seg == 0.0 else (offset - cum[j]) / seg
    frac = min(max(frac, 0.0), 1.0)
    x = coords[lo + j, 0] + (coords[lo + j + 1, 0] - coords[lo + j, 0]) * frac
    y = coords[lo + j, 1] + (coords[lo + j + 1, 1] - coords[lo + j, 1]) * frac
    return x, y


def _lengths_bearings(coords: FloatArray, start: IntArray) -> tuple[FloatArray, FloatArray]:
    """Each edge's length, and its bearings leaving u and arriving at v over 20 m
    (:func:`roadgraph.geometry.end_bearings_rad`)."""
    return _lengths_bearings_kernel(np.ascontiguousarray(coords), start, 20.0)


def _degrees(u: IntArray, v: IntArray, n: int) -> IntArray:
    """Distinct neighbours of each node, either direction, itself left out."""
    a, b = np.minimum(u, v), np.maximum(u, v)
    pairs = unique_sorted((a * n + b)[a != b])
    return (np.bincount(pairs // n, minlength=n) + np.bincount(pairs % n, minlength=n)
            ).astype(np.int64)


def _attributes(roads: RoadPieces, edges: _Edges, order: IntArray, lonlat: FloatArray
                ) -> EdgeAttributes:
    """Each edge's tags from its ways (osmnx's merge: unique values; names joined, the
    largest lane count, a tunnel or bridge when any part is one)."""
    tags, way_ids = roads.way_tags, roads.way_ids.tolist()
    ws, wl = edges.way_start.tolist(), edges.ways.tolist()
    ids: list[tuple[int, ...]] = []
    rows: list[tuple[object, ...]] = []
    cache: dict[tuple[tuple[str | None, ...], ...], tuple[object, ...]] = {}
    for e in order.tolist():
        lo, hi = ws[e], ws[e + 1]
        group = (wl[lo],) if hi - lo == 1 else tuple(dict.fromkeys(wl[lo:hi]))
        ids.append(tuple(way_ids[w] for w in group))
        values = tuple(tags[w] for w in group)  # tag tuples are shared: ways repeat them
        row = cache.get(values)
        if row is None:
            row = cache[values] = _merge_tags(values)
        rows.append(row)
    cols: list[Any] = list(zip(*rows)) if rows else [()] * 7
    return EdgeAttributes(
        osm_way_ids=ids, name=list(cols[0]), highway=list(cols[1]),
        oneway=list(cols[2]), maxspeed=list(cols[3]), lanes=list(cols[4]),
        tunnel=list(cols[5]), bridge=list(cols[6]), lonlat=lonlat)


def _merge_tags(values: tuple[tuple[str | None, ...], ...]) -> tuple[object, ...]:
    """name, highway, oneway, maxspeed, lanes, tunnel, bridge of the ways' tags together."""
    oneway, _ = way_directions(list(values))
    names = [t[_TAG["name"]] for t in values if t[_TAG["name"]] is not None]
    highways = [t[_TAG["highway"]] for t in values if t[_TAG["highway"]] is not None]
    speeds = [t[_TAG["maxspeed"]] for t in values if t[_TAG["maxspeed"]] is not None]
    lanes = [int(float(s)) for t in values if t[_TAG["lanes"]] is not None
             for s in _iter_numbers([t[_TAG["lanes"]]])]
    return (
        "; ".join(dict.fromkeys(str(n) for n in names)) or None,
        str(highways[0]) if highways else "road",
        bool(oneway.any()),
        str(speeds[0]) if speeds else None,
        max(lanes) if lanes else None,
        any(_tag_yes(t[_TAG["tunnel"]]) for t in values),
        any(_tag_yes(t[_TAG["bridge"]]) for t in values),
    )


def _summary(a: GraphArrays, attrs: EdgeAttributes, frame: LocalFrame, *,
             consolidate_m: float, network: str, merged: int) -> MapInfo:
    """The :class:`MapInfo` of the arrays (as :func:`roadgraph.build.summarize`)."""
    lonlat = attrs.lonlat
    oneway = np.asarray(attrs.oneway, dtype=bool)
    adjacent = np.hypot(*(a.node_xy[a.edge_u] - a.node_xy[a.edge_v]).T)
    epsg = CRS.from_wkt(frame.crs_wkt).to_epsg()
    return MapInfo(
        crs_wkt=frame.crs_wkt, epsg=epsg,
        bbox_wgs84=(float(lonlat[:, 0].min()), float(lonlat[:, 1].min()),
                    float(lonlat[:, 0].max()), float(lonlat[:, 1].max())),
        node_count=len(a.node_id), edge_count=len(a.edge_u),
        total_length_m=float(a.edge_length_m.sum()),
        longest_edge_m=float(a.edge_length_m.max()),
        max_adjacent_node_distance_m=float(adjacent.max()),
        network=network, consolidate_m=consolidate_m,
        osmnx_version="",  # built without osmnx
        road_length_m=float(np.sum(a.edge_length_m * np.where(oneway, 1.0, 0.5))),
        junction_count=int(np.count_nonzero(a.node_degree >= 3)),
        dead_end_count=int(np.count_nonzero(a.node_degree == 1)),
        junction_nodes_merged=merged,
    )
