"""Errors raised by the road-graph package.

::

    RoadGraphError                 anything this package refuses to do
    ├── MapSourceError             the OSM source is missing, unreadable, truncated, or unknown
    │   └── NoDrivableRoadError    the source holds no road of the requested network
    └── MapDatabaseError           the road-graph database cannot be written or read
        └── SchemaVersionError     the database was written by another schema version

Every message names the file (or place) and the problem, so the CLI prints it as is.
"""


class RoadGraphError(Exception):
    """Base of every error this package raises."""


class MapSourceError(RoadGraphError):
    """The OSM source cannot be used."""


class NoDrivableRoadError(MapSourceError):
    """The source holds no road of the requested network type."""


class MapDatabaseError(RoadGraphError):
    """The road-graph database cannot be written or read."""


class SchemaVersionError(MapDatabaseError):
    """The database's schema version is not the one this code reads."""
