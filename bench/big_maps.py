"""Big OSM extracts made by tiling real ones: ``.osm.pbf`` files of growing size for the
scaling benchmark (bench/roadgraph_bench.py ``--scaling``).

Each tile is a copy of a real extract (the bundled Monaco map by default) with new ids and
its positions moved by a whole number of tile widths in one metric frame (the UTM zone of the
first source), so that every road keeps its real shape and length there; tiles lie side by
side with a gap, and do not touch. Ids are dense (tile after tile, in the order of the
source's ids), as in a real country extract. Nodes and ways are kept with all their tags
(buildings, land use and foot paths too: the importer must skip them, as in a real file);
relations are left out (the road graph reads none).

The objects are written as OPL text to ``osmium cat`` (osmium-tool), which writes the PBF:
pyosmium's writer costs 5 µs a node from Python, too slow for 50 million nodes.

    python bench/big_maps.py --tiles 1 16 128 1024 3600 [--source maps/monaco.osm.gz ...]
        [--out bench/.cache/big_maps]
"""

from __future__ import annotations

import argparse
import math
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
import osmium

from roadgraph.geometry import LocalFrame

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_OUT = ROOT / "bench" / ".cache" / "big_maps"
GAP_M = 500.0  # between tiles: far more than the importer's consolidation tolerance


@dataclass(frozen=True)
class Source:
    """One real extract in memory: nodes (dense rank order) and ways, tags as OPL text."""

    name: str
    xy_m: npt.NDArray[np.float64]  # (n, 2) in the target frame, origin at the extract's corner
    node_tags: list[str]  # OPL tag lists, escaped
    way_tags: list[str]
    way_refs: list[npt.NDArray[np.int64]]  # each way's nodes as ranks into xy_m

    @property
    def size_m(self) -> tuple[float, float]:
        span = self.xy_m.max(axis=0)
        return float(span[0]), float(span[1])


def opl_escape(text: str) -> str:
    """OPL's escaping of a tag key or value: anything but plain printable ASCII as %hex%."""
    return "".join(c if (c.isascii() and c.isprintable() and c not in " ,=@%") else
                   f"%{ord(c):x}%" for c in text)


def _opl_tags(tags: osmium.osm.TagList) -> str:
    return ",".join(f"{opl_escape(t.k)}={opl_escape(t.v)}" for t in tags)


def read_source(path: Path) -> Source:
    """Read an extract's nodes and ways, positions in metres from the south-west corner of the
    box of its roads.

    Positions go through the extract's own UTM frame, so that shapes are those of a conformal
    map of the place itself. Nodes outside the box of the roads' nodes (a coastline or a
    boundary reaching far out) are left out, with the ways that use them."""
    ids, lonlat, node_tags = [], [], []
    ways: list[tuple[int, list[int], str, bool]] = []
    for obj in osmium.FileProcessor(str(path), osmium.osm.NODE | osmium.osm.WAY):
        if obj.is_node():
            if obj.location.valid():
                ids.append(obj.id)
                lonlat.append((obj.location.lon, obj.location.lat))
                node_tags.append(_opl_tags(obj.tags))
        else:
            ways.append((obj.id, [n.ref for n in obj.nodes], _opl_tags(obj.tags),
                         "highway" in obj.tags))
    order = np.argsort(ids)
    sorted_ids = np.asarray(ids, dtype=np.int64)[order]
    ll = np.asarray(lonlat, dtype=np.float64)[order]
    road_refs = np.unique(np.concatenate([w[1] for w in ways if w[3]]))
    road_ll = ll[np.searchsorted(sorted_ids, road_refs[np.isin(road_refs, sorted_ids)])]
    lo, hi = road_ll.min(axis=0), road_ll.max(axis=0)
    inside = np.all((ll >= lo) & (ll <= hi), axis=1)
    sorted_ids, ll = sorted_ids[inside], ll[inside]
    tags_in = [node_tags[i] for i, keep in zip(order.tolist(), inside.tolist()) if keep]
    centre = (lo + hi) / 2.0
    xy = LocalFrame.for_point(float(centre[0]), float(centre[1])).coords_to_local(ll)
    xy -= xy.min(axis=0)
    ways.sort()
    refs, tags = [], []
    for _, nodes, text, _ in ways:
        rank = np.minimum(np.searchsorted(sorted_ids, nodes), len(sorted_ids) - 1)
        if np.all(sorted_ids[rank] == np.asarray(nodes)):  # ways cut by the box: left out
            refs.append(rank)
            tags.append(text)
    return Source(path.name, xy, tags_in, tags, refs)


