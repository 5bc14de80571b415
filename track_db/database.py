"""TrackDatabase: read access to a track database file (the contract of docs/architecture.md)."""

from __future__ import annotations

import json
import sqlite3
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from .errors import QueryError, SchemaError
from .geodesy import LocalFrame, check_latlon
from .line import TrackLine
from .schema import read_meta
from .segments import SegmentIndex

__all__ = ["Junction", "LineInfo", "Projection", "ProjectionArrays", "Stop", "TrackDatabase"]


@dataclass(frozen=True)
class LineInfo:
    line_id: int
    name: str
    length_m: float  #: WGS84 geodesic polyline length [m]
    n_vertices: int
    source: str
    attribution: str
    has_altitude: bool = False
    min_radius_m: float | None = None  #: tightest radius of the smoothed curvature [m]; None if straight
    properties: dict = field(default_factory=dict, compare=False)  #: source tags (OSM, GTFS ...)


@dataclass(frozen=True)
class Projection:
    """A position projected onto the network."""

    line_id: int
    s_m: float  #: arc length of the nearest point [m]
    offset_m: float  #: signed lateral offset, > 0 right of the direction of increasing s [m]
    distance_m: float  #: |offset_m| [m]


@dataclass(frozen=True)
class ProjectionArrays:
    """Vectorised projections (``locate_many``): equal-length arrays; index it for a Projection."""

    line_id: np.ndarray
    s_m: np.ndarray
    offset_m: np.ndarray
    distance_m: np.ndarray

    def __len__(self) -> int:
        return int(self.s_m.size)

    def __getitem__(self, k: int) -> Projection:
        return Projection(
            int(self.line_id[k]), float(self.s_m[k]), float(self.offset_m[k]), float(self.distance_m[k])
        )


@dataclass(frozen=True)
class Junction:
    """Two lines meeting at a branch point of the network (see docs/track-db.md, Topology)."""

    line_a: int
    s_a_m: float  #: arc length of the junction on line_a [m]
    line_b: int
    s_b_m: float  #: arc length of the junction on line_b [m]
    lat_deg: float
    lon_deg: float
    kind: str = "diverge"  #: "diverge", "crossing" or "end"
    node_id: int = 0  #: branch point number; several junctions share a node where many lines meet

    @property
    def lat(self) -> float:
        return self.lat_deg

    @property
    def lon(self) -> float:
        return self.lon_deg


@dataclass(frozen=True)
class Stop:
    name: str
    line_id: int
    s_m: float  #: arc length of the stop's projection on the line [m]
    offset_m: float  #: lateral offset of the stop's point (platform/node) from the line [m]
    lat_deg: float
    lon_deg: float


