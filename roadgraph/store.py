"""The road-graph database: one SQLite file per map (I/O).

Schema (version :data:`SCHEMA_VERSION`, also in ``PRAGMA user_version``)::

    meta(key, value)            schema_version, info (MapInfo as JSON)
    arrays(name, part, dtype, shape, data)   the compact arrays a service opens
                                (:class:`roadgraph.arrays.GraphArrays`, raw little-endian,
                                in parts of at most 900 MiB)
    nodes(id, osm_ids, lon, lat, x, y, degree)
    edges(id, u, v, key, osm_way_ids, name, highway, oneway, maxspeed, lanes, tunnel, bridge,
          length_m, bearing_start_rad, bearing_end_rad,
          geom_local (WKB, map CRS metres), geom_wgs84 (WKB, lon/lat degrees))
    edges_rtree(id, min_lon, max_lon, min_lat, max_lat)     SQLite R*Tree over edge bounding boxes

``osm_ids`` and ``osm_way_ids`` are JSON arrays. A write goes to a temporary file in the target's
folder, which is renamed over the target only when complete: a failed write leaves no database
behind and never damages an existing one.
"""

from __future__ import annotations

import dataclasses
import json
import os
import sqlite3
import tempfile
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any

import numpy as np
import shapely

from roadgraph.arrays import (
    EdgeAttributes,
    GraphArrays,
    array_names,
    arrays_from_records,
    attributes_from_records,
)
from roadgraph.build import EdgeRecord, MapInfo, NodeRecord, RoadNetwork
from roadgraph.errors import MapDatabaseError, SchemaVersionError

SCHEMA_VERSION = 2  # 2: the arrays table
# Versions this code reads: a version 1 database (no arrays) opens from its rows, slowly.
READABLE_VERSIONS = (1, 2)
_PART_BYTES = 900 << 20  # under SQLite's default largest blob (10^9 bytes)

_SCHEMA = """
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE nodes (
    id INTEGER PRIMARY KEY, osm_ids TEXT NOT NULL, lon REAL NOT NULL, lat REAL NOT NULL,
    x REAL NOT NULL, y REAL NOT NULL, degree INTEGER NOT NULL
);
CREATE TABLE edges (
    id INTEGER PRIMARY KEY, u INTEGER NOT NULL REFERENCES nodes(id),
    v INTEGER NOT NULL REFERENCES nodes(id), key INTEGER NOT NULL,
    osm_way_ids TEXT NOT NULL, name TEXT, highway TEXT NOT NULL, oneway INTEGER NOT NULL,
    maxspeed TEXT, lanes INTEGER, tunnel INTEGER NOT NULL, bridge INTEGER NOT NULL,
    length_m REAL NOT NULL, bearing_start_rad REAL NOT NULL, bearing_end_rad REAL NOT NULL,
    geom_local BLOB NOT NULL, geom_wgs84 BLOB NOT NULL,
    UNIQUE (u, v, key)
);
CREATE TABLE arrays (
    name TEXT NOT NULL, part INTEGER NOT NULL, dtype TEXT NOT NULL, shape TEXT NOT NULL,
    data BLOB NOT NULL, PRIMARY KEY (name, part)
);
CREATE VIRTUAL TABLE edges_rtree USING rtree(id, min_lon, max_lon, min_lat, max_lat);
"""

_EDGE_COLUMNS = (
    "u, v, key, osm_way_ids, name, highway, oneway, maxspeed, lanes, tunnel, bridge, length_m, "
    "bearing_start_rad, bearing_end_rad, geom_local, geom_wgs84"
)


def write_network(network: RoadNetwork, path: Path) -> None:
    """Write a network of records to ``path`` atomically (temporary file, then rename)."""
    write_map(path, network.info, arrays_from_records(network.nodes, network.edges),
              attributes_from_records(network.edges))