def tile_origins(n_tiles: int, cell_m: tuple[float, float]) -> npt.NDArray[np.float64]:
    """South-west corners of ``n_tiles`` tiles on a square grid, row by row (metres)."""
    cols = math.ceil(math.sqrt(n_tiles))
    k = np.arange(n_tiles)
    return np.column_stack([(k % cols) * cell_m[0], (k // cols) * cell_m[1]])


def write_tiled(sources: list[Source], n_tiles: int, frame: LocalFrame,
                anchor_m: tuple[float, float], out: Path) -> dict[str, int]:
    """Write ``n_tiles`` tiles (cycling through the sources) to ``out`` via ``osmium cat``."""
    width = max(s.size_m[0] for s in sources) + GAP_M
    height = max(s.size_m[1] for s in sources) + GAP_M
    origins = tile_origins(n_tiles, (width, height)) + np.asarray(anchor_m)
    plan = [sources[t % len(sources)] for t in range(n_tiles)]
    node_base = np.cumsum([0] + [len(s.xy_m) for s in plan]) + 1
    way_base = np.cumsum([0] + [len(s.way_refs) for s in plan]) + 1
    tmp = out.with_name(out.name + ".tmp.osm.pbf")
    cmd = ["osmium", "cat", "--input-format", "opl", "-", "-o", str(tmp), "--overwrite"]
    proc = subprocess.Popen(cmd, stdin=subprocess.PIPE)
    assert proc.stdin is not None
    try:
        for t, src in enumerate(plan):
            lonlat = frame.coords_to_wgs84(src.xy_m + origins[t])
            base = int(node_base[t])
            lines = [f"n{base + i} v1 x{lon:.7f} y{lat:.7f} T{tags}\n"
                     for i, ((lon, lat), tags) in enumerate(zip(lonlat.tolist(), src.node_tags))]
            proc.stdin.write("".join(lines).encode())
        for t, src in enumerate(plan):
            nb, wb = int(node_base[t]), int(way_base[t])
            lines = [f"w{wb + i} v1 T{tags} N{','.join(f'n{nb + r}' for r in refs.tolist())}\n"
                     for i, (refs, tags) in enumerate(zip(src.way_refs, src.way_tags))]
            proc.stdin.write("".join(lines).encode())
        proc.stdin.close()
        if proc.wait() != 0:
            raise RuntimeError(f"osmium cat failed for {out}")
    except BaseException:
        proc.kill()
        tmp.unlink(missing_ok=True)
        raise
    tmp.replace(out)
    return {"tiles": n_tiles, "nodes": int(node_base[-1] - 1), "ways": int(way_base[-1] - 1)}


def build(tiles: list[int], source_paths: list[Path], out_dir: Path,
          force: bool = False) -> list[Path]:
    """The tiled extracts (made when missing), one per tile count."""
    if shutil.which("osmium") is None:
        sys.exit("big_maps: needs osmium-tool (apt-get install osmium-tool)")
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = "+".join(p.name.split(".")[0] for p in source_paths)
    paths = [out_dir / f"{stem}-x{n}.osm.pbf" for n in tiles]
    todo = [(n, p) for n, p in zip(tiles, paths) if force or not p.exists()]
    if not todo:
        return paths
    first = osmium.FileProcessor(str(source_paths[0]), osmium.osm.NODE)
    lon0, lat0 = next((n.location.lon, n.location.lat) for n in first if n.location.valid())
    frame = LocalFrame.for_point(lon0, lat0)
    anchor = frame.to_local(lon0, lat0)
    sources = [read_source(p) for p in source_paths]
    for n, path in todo:
        t = time.perf_counter()
        counts = write_tiled(sources, n, frame, anchor, path)
        print(f"{path.name}: {counts['nodes']:,} nodes, {counts['ways']:,} ways, "
              f"{path.stat().st_size / 2**20:.1f} MiB in {time.perf_counter() - t:.1f} s")
    return paths


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tiles", type=int, nargs="+", default=[1, 16, 128, 1024, 3600])
    parser.add_argument("--source", type=Path, nargs="+",
                        default=[ROOT / "maps" / "monaco.osm.gz"])
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    parser.add_argument("--force", action="store_true", help="rewrite existing files")
    args = parser.parse_args()
    for path in build(args.tiles, args.source, args.out, args.force):
        print(path)


if __name__ == "__main__":
    main()
