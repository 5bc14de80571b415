"""A line's geometry as contiguous float64 arrays for the compiled kernels.

Positions are the database's own vertices plus points inserted on the segments every ``PROFILE_STEP_M``
(so ``h(s)`` is exactly the database's ``point_at``: linear within a segment); grade and curvature are
the database's smoothed values sampled at those points and interpolated linearly in between.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sfa.errors import FilterStateError

PROFILE_STEP_M = 4.0  #: spacing of the grade/curvature samples on long segments [m]


def _finite(values) -> np.ndarray:
    return np.nan_to_num(np.asarray(values, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)


@dataclass(frozen=True)
class TrackArrays:
    """Per-vertex arrays of one line (all float64, contiguous, equal length >= 2)."""

    line_id: int
    length_m: float  #: line length [m]
    s_m: np.ndarray  #: arc length per vertex, strictly increasing [m]
    east_m: np.ndarray  #: local east per vertex [m]
    north_m: np.ndarray  #: local north per vertex [m]
    grade: np.ndarray  #: smoothed dz/ds per vertex [-]
    curvature_inv_m: np.ndarray  #: smoothed signed curvature per vertex (> 0 turning right) [1/m]
    lat_deg: np.ndarray | None = None  #: WGS84 latitude per point (for reporting) [deg]
    lon_deg: np.ndarray | None = None  #: WGS84 longitude per point [deg]

    @classmethod
    def from_line(cls, line) -> TrackArrays:
        """Build from a ``track_db.TrackLine`` (s_m, east_m, north_m, grade_at, curvature_at)."""
        s = np.ascontiguousarray(line.s_m, dtype=np.float64)
        e = np.ascontiguousarray(line.east_m, dtype=np.float64)
        n = np.ascontiguousarray(line.north_m, dtype=np.float64)
        if s.ndim != 1 or s.shape[0] < 2 or e.shape != s.shape or n.shape != s.shape:
            raise FilterStateError(f"line {getattr(line, 'line_id', '?')}: needs >= 2 vertices")
        keep = np.concatenate(([True], np.diff(s) > 0.0))  # drop zero-length segments
        s, e, n = s[keep], e[keep], n[keep]
        finite = bool(np.all(np.isfinite(s)) and np.all(np.isfinite(e)) and np.all(np.isfinite(n)))
        if s.shape[0] < 2 or not finite:
            raise FilterStateError(f"line {getattr(line, 'line_id', '?')}: degenerate or non-finite geometry")
        grid = np.arange(s[0], s[-1], PROFILE_STEP_M)
        s_all = np.union1d(s, grid)
        s_all = s_all[np.concatenate(([True], np.diff(s_all) > 1e-6))]
        if s_all[-1] != s[-1]:
            s_all[-1] = s[-1]
        e, n = np.interp(s_all, s, e), np.interp(s_all, s, n)
        s = s_all
        grade = _finite(line.grade_at(s))
        curv = _finite(line.curvature_at(s))
        try:
            lat, lon = (np.ascontiguousarray(v, dtype=np.float64) for v in line.latlon_at(s))
        except Exception:  # a line without geodetic support still filters; lat/lon are then NaN
            lat = lon = None
        return cls(
            line_id=int(line.line_id),
            lat_deg=lat,
            lon_deg=lon,
            length_m=float(s[-1]),
            s_m=np.ascontiguousarray(s),
            east_m=np.ascontiguousarray(e),
            north_m=np.ascontiguousarray(n),
            grade=np.ascontiguousarray(grade),
            curvature_inv_m=np.ascontiguousarray(curv),
        )