def write_map(path: Path, info: MapInfo, arrays: GraphArrays, attrs: EdgeAttributes,
              progress: Callable[[int], None] | None = None) -> None:
    """Write a map given as arrays to ``path`` atomically (temporary file, then rename).

    ``progress`` is called with the number of edges written so far, now and then."""
    path = Path(path)
    tmp = _temporary_sibling(path)
    try:
        with _connect(tmp) as conn:
            # large pages: the service reads the arrays' blobs at open, 1.5x faster than with
            # 4 kB pages on a 2-million-edge map
            conn.execute("PRAGMA page_size = 65536")
            conn.executescript(_SCHEMA)
            conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")
            _insert(conn, info, arrays, attrs, progress or (lambda _: None))
            conn.commit()
        os.replace(tmp, path)
    except sqlite3.Error as exc:
        raise MapDatabaseError(f"{path}: cannot write the database: {exc}") from exc
    except OSError as exc:
        raise MapDatabaseError(f"{path}: cannot write the database: {exc.strerror}") from exc
    finally:
        with suppress(FileNotFoundError):
            tmp.unlink()


def check_writable(path: Path) -> None:
    """Fail early, before a long import, when ``path`` cannot be written."""
    _temporary_sibling(Path(path)).unlink()


def _temporary_sibling(path: Path) -> Path:
    if path.is_dir():
        raise MapDatabaseError(f"{path}: is a folder; give a database file name")
    try:
        fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as exc:
        raise MapDatabaseError(f"{path}: cannot write here: {exc.strerror}") from exc
    os.close(fd)
    return Path(name)


def _insert(conn: sqlite3.Connection, info: MapInfo, a: GraphArrays, attrs: EdgeAttributes,
            progress: Callable[[int], None]) -> None:
    conn.execute("PRAGMA journal_mode = OFF")  # a fresh temporary file: nothing to roll back to
    conn.execute("PRAGMA synchronous = OFF")  # made durable by the rename after the close
    conn.execute("PRAGMA cache_size = -262144")  # 256 MiB: the R*Tree's inserts thrash less
    meta = {"schema_version": str(SCHEMA_VERSION), "info": json.dumps(dataclasses.asdict(info))}
    conn.executemany("INSERT INTO meta VALUES (?, ?)", meta.items())
    _insert_arrays(conn, a)
    ids = a.node_id.tolist()
    osm = [json.dumps(a.node_osm[s:e].tolist())
           for s, e in zip(a.node_osm_start[:-1].tolist(), a.node_osm_start[1:].tolist())]
    conn.executemany("INSERT INTO nodes VALUES (?, ?, ?, ?, ?, ?, ?)", zip(
        ids, osm, a.node_lonlat[:, 0].tolist(), a.node_lonlat[:, 1].tolist(),
        a.node_xy[:, 0].tolist(), a.node_xy[:, 1].tolist(), a.node_degree.tolist()))
    chunk = 100_000
    boxes = []
    for lo in range(0, len(a.edge_u), chunk):
        hi = min(lo + chunk, len(a.edge_u))
        conn.executemany(f"INSERT INTO edges (id, {_EDGE_COLUMNS}) VALUES ({', '.join('?' * 17)})",
                         _edge_rows(a, attrs, ids, lo, hi))
        boxes.append(_boxes(attrs, a.coord_start[lo:hi + 1]))
        progress(hi)
    # the R*Tree filled in the order of the boxes' places (1 km cells), which keeps its
    # inserts local: in the edges' order they took most of a big map's writing time
    box = np.vstack(boxes) if boxes else np.empty((0, 4))
    order = np.lexsort((np.floor(box[:, 2] * 100.0), np.floor(box[:, 0] * 100.0)))
    conn.executemany("INSERT INTO edges_rtree VALUES (?, ?, ?, ?, ?)",
                     ((i, *b) for i, b in zip(order.tolist(), box[order].tolist())))


def _linestrings_wkb(coords: np.ndarray, start: np.ndarray) -> list[bytes]:
    counts = np.diff(start)
    lines = shapely.linestrings(coords[start[0]:start[-1]],
                                indices=np.repeat(np.arange(len(counts)), counts))
    return shapely.to_wkb(lines).tolist()  # type: ignore[no-any-return]


