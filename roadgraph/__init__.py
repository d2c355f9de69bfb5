"""roadgraph: OpenStreetMap roads as an intersection graph in an SQLite database.

Knows nothing about vehicles. ``roadgraph import`` builds a database (osm → build → store);
services open it with :meth:`RoadGraph.open` and query it.
"""

from roadgraph.arrays import GraphArrays
from roadgraph.build import EdgeRecord, MapInfo, NodeRecord, RoadNetwork
from roadgraph.errors import (
    MapDatabaseError,
    MapSourceError,
    NoDrivableRoadError,
    RoadGraphError,
    SchemaVersionError,
)
from roadgraph.geometry import LocalFrame
from roadgraph.graph import EdgeKey, EdgeProjection, RoadGraph

__all__ = [
    "EdgeKey", "EdgeProjection", "EdgeRecord", "GraphArrays", "LocalFrame", "MapDatabaseError",
    "MapInfo", "MapSourceError", "NoDrivableRoadError", "NodeRecord", "RoadGraph",
    "RoadGraphError", "RoadNetwork", "SchemaVersionError", "import_map",
]


def __getattr__(name: str) -> object:
    """``import_map`` on first use: the importer's builder and readers (numba kernels,
    scipy, pyosmium) cost a second at start-up that opening a map does not need."""
    if name == "import_map":
        from roadgraph.importer import import_map

        return import_map
    raise AttributeError(f"module 'roadgraph' has no attribute {name!r}")
