"""Building track databases: validated geometry in, a complete SQLite file out, in one transaction.

Typical use (also the way tests make synthetic tracks)::

    from track_db.build import LineGeometry, create_database
    create_database(tmp_path / "t.db", [LineGeometry("straight", lat_deg, lon_deg)])

Everything is validated and computed in memory first (arc length, local coordinates, profiles,
junctions, stop positions); only then is the file written, in one transaction. A new database is
written to a temporary file next to the target and renamed into place, so a failed build leaves no
file (and never a half-written one); :func:`append_lines` adds lines to an existing database in one
SQLite transaction, so a failure leaves it byte-for-byte unchanged.
"""

from __future__ import annotations

import json
import math
import os
import sqlite3
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import sqlite_utils

from .errors import ImportFailed, SchemaError
from .geodesy import LocalFrame, centred_proj_string
from .schema import create_schema, read_meta
from .segments import SegmentIndex
from .smoothing import Profile, compute_profile
from .topology import find_junctions
from .validate import validate_vertices

__all__ = ["BuildConfig", "LineGeometry", "StopPoint", "create_database", "append_lines"]


@dataclass(frozen=True)
class BuildConfig:
    """Parameters of a database build; recorded in its ``meta`` table."""

    smoothing_sigma_m: float = 20.0  #: standard deviation of the Gaussian along-track smoothing kernel [m]
    profile_step_m: float = 2.0  #: maximum step of the heading/curvature/grade profile grid [m]
    junction_tolerance_m: float = 1.0  #: vertices closer than this are one network node [m]
    max_gap_m: float = 1000.0  #: longest accepted distance between consecutive vertices [m]
    stop_tolerance_m: float = 30.0  #: a stop belongs to every line passing within this distance [m]
    projection: str | None = None  #: PROJ string of the local frame; None: tmerc centred on the network

    def __post_init__(self) -> None:
        for name in (
            "smoothing_sigma_m",
            "profile_step_m",
            "junction_tolerance_m",
            "max_gap_m",
            "stop_tolerance_m",
        ):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ImportFailed(f"BuildConfig.{name} must be a positive finite number, got {value!r}")


@dataclass(frozen=True)
class LineGeometry:
    """One line to import: vertices in WGS84 degrees (and metres above MSL when known), in travel order."""

    name: str
    lat_deg: Sequence[float] | np.ndarray
    lon_deg: Sequence[float] | np.ndarray
    alt_m: Sequence[float] | np.ndarray | None = None
    source: str = ""  #: where the geometry comes from (file, feature, relation, shape id)
    attribution: str = ""  #: attribution/licence statement the data requires
    properties: Mapping[str, object] = field(default_factory=dict)  #: source tags, stored as JSON
    label: str = ""  #: how errors name this line (e.g. "feature 3 (rel/147372)"); default: its name
    vertex_refs: Sequence[str] | None = None  #: how errors name each vertex (e.g. "shapes.txt line 812")


@dataclass(frozen=True)
class StopPoint:
    """A named stop; stored once per line that passes within ``stop_tolerance_m``."""

    name: str
    lat_deg: float
    lon_deg: float
    #: index (in the lines being imported) of the one line this stop belongs to, e.g. an OSM route
    #: relation's stop member; None: every line passing within stop_tolerance_m
    line: int | None = None


@dataclass(frozen=True)
class _Derived:
    geometry: LineGeometry
    lat: np.ndarray
    lon: np.ndarray
    alt: np.ndarray | None
    s: np.ndarray
    east: np.ndarray
    north: np.ndarray
    profile: Profile
    min_radius_m: float | None


def _prepare(geometry: LineGeometry, index: int, config: BuildConfig) -> tuple:
    label = geometry.label or f"line {index + 1} ({geometry.name!r})"
    if not isinstance(geometry.name, str) or not geometry.name.strip():
        raise ImportFailed(f"{label}: empty line name")
    try:
        lat = np.ascontiguousarray(geometry.lat_deg, dtype=np.float64).ravel()
        lon = np.ascontiguousarray(geometry.lon_deg, dtype=np.float64).ravel()
        alt = (
            None if geometry.alt_m is None else np.ascontiguousarray(geometry.alt_m, dtype=np.float64).ravel()
        )
    except (TypeError, ValueError) as exc:
        raise ImportFailed(f"{label}: coordinates are not numbers ({exc})") from None
    seg = validate_vertices(label, lat, lon, alt, max_gap_m=config.max_gap_m, refs=geometry.vertex_refs)
    return label, lat, lon, alt, np.concatenate(([0.0], np.cumsum(seg)))


def _derive(geometry, lat, lon, alt, s, frame: LocalFrame, config: BuildConfig) -> _Derived:
    east, north = frame.to_local(lat, lon)
    profile = compute_profile(
        s, east, north, alt, sigma_m=config.smoothing_sigma_m, step_m=config.profile_step_m
    )
    kmax = float(np.max(np.abs(profile.curvature_per_m)))
    min_radius = 1.0 / kmax if kmax > 1e-9 else None
    return _Derived(geometry, lat, lon, alt, s, east, north, profile, min_radius)