def _edge_rows(a: GraphArrays, attrs: EdgeAttributes, ids: list[int], lo: int, hi: int
               ) -> Iterator[tuple[Any, ...]]:
    start = a.coord_start[lo:hi + 1]
    local, wgs84 = _linestrings_wkb(a.coords, start), _linestrings_wkb(attrs.lonlat, start)
    u, v, key = a.edge_u[lo:hi].tolist(), a.edge_v[lo:hi].tolist(), a.edge_key[lo:hi].tolist()
    length, bearing = a.edge_length_m[lo:hi].tolist(), a.edge_bearing_rad[lo:hi].tolist()
    for k in range(hi - lo):
        i = lo + k
        yield (i, ids[u[k]], ids[v[k]], key[k], json.dumps(list(attrs.osm_way_ids[i])),
               attrs.name[i], attrs.highway[i], int(attrs.oneway[i]), attrs.maxspeed[i],
               attrs.lanes[i], int(attrs.tunnel[i]), int(attrs.bridge[i]), length[k],
               bearing[k][0], bearing[k][1], local[k], wgs84[k])


def _boxes(attrs: EdgeAttributes, start: np.ndarray) -> np.ndarray:
    """``(min_lon, max_lon, min_lat, max_lat)`` of the edges whose vertices start there."""
    part = attrs.lonlat[start[0]:start[-1]]
    at = start[:-1] - start[0]
    low, high = np.minimum.reduceat(part, at), np.maximum.reduceat(part, at)
    return np.column_stack([low[:, 0], high[:, 0], low[:, 1], high[:, 1]])


def _insert_arrays(conn: sqlite3.Connection, a: GraphArrays) -> None:
    for name, value in a.as_dict().items():
        array = np.asarray(value)
        array = np.ascontiguousarray(array) if array.ndim else array
        data = array.astype(array.dtype.newbyteorder("<"), copy=False).tobytes()
        parts = range(0, max(len(data), 1), _PART_BYTES)
        conn.executemany("INSERT INTO arrays VALUES (?, ?, ?, ?, ?)", [
            (name, k, array.dtype.str.replace(">", "<"), json.dumps(array.shape),
             data[p:p + _PART_BYTES]) for k, p in enumerate(parts)])


def schema_version(path: Path) -> int:
    """The database's schema version (one this code reads)."""
    with _open_checked(path) as conn:
        version: int = conn.execute("PRAGMA user_version").fetchone()[0]
        return version


def read_arrays(path: Path) -> tuple[MapInfo, GraphArrays]:
    """The map's summary and its compact arrays (what a service opens)."""
    with _open_checked(path) as conn:
        info = _read_info(conn)
        if conn.execute("PRAGMA user_version").fetchone()[0] < 2:
            raise MapDatabaseError(f"{path}: schema version 1 has no arrays; open it with "
                                   "RoadGraph.open, or re-import the map")
        parts: dict[str, list[tuple[str, str, bytes]]] = {}
        for name, dtype, shape, data in conn.execute(
                "SELECT name, dtype, shape, data FROM arrays ORDER BY name, part"):
            parts.setdefault(name, []).append((dtype, shape, data))
    values: dict[str, Any] = {}
    for name, chunks in parts.items():
        dtype, shape = chunks[0][0], tuple(json.loads(chunks[0][1]))
        data = chunks[0][2] if len(chunks) == 1 else b"".join(c[2] for c in chunks)
        array = np.frombuffer(data, dtype=np.dtype(dtype)).reshape(shape)
        values[name] = array[()] if shape == () else array
    missing = set(array_names()) - values.keys()
    if missing:
        raise MapDatabaseError(f"{path}: not a road-graph database (arrays missing: "
                               f"{', '.join(sorted(missing))}); re-import the map")
    values["grid_cell_m"] = float(values["grid_cell_m"])
    return info, GraphArrays(**values)