class TrackDatabase:
    """An open track database. Lines are loaded on first use and cached in memory."""

    def __init__(self, path: Path, conn: sqlite3.Connection, meta: dict[str, str]) -> None:
        self.path = path
        self._conn = conn
        self.meta = meta
        self.frame = LocalFrame.from_proj(meta["projection"])
        self.projection = meta["projection"]
        self.default_line_id = int(meta["default_line_id"])
        self._lines: dict[int, TrackLine] = {}
        self._infos = self._read_infos()
        if self.default_line_id not in self._infos:
            raise SchemaError(f"{path}: default line {self.default_line_id} does not exist")

    @classmethod
    def open(cls, path: str | Path) -> TrackDatabase:
        """Open a track database read-only. Raises SchemaError if it is not one (or not readable)."""
        path = Path(path)
        if not path.is_file():
            raise SchemaError(f"{path}: no such file")
        try:
            conn = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True, check_same_thread=False)
            meta = read_meta(conn)
        except sqlite3.DatabaseError as exc:
            raise SchemaError(f"{path}: not a track database ({exc})") from None
        except SchemaError as exc:
            raise SchemaError(f"{path}: {exc}") from None
        try:
            return cls(path, conn, meta)
        except (KeyError, ValueError, sqlite3.DatabaseError) as exc:
            conn.close()
            raise SchemaError(f"{path}: damaged track database ({exc!r})") from None

    def close(self) -> None:
        self._conn.close()

    def __enter__(self) -> TrackDatabase:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _read_infos(self) -> dict[int, LineInfo]:
        rows = self._conn.execute(
            "SELECT line_id, name, length_m, n_vertices, source, attribution, has_altitude, min_radius_m, "
            "properties FROM lines ORDER BY line_id"
        )
        return {
            r[0]: LineInfo(
                r[0], r[1], r[2], r[3], r[4] or "", r[5] or "", bool(r[6]), r[7], json.loads(r[8] or "{}")
            )
            for r in rows
        }

    def lines(self) -> list[LineInfo]:
        return list(self._infos.values())

    def line(self, line_id: int | None = None) -> TrackLine:
        """The line ``line_id`` (None: the default line), loaded once and cached."""
        lid = self.default_line_id if line_id is None else int(line_id)
        cached = self._lines.get(lid)
        if cached is not None:
            return cached
        info = self._infos.get(lid)
        if info is None:
            raise QueryError(f"no line {lid} in {self.path.name} (lines: {sorted(self._infos)})")
        v = np.array(
            self._conn.execute(
                "SELECT s_m, lat_deg, lon_deg, COALESCE(alt_m, 'nan'), east_m, north_m FROM vertices "
                "WHERE line_id = ? ORDER BY idx",
                (lid,),
            ).fetchall(),
            dtype=np.float64,
        )
        prof = self._conn.execute(
            "SELECT step_m, n_samples, heading_rad, curvature_per_m, grade FROM profiles WHERE line_id = ?",
            (lid,),
        ).fetchone()
        if v.shape[0] < 2 or prof is None:
            raise SchemaError(f"{self.path}: line {lid} has no geometry or no profile")
        step, n, *blobs = prof
        try:
            arrays = [np.frombuffer(b, dtype="<f8").astype(np.float64) for b in blobs]
        except (TypeError, ValueError):
            arrays = []
        if len(arrays) != 3 or any(a.size != n for a in arrays):
            raise SchemaError(f"{self.path}: profile of line {lid} is damaged")
        line = TrackLine(
            line_id=lid,
            name=info.name,
            frame=self.frame,
            s_m=np.ascontiguousarray(v[:, 0]),
            lat_deg=np.ascontiguousarray(v[:, 1]),
            lon_deg=np.ascontiguousarray(v[:, 2]),
            alt_m=np.ascontiguousarray(v[:, 3]),
            east_m=np.ascontiguousarray(v[:, 4]),
            north_m=np.ascontiguousarray(v[:, 5]),
            profile_step_m=step,
            heading_rad=arrays[0],
            curvature_per_m=arrays[1],
            grade=arrays[2],
            has_altitude=info.has_altitude,
            source=info.source,
            attribution=info.attribution,
        )
        self._lines[lid] = line
        return line

    # ---- network queries -------------------------------------------------------------------------
    @cached_property
    def _network_index(self) -> SegmentIndex:
        return SegmentIndex.for_lines(
            (ln.line_id, ln.s_m, ln.east_m, ln.north_m) for ln in (self.line(i) for i in self._infos)
        )

    def locate_many(self, lat_deg, lon_deg) -> ProjectionArrays:
        """Nearest line of the network for each position (arrays); ties go to the lowest line id."""
        lat = np.atleast_1d(np.asarray(lat_deg, dtype=np.float64)).ravel()
        lon = np.atleast_1d(np.asarray(lon_deg, dtype=np.float64)).ravel()
        if lat.shape != lon.shape:
            raise QueryError("latitude and longitude arrays differ in length")
        check_latlon(lat, lon)
        e, n = self.frame.to_local(lat, lon)
        res = self._network_index.nearest(e, n)
        return ProjectionArrays(res.line_id, res.s_m, res.offset_m, res.distance_m)

    def locate(self, lat_deg: float, lon_deg: float) -> Projection:
        """Nearest line of the network to one position."""
        return self.locate_many([lat_deg], [lon_deg])[0]

    def junctions(self) -> list[Junction]:
        rows = self._conn.execute(
            "SELECT line_a, s_a_m, line_b, s_b_m, lat_deg, lon_deg, kind, node_id FROM junctions "
            "ORDER BY junction_id"
        )
        return [Junction(*r) for r in rows]

    def stops(self, line_id: int | None = None) -> list[Stop]:
        """Named stops along a line (None: the default line), by arc length."""
        lid = self.default_line_id if line_id is None else int(line_id)
        rows = self._conn.execute(
            "SELECT name, line_id, s_m, offset_m, lat_deg, lon_deg FROM stops WHERE line_id = ? ORDER BY s_m",
            (lid,),
        )
        return [Stop(*r) for r in rows]

    def to_local(self, lat_deg, lon_deg):
        """(lat, lon) degrees -> (east_m, north_m) in the database's projection."""
        return self.frame.to_local(lat_deg, lon_deg)

    def to_geodetic(self, east_m, north_m):
        """(east_m, north_m) -> (lat_deg, lon_deg)."""
        return self.frame.to_geodetic(east_m, north_m)
