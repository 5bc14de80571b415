"""SQLite schema of a track database, created and migrated with sqlite-utils.

The full description (every table, column, unit and meta key) is in docs/track-db.md. The schema
version is the ``schema_version`` key of the ``meta`` table; :func:`migrate` brings an older database
up to :data:`SCHEMA_VERSION` step by step, and refuses a newer one.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Callable

import sqlite_utils

from .errors import SchemaError

__all__ = ["SCHEMA_VERSION", "create_schema", "migrate", "read_meta", "schema_version"]

#: version written by this code; bump it and append a step to ``_MIGRATIONS`` for every change
SCHEMA_VERSION = 1


def _create_v1(db: sqlite_utils.Database) -> None:
    db["meta"].create({"key": str, "value": str}, pk="key")
    db["lines"].create(
        {
            "line_id": int,
            "name": str,
            "source": str,
            "attribution": str,
            "length_m": float,
            "n_vertices": int,
            "has_altitude": int,
            "min_radius_m": float,
            "properties": str,
        },
        pk="line_id",
        not_null={"name", "length_m", "n_vertices", "has_altitude"},
    )
    db["vertices"].create(
        {
            "line_id": int,
            "idx": int,
            "lat_deg": float,
            "lon_deg": float,
            "alt_m": float,
            "s_m": float,
            "east_m": float,
            "north_m": float,
        },
        pk=("line_id", "idx"),
        foreign_keys=[("line_id", "lines", "line_id")],
        not_null={"lat_deg", "lon_deg", "s_m", "east_m", "north_m"},
    )
    db["profiles"].create(
        {
            "line_id": int,
            "step_m": float,
            "n_samples": int,
            "heading_rad": bytes,
            "curvature_per_m": bytes,
            "grade": bytes,
        },
        pk="line_id",
        foreign_keys=[("line_id", "lines", "line_id")],
        not_null={"step_m", "n_samples", "heading_rad", "curvature_per_m", "grade"},
    )
    db["junctions"].create(
        {
            "junction_id": int,
            "node_id": int,
            "kind": str,
            "line_a": int,
            "s_a_m": float,
            "line_b": int,
            "s_b_m": float,
            "lat_deg": float,
            "lon_deg": float,
        },
        pk="junction_id",
        foreign_keys=[("line_a", "lines", "line_id"), ("line_b", "lines", "line_id")],
    )
    db["stops"].create(
        {
            "stop_id": int,
            "name": str,
            "lat_deg": float,
            "lon_deg": float,
            "line_id": int,
            "s_m": float,
            "offset_m": float,
        },
        pk="stop_id",
        foreign_keys=[("line_id", "lines", "line_id")],
    )
    db["stops"].create_index(["line_id", "s_m"])
    db["junctions"].create_index(["line_a"])
    db["junctions"].create_index(["line_b"])


#: _MIGRATIONS[k] takes a database at version k to version k + 1 (version 0 = empty file)
_MIGRATIONS: list[Callable[[sqlite_utils.Database], None]] = [_create_v1]
assert len(_MIGRATIONS) == SCHEMA_VERSION


def schema_version(conn: sqlite3.Connection) -> int:
    """Schema version of an open database: 0 for an empty file; SchemaError if it is not a track database."""
    try:
        tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    except sqlite3.DatabaseError as exc:
        raise SchemaError(f"not an SQLite database: {exc}") from None
    if not tables:
        return 0
    if "meta" not in tables:
        raise SchemaError("not a track database (no meta table)")
    row = conn.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()
    if row is None:
        raise SchemaError("not a track database (no schema_version in meta)")
    try:
        return int(row[0])
    except ValueError:
        raise SchemaError(f"bad schema_version {row[0]!r}") from None


def migrate(db: sqlite_utils.Database) -> int:
    """Create or upgrade the schema of ``db`` to SCHEMA_VERSION inside the caller's transaction."""
    version = schema_version(db.conn)
    if version > SCHEMA_VERSION:
        raise SchemaError(f"schema version {version} is newer than this software ({SCHEMA_VERSION})")
    for step in range(version, SCHEMA_VERSION):
        _MIGRATIONS[step](db)
        db["meta"].upsert({"key": "schema_version", "value": str(step + 1)}, pk="key")
    return SCHEMA_VERSION


def create_schema(db: sqlite_utils.Database) -> None:
    """Schema of a new (empty) database."""
    if schema_version(db.conn) != 0:
        raise SchemaError("database is not empty")
    migrate(db)


def read_meta(conn: sqlite3.Connection) -> dict[str, str]:
    """All meta keys of a database whose version this software reads."""
    version = schema_version(conn)
    if version == 0:
        raise SchemaError("empty file: not a track database")
    if version != SCHEMA_VERSION:
        raise SchemaError(f"schema version {version}; this software reads version {SCHEMA_VERSION}")
    return {k: v for k, v in conn.execute("SELECT key, value FROM meta")}
