"""GPS traces from files or request bodies: GPX, GeoJSON, CSV, JSON Lines.

Every reader returns :class:`TraceFix` values in file order; :func:`clean` then sorts them by
time and drops exact duplicates (documented behaviour, not an error). Errors name the file and
line (or element).

* GPX: every ``trkpt`` (else ``rtept``), ``time`` optional (ISO 8601).
* GeoJSON: a ``LineString``/``MultiPoint`` (times from ``properties.times`` or
  ``coordTimes`` when present) or a ``FeatureCollection`` of ``Point`` features (time from
  ``properties.time`` or ``properties.t``).
* CSV: a header with ``lat`` and ``lon`` (or ``latitude``/``longitude``) and optionally ``t``
  or ``time``.
* JSON Lines: objects with ``lat``, ``lon`` and optionally ``t`` (``kind: "gps"`` packets; other
  kinds are skipped).

Points without a time are one second apart.
"""

from __future__ import annotations

import csv
import io
import json
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

from navsvc.errors import TraceError


@dataclass(frozen=True)
class TraceFix:
    t: float
    lat_deg: float
    lon_deg: float


FORMATS = ("gpx", "geojson", "csv", "jsonl")


def format_of(name: str) -> str:
    suffix = name.lower().rsplit(".", 1)[-1]
    found = {"gpx": "gpx", "geojson": "geojson", "json": "geojson", "csv": "csv",
             "jsonl": "jsonl", "ndjson": "jsonl"}.get(suffix)
    if found is None:
        raise TraceError(f"{name}: unknown trace format (use .gpx, .geojson, .csv or .jsonl)")
    return found


def read_trace(path: Path) -> list[TraceFix]:
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise TraceError(f"{path}: cannot read ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise TraceError(f"{path}: not a UTF-8 text file") from None
    return parse_trace(text, format_of(path.name), str(path))


def parse_trace(text: str, fmt: str, name: str = "trace") -> list[TraceFix]:
    readers = {"gpx": _gpx, "geojson": _geojson, "csv": _csv, "jsonl": _jsonl}
    if fmt not in readers:
        raise TraceError(f"{name}: unknown trace format {fmt!r} (known: {', '.join(FORMATS)})")
    try:
        text.encode("utf-8")
    except UnicodeEncodeError as exc:  # a lone surrogate, as JSON's \ud800 can carry
        raise TraceError(f"{name}: not valid Unicode text at character {exc.start} "
                         f"({exc.reason})") from None
    fixes = readers[fmt](text, name)
    if not fixes:
        raise TraceError(f"{name}: the trace has no points")
    return fixes


def clean(fixes: list[TraceFix]) -> list[TraceFix]:
    """Sorted by time (stable) without exact repeats of time and position."""
    out: list[TraceFix] = []
    for f in sorted(fixes, key=lambda f: f.t):
        if out and out[-1] == f:
            continue
        out.append(f)
    return out


def _time(value: Any, default: float, where: str) -> float:
    if value is None or value == "":
        return default
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        t = float(value)
    else:
        try:
            t = float(value)
        except ValueError:
            try:
                t = datetime.fromisoformat(str(value).strip().replace("Z", "+00:00")).timestamp()
            except ValueError:
                raise TraceError(f"{where}: time {value!r} is neither seconds nor ISO 8601") \
                    from None
    if not math.isfinite(t):
        raise TraceError(f"{where}: time must be finite")
    return t


def _fix(lat: Any, lon: Any, t: float, where: str) -> TraceFix:
    try:
        la, lo = float(lat), float(lon)
    except (TypeError, ValueError):
        raise TraceError(f"{where}: lat/lon {lat!r}, {lon!r} are not numbers") from None
    if not (math.isfinite(la) and math.isfinite(lo) and abs(la) <= 90 and abs(lo) <= 180):
        raise TraceError(f"{where}: lat={la} lon={lo} out of range")
    return TraceFix(t, la, lo)


def _gpx(text: str, name: str) -> list[TraceFix]:
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise TraceError(f"{name}:{exc.position[0]}: not valid GPX/XML ({exc})") from None
    points = [e for e in root.iter() if e.tag.rsplit("}", 1)[-1] == "trkpt"] or \
        [e for e in root.iter() if e.tag.rsplit("}", 1)[-1] == "rtept"]
    out = []
    for i, p in enumerate(points):
        time = next((c.text for c in p if c.tag.rsplit("}", 1)[-1] == "time"), None)
        where = f"{name}: point {i + 1}"
        out.append(_fix(p.get("lat"), p.get("lon"), _time(time, float(i), where), where))
    return out


def _geojson(text: str, name: str) -> list[TraceFix]:
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise TraceError(f"{name}:{exc.lineno}: not JSON ({exc.msg})") from None
    if not isinstance(doc, dict):
        raise TraceError(f"{name}: expected a GeoJSON object")
    if doc.get("type") == "FeatureCollection":
        out = []
        for i, f in enumerate(doc.get("features") or []):
            geom, props = (f or {}).get("geometry") or {}, (f or {}).get("properties") or {}
            if geom.get("type") != "Point":
                continue
            where = f"{name}: feature {i + 1}"
            lon, lat = (geom.get("coordinates") or [None, None])[:2]
            out.append(_fix(lat, lon, _time(props.get("time", props.get("t")), float(i),
                                            where), where))
        return out
    feature = doc if doc.get("type") == "Feature" else {"geometry": doc, "properties": {}}
    geom, props = feature.get("geometry") or {}, feature.get("properties") or {}
    if geom.get("type") not in ("LineString", "MultiPoint"):
        raise TraceError(f"{name}: expected a LineString, MultiPoint or FeatureCollection of "
                         f"Points, got {geom.get('type')!r}")
    times = props.get("times") or props.get("coordTimes") or []
    out = []
    for i, c in enumerate(geom.get("coordinates") or []):
        where = f"{name}: coordinate {i + 1}"
        if not isinstance(c, list) or len(c) < 2:
            raise TraceError(f"{where}: expected [lon, lat]")
        out.append(_fix(c[1], c[0], _time(times[i] if i < len(times) else None, float(i),
                                          where), where))
    return out


def _csv(text: str, name: str) -> list[TraceFix]:
    reader = csv.DictReader(io.StringIO(text))
    fields = {f.strip().lower(): f for f in reader.fieldnames or []}
    lat_key = fields.get("lat") or fields.get("latitude")
    lon_key = fields.get("lon") or fields.get("lng") or fields.get("longitude")
    time_key = fields.get("t") or fields.get("time") or fields.get("timestamp")
    if lat_key is None or lon_key is None:
        raise TraceError(f"{name}:1: the header needs lat and lon columns")
    out = []
    for i, row in enumerate(reader):
        where = f"{name}:{reader.line_num}"
        out.append(_fix(row.get(lat_key), row.get(lon_key),
                        _time(row.get(time_key) if time_key else None, float(i), where), where))
    return out


def _jsonl(text: str, name: str) -> list[TraceFix]:
    out: list[TraceFix] = []
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        where = f"{name}:{number}"
        try:
            obj = json.loads(line)
        except json.JSONDecodeError as exc:
            raise TraceError(f"{where}: not JSON ({exc.msg})") from None
        if not isinstance(obj, dict):
            raise TraceError(f"{where}: expected a JSON object")
        if obj.get("kind", "gps") != "gps":
            continue
        out.append(_fix(obj.get("lat"), obj.get("lon"), _time(obj.get("t"), float(len(out)),
                                                              where), where))
    return out