class EdgeRows:
    """One edge's full row at a time, by its index in the arrays (one read-only connection
    per thread: a service answers from several)."""

    def __init__(self, path: Path) -> None:
        self._path = Path(path)
        self._local = threading.local()

    def edge(self, i: int) -> EdgeRecord:
        conn = getattr(self._local, "conn", None)
        if conn is None:
            conn = self._local.conn = sqlite3.connect(
                f"{self._path.resolve().as_uri()}?mode=ro", uri=True)
        row = conn.execute(f"SELECT {_EDGE_COLUMNS} FROM edges WHERE id = ?", (i,)).fetchone()
        if row is None:
            raise MapDatabaseError(f"{self._path}: edge {i} missing from the database")
        return _edge_from_row(row)


def read_network(path: Path) -> RoadNetwork:
    """Read a whole network back."""
    with _open_checked(path) as conn:
        info = _read_info(conn)
        nodes = tuple(
            NodeRecord(id=r[0], osm_ids=tuple(json.loads(r[1])), lon_deg=r[2], lat_deg=r[3],
                       x_m=r[4], y_m=r[5], degree=r[6])
            for r in conn.execute("SELECT * FROM nodes ORDER BY id")
        )
        edges = tuple(_edge_from_row(r) for r in conn.execute(
            f"SELECT {_EDGE_COLUMNS} FROM edges ORDER BY id"))
    return RoadNetwork(info=info, nodes=nodes, edges=edges)


def read_info(path: Path) -> MapInfo:
    """Read only the map's summary (cheap)."""
    with _open_checked(path) as conn:
        return _read_info(conn)


def read_edges_in_bbox(path: Path, bbox: tuple[float, float, float, float]) -> list[EdgeRecord]:
    """Edges whose bounding box meets a ``(west, south, east, north)`` box, via the R*Tree."""
    west, south, east, north = bbox
    with _open_checked(path) as conn:
        rows = conn.execute(
            f"SELECT {_EDGE_COLUMNS} FROM edges WHERE id IN (SELECT id FROM edges_rtree "
            "WHERE max_lon >= ? AND min_lon <= ? AND max_lat >= ? AND min_lat <= ?) ORDER BY id",
            (west, east, south, north),
        )
        return [_edge_from_row(r) for r in rows]


def _edge_from_row(r: tuple[Any, ...]) -> EdgeRecord:
    return EdgeRecord(
        u=r[0], v=r[1], key=r[2], osm_way_ids=tuple(json.loads(r[3])), name=r[4], highway=r[5],
        oneway=bool(r[6]), maxspeed=r[7], lanes=r[8], tunnel=bool(r[9]), bridge=bool(r[10]),
        length_m=r[11], bearing_start_rad=r[12], bearing_end_rad=r[13],
        coords=np.asarray(shapely.get_coordinates(shapely.from_wkb(r[14])), dtype=np.float64),
        lonlat=np.asarray(shapely.get_coordinates(shapely.from_wkb(r[15])), dtype=np.float64),
    )


def _read_info(conn: sqlite3.Connection) -> MapInfo:
    row = conn.execute("SELECT value FROM meta WHERE key = 'info'").fetchone()
    fields = json.loads(row[0])
    fields["bbox_wgs84"] = tuple(fields["bbox_wgs84"])
    return MapInfo(**fields)


@contextmanager
def _open_checked(path: Path) -> Iterator[sqlite3.Connection]:
    path = Path(path)
    if not path.is_file():
        raise MapDatabaseError(f"{path}: no such road-graph database")
    try:
        with _connect(path, read_only=True) as conn:
            version = conn.execute("PRAGMA user_version").fetchone()[0]
            tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master")}
            if not {"meta", "nodes", "edges"} <= tables:
                raise MapDatabaseError(f"{path}: not a road-graph database (tables missing)")
            if version not in READABLE_VERSIONS:
                raise SchemaVersionError(
                    f"{path}: schema version {version}, this navsvc reads version "
                    f"{SCHEMA_VERSION}; re-import the map with `roadgraph import`"
                )
            yield conn
    except sqlite3.DatabaseError as exc:
        raise MapDatabaseError(f"{path}: not a road-graph database ({exc})") from exc


@contextmanager
def _connect(path: Path, read_only: bool = False) -> Iterator[sqlite3.Connection]:
    if read_only:
        conn = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True)
    else:
        conn = sqlite3.connect(path)
    try:
        yield conn
    finally:
        conn.close()
