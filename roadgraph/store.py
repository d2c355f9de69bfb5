"""The road-graph database: one SQLite file per map (I/O).

Schema (version :data:`SCHEMA_VERSION`, also in ``PRAGMA user_version``)::

    meta(key, value)            schema_version, info (MapInfo as JSON)
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
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any

import numpy as np
import shapely

from roadgraph.build import EdgeRecord, MapInfo, NodeRecord, RoadNetwork
from roadgraph.errors import MapDatabaseError, SchemaVersionError

SCHEMA_VERSION = 1

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
CREATE VIRTUAL TABLE edges_rtree USING rtree(id, min_lon, max_lon, min_lat, max_lat);
"""

_EDGE_COLUMNS = (
    "u, v, key, osm_way_ids, name, highway, oneway, maxspeed, lanes, tunnel, bridge, length_m, "
    "bearing_start_rad, bearing_end_rad, geom_local, geom_wgs84"
)


def write_network(network: RoadNetwork, path: Path) -> None:
    """Write a network to ``path`` atomically (temporary file, then rename)."""
    path = Path(path)
    tmp = _temporary_sibling(path)
    try:
        with _connect(tmp) as conn:
            conn.executescript(_SCHEMA)
            conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")
            _insert(conn, network)
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


def _insert(conn: sqlite3.Connection, network: RoadNetwork) -> None:
    meta = {"schema_version": str(SCHEMA_VERSION),
            "info": json.dumps(dataclasses.asdict(network.info))}
    conn.executemany("INSERT INTO meta VALUES (?, ?)", meta.items())
    conn.executemany(
        "INSERT INTO nodes VALUES (?, ?, ?, ?, ?, ?, ?)",
        [(n.id, json.dumps(n.osm_ids), n.lon_deg, n.lat_deg, n.x_m, n.y_m, n.degree)
         for n in network.nodes],
    )
    for edge_id, e in enumerate(network.edges):
        conn.execute(
            f"INSERT INTO edges (id, {_EDGE_COLUMNS}) VALUES ({', '.join('?' * 17)})",
            (edge_id, e.u, e.v, e.key, json.dumps(e.osm_way_ids), e.name, e.highway,
             int(e.oneway), e.maxspeed, e.lanes, int(e.tunnel), int(e.bridge), e.length_m,
             e.bearing_start_rad, e.bearing_end_rad,
             shapely.to_wkb(shapely.linestrings(e.coords)),
             shapely.to_wkb(shapely.linestrings(e.lonlat))),
        )
        lo, hi = e.lonlat.min(axis=0), e.lonlat.max(axis=0)
        conn.execute("INSERT INTO edges_rtree VALUES (?, ?, ?, ?, ?)",
                     (edge_id, lo[0], hi[0], lo[1], hi[1]))


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
            if version != SCHEMA_VERSION:
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