def _line_rows(line_id: int, d: _Derived):
    g = d.geometry
    line_row = {
        "line_id": line_id,
        "name": g.name,
        "source": g.source,
        "attribution": g.attribution,
        "length_m": float(d.s[-1]),
        "n_vertices": int(d.s.size),
        "has_altitude": int(d.alt is not None),
        "min_radius_m": d.min_radius_m,
        "properties": json.dumps(dict(g.properties), sort_keys=True, ensure_ascii=False, default=str),
    }
    alt = d.alt if d.alt is not None else [None] * d.s.size
    vertex_rows = [
        {
            "line_id": line_id,
            "idx": i,
            "lat_deg": float(d.lat[i]),
            "lon_deg": float(d.lon[i]),
            "alt_m": None if alt[i] is None else float(alt[i]),
            "s_m": float(d.s[i]),
            "east_m": float(d.east[i]),
            "north_m": float(d.north[i]),
        }
        for i in range(d.s.size)
    ]
    p = d.profile
    profile_row = {
        "line_id": line_id,
        "step_m": p.step_m,
        "n_samples": int(p.heading_rad.size),
        "heading_rad": p.heading_rad.astype("<f8").tobytes(),
        "curvature_per_m": p.curvature_per_m.astype("<f8").tobytes(),
        "grade": p.grade.astype("<f8").tobytes(),
    }
    return line_row, vertex_rows, profile_row


def _stop_rows(
    stops: Sequence[StopPoint], lines: dict[int, _Derived], frame: LocalFrame, tol_m: float, first_id: int = 1
):
    """Stops within ``tol_m`` of each line (a stop with ``line`` set: of that line only)."""
    rows = []
    if not stops or not lines:
        return rows
    lat = np.array([st.lat_deg for st in stops], dtype=np.float64)
    lon = np.array([st.lon_deg for st in stops], dtype=np.float64)
    if not (np.all(np.isfinite(lat)) and np.all(np.isfinite(lon))):
        raise ImportFailed("stops: non-finite stop coordinates")
    e, n = frame.to_local(lat, lon)
    for line_id in sorted(lines):
        d = lines[line_id]
        index = SegmentIndex.for_line(line_id, d.s, d.east, d.north)
        res = index.nearest(np.atleast_1d(e), np.atleast_1d(n))
        own = np.array([st.line is None or st.line + first_id == line_id for st in stops])
        for k in np.flatnonzero((res.distance_m <= tol_m) & own):
            rows.append(
                {
                    "name": stops[k].name,
                    "lat_deg": float(lat[k]),
                    "lon_deg": float(lon[k]),
                    "line_id": line_id,
                    "s_m": float(res.s_m[k]),
                    "offset_m": float(res.offset_m[k]),
                }
            )
    rows.sort(key=lambda r: (r["line_id"], r["s_m"], r["name"]))
    return rows


def _junction_rows(all_lines: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]], frame, tol_m):
    ids = sorted(all_lines)
    rows = find_junctions(
        ids,
        [all_lines[i][0] for i in ids],
        [all_lines[i][1] for i in ids],
        [all_lines[i][2] for i in ids],
        tol_m,
    )
    if not rows:
        return []
    lat, lon = frame.to_geodetic(np.array([r.east_m for r in rows]), np.array([r.north_m for r in rows]))
    return [
        {
            "junction_id": k + 1,
            "node_id": r.node_id,
            "kind": r.kind,
            "line_a": r.line_a,
            "s_a_m": r.s_a_m,
            "line_b": r.line_b,
            "s_b_m": r.s_b_m,
            "lat_deg": float(lat[k]),
            "lon_deg": float(lon[k]),
        }
        for k, r in enumerate(rows)
    ]


def _write(db: sqlite_utils.Database, derived: dict[int, _Derived], junctions, stops) -> None:
    for line_id in sorted(derived):
        line_row, vertex_rows, profile_row = _line_rows(line_id, derived[line_id])
        db["lines"].insert(line_row)
        db["vertices"].insert_all(vertex_rows, batch_size=5000)
        db["profiles"].insert(profile_row)
    db.execute("DELETE FROM junctions")
    if junctions:
        db["junctions"].insert_all(junctions, batch_size=5000)
    if stops:
        db["stops"].insert_all(stops, batch_size=5000)


def _meta_rows(config: BuildConfig, proj: str, default_line_id: int) -> list[dict[str, str]]:
    meta = {
        "projection": proj,
        "arc_length": "WGS84 geodesic polyline length from the first vertex (pyproj Geod.inv per segment)",
        "smoothing_sigma_m": repr(config.smoothing_sigma_m),
        "profile_step_m": repr(config.profile_step_m),
        "junction_tolerance_m": repr(config.junction_tolerance_m),
        "max_gap_m": repr(config.max_gap_m),
        "stop_tolerance_m": repr(config.stop_tolerance_m),
        "default_line_id": str(default_line_id),
        "generator": "sfa track_db",
    }
    return [{"key": k, "value": v} for k, v in sorted(meta.items())]


