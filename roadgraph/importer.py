"""`roadgraph import`: OSM source → intersection graph → road-graph database (I/O).

The output path is checked before any work, and the database is written atomically by the
store, so a failed import leaves nothing behind and never damages an existing database.
"""

from __future__ import annotations

import dataclasses
import logging
from datetime import UTC, datetime
from pathlib import Path

from tqdm import tqdm

from roadgraph.build import DEFAULT_CONSOLIDATE_M, MapInfo, build_network
from roadgraph.osm import download_graph, file_sha256, read_graphml, read_osm_file
from roadgraph.store import check_writable, write_network

log = logging.getLogger(__name__)


def import_map(
    output: Path,
    *,
    source: Path | None = None,
    place: str | None = None,
    bbox: tuple[float, float, float, float] | None = None,
    network: str = "drive",
    consolidate_m: float = DEFAULT_CONSOLIDATE_M,
    progress: bool = False,
) -> MapInfo:
    """Import one map from a local file, a place name or a bounding box; return its summary."""
    if (source is None) == (place is None and bbox is None) or (place and bbox):
        raise ValueError("give exactly one of SOURCE, --place or --bbox")
    check_writable(output)
    steps = tqdm(total=3, desc="import", unit="step", leave=False,
                 disable=None if progress else True)
    with steps:
        steps.set_postfix_str("reading OSM")
        if source is not None and source.suffix == ".graphml":
            raw = read_graphml(source)
            name, sha = source.name, file_sha256(source)
        elif source is not None:
            raw = read_osm_file(source, network)
            name, sha = source.name, file_sha256(source)
        else:
            raw = download_graph(place=place, bbox=bbox, network=network)
            name, sha = (f"place:{place}" if place else f"bbox:{bbox}"), ""
        log.info("read %d OSM nodes, %d edges", raw.number_of_nodes(), raw.number_of_edges())
        steps.update()
        steps.set_postfix_str("building intersection graph")
        net = build_network(raw, consolidate_m=consolidate_m, network=network)
        info = dataclasses.replace(
            net.info, source_name=name, source_sha256=sha,
            created_utc=datetime.now(UTC).isoformat(timespec="seconds"),
        )
        net = dataclasses.replace(net, info=info)
        steps.update()
        steps.set_postfix_str("writing database")
        write_network(net, output)
        steps.update()
    log.info("wrote %s: %d nodes, %d edges", output, info.node_count, info.edge_count)
    return info
