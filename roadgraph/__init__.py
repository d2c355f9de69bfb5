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
from roadgraph.importer import import_map

__all__ = [
    "EdgeKey", "EdgeProjection", "EdgeRecord", "GraphArrays", "LocalFrame", "MapDatabaseError",
    "MapInfo", "MapSourceError", "NoDrivableRoadError", "NodeRecord", "RoadGraph",
    "RoadGraphError", "RoadNetwork", "SchemaVersionError", "import_map",
]