def create_database(
    path: str | Path,
    lines: Sequence[LineGeometry],
    *,
    config: BuildConfig | None = None,
    stops: Sequence[StopPoint] = (),
    default_line: int = 0,
    overwrite: bool = False,
) -> Path:
    """Create the track database ``path`` from ``lines`` (line ids 1, 2, ... in the given order).

    ``default_line`` is the index in ``lines`` of the database's default line. Raises ImportFailed
    (nothing is written) for invalid geometry, an existing file without ``overwrite``, or a bad
    configuration.
    """
    config = config or BuildConfig()
    path = Path(path)
    if path.exists() and not overwrite:
        raise ImportFailed(f"{path} already exists (append to it, or overwrite it explicitly)")
    if not lines:
        raise ImportFailed("no lines to import")
    if not 0 <= default_line < len(lines):
        raise ImportFailed(f"default_line {default_line} is not an index of the {len(lines)} lines")
    prepared = [_prepare(g, i, config) for i, g in enumerate(lines)]
    proj = config.projection or centred_proj_string(
        np.concatenate([p[1] for p in prepared]), np.concatenate([p[2] for p in prepared])
    )
    try:
        frame = LocalFrame.from_proj(proj)
    except Exception as exc:  # pyproj raises CRSError and others for a bad PROJ string
        raise ImportFailed(f"projection {proj!r} is not usable: {exc}") from None
    derived = {
        i + 1: _derive(g, *p[1:], frame, config) for i, (g, p) in enumerate(zip(lines, prepared, strict=True))
    }
    junctions = _junction_rows(
        {k: (d.s, d.east, d.north) for k, d in derived.items()}, frame, config.junction_tolerance_m
    )
    stop_rows = _stop_rows(stops, derived, frame, config.stop_tolerance_m)

    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        tmp.unlink()
        db = sqlite_utils.Database(tmp)
        try:
            with db.atomic():
                create_schema(db)
                db["meta"].insert_all(_meta_rows(config, proj, default_line + 1), pk="key", replace=True)
                _write(db, derived, junctions, stop_rows)
            db.execute("VACUUM")
        finally:
            db.close()
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def _load_network(conn: sqlite3.Connection) -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    out: dict[int, list] = {}
    for line_id, s, e, n in conn.execute(
        "SELECT line_id, s_m, east_m, north_m FROM vertices ORDER BY line_id, idx"
    ):
        out.setdefault(line_id, []).append((s, e, n))
    return {k: tuple(np.array(col) for col in zip(*v, strict=True)) for k, v in out.items()}


def append_lines(
    path: str | Path,
    lines: Sequence[LineGeometry],
    *,
    stops: Sequence[StopPoint] = (),
    max_gap_m: float | None = None,
) -> list[int]:
    """Add lines to an existing database in one transaction; return their new line ids.

    The database keeps its projection and smoothing parameters (the new lines use them); junctions
    are recomputed over the whole network. On any error nothing is written.
    """
    path = Path(path)
    if not path.is_file():
        raise ImportFailed(f"{path}: no such track database to append to")
    if not lines:
        raise ImportFailed("no lines to import")
    conn = sqlite3.connect(path, isolation_level=None)
    try:
        try:
            meta = read_meta(conn)
        except SchemaError as exc:
            raise ImportFailed(f"{path}: {exc}") from None
        config = BuildConfig(
            smoothing_sigma_m=float(meta["smoothing_sigma_m"]),
            profile_step_m=float(meta["profile_step_m"]),
            junction_tolerance_m=float(meta["junction_tolerance_m"]),
            max_gap_m=float(max_gap_m if max_gap_m is not None else meta["max_gap_m"]),
            stop_tolerance_m=float(meta["stop_tolerance_m"]),
            projection=meta["projection"],
        )
        frame = LocalFrame.from_proj(meta["projection"])
        first_id = int(conn.execute("SELECT COALESCE(MAX(line_id), 0) FROM lines").fetchone()[0]) + 1
        prepared = [_prepare(g, i, config) for i, g in enumerate(lines)]
        derived = {
            first_id + i: _derive(g, *p[1:], frame, config)
            for i, (g, p) in enumerate(zip(lines, prepared, strict=True))
        }
        network = _load_network(conn)
        network.update({k: (d.s, d.east, d.north) for k, d in derived.items()})
        junctions = _junction_rows(network, frame, config.junction_tolerance_m)
        stop_rows = _stop_rows(stops, derived, frame, config.stop_tolerance_m, first_id)
        db = sqlite_utils.Database(conn)
        with db.atomic():
            _write(db, derived, junctions, stop_rows)
    finally:
        conn.close()
    return sorted(derived)
