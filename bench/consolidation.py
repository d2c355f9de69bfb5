"""Which junction-consolidation tolerance? Node counts and junction artefacts per tolerance.

For each tolerance: nodes, edges, *stub edges* (edges shorter than 15 m between two
junctions of degree >= 3: the slivers that dual carriageways and roundabout entries leave, which
make one real intersection look like two), and *long merges* (consolidated nodes whose members
lie more than 30 m apart: over-merging that fuses separate intersections).

    python bench/consolidation.py [--map-source maps/monaco.osm.gz]
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import networkx as nx
from report import print_table, write_json
from tqdm import tqdm

from roadgraph.build import build_network
from roadgraph.geometry import LocalFrame
from roadgraph.osm import read_osm_file

ROOT = Path(__file__).resolve().parent.parent
TOLERANCES_M = (0.0, 5.0, 8.0, 10.0, 12.0, 15.0, 20.0, 25.0)


def measure(raw: nx.MultiDiGraph, tolerance_m: float,
            raw_lonlat: dict[int, tuple[float, float]]) -> dict[str, float]:
    net = build_network(raw, consolidate_m=tolerance_m)
    degree = {n.id: n.degree for n in net.nodes}
    stubs = sum(1 for e in net.edges
                if e.length_m < 15.0 and e.u != e.v and degree[e.u] >= 3 and degree[e.v] >= 3)
    frame = LocalFrame(net.info.crs_wkt)
    long_merges = 0
    for n in net.nodes:
        if len(n.osm_ids) < 2:
            continue
        pts = [frame.to_local(*raw_lonlat[i]) for i in n.osm_ids if i in raw_lonlat]
        spread = max(math.dist(a, b) for a in pts for b in pts)
        long_merges += spread > 30.0
    return {"tolerance_m": tolerance_m, "nodes": net.info.node_count,
            "edges": net.info.edge_count, "stub_edges_lt_15m": stubs,
            "merges_spanning_gt_30m": long_merges}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--map-source", type=Path, default=ROOT / "maps" / "monaco.osm.gz")
    args = parser.parse_args()
    raw = read_osm_file(args.map_source)
    positions = {int(n): (d["x"], d["y"]) for n, d in raw.nodes(data=True)}
    rows = [measure(raw, t, positions)
            for t in tqdm(TOLERANCES_M, desc="tolerances", leave=False)]
    print_table(f"Junction consolidation on {args.map_source.name}",
                list(rows[0]), [list(r.values()) for r in rows])
    write_json("consolidation", {"map": args.map_source.name, "rows": rows})


if __name__ == "__main__":
    main()
