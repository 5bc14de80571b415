"""The digitised track database (SQLite) and its geometry.

Open a database with :meth:`TrackDatabase.open`; build one with :func:`track_db.build.create_database`
(arrays) or the importers (``sfa track import``). The bundled Jena tram network is at
:func:`default_database_path`. Schema and methods: docs/track-db.md.
"""

from __future__ import annotations

from pathlib import Path

from .database import Junction, LineInfo, Projection, ProjectionArrays, Stop, TrackDatabase
from .errors import BASE_ERROR, ImportFailed, QueryError, SchemaError, TrackDbError
from .line import TrackLine

__all__ = [
    "BASE_ERROR",
    "ImportFailed",
    "Junction",
    "LineInfo",
    "Projection",
    "ProjectionArrays",
    "QueryError",
    "SchemaError",
    "Stop",
    "TrackDatabase",
    "TrackDbError",
    "TrackLine",
    "default_database_path",
]


def default_database_path() -> Path:
    """The bundled default database: the Jena tram network (OpenStreetMap, ODbL 1.0), data/jena-tram.db."""
    return Path(__file__).resolve().parent / "data" / "jena-tram.db"
