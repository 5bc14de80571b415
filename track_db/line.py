"""TrackLine: the in-memory geometry of one line and the per-measurement queries of the filter.

Every query accepts a float or a numpy array (vectorised) and returns the same shape: a Python float
in gives floats out through a pure-Python fast path (about 1 us per query, for per-measurement use);
arrays (or numpy scalars) go through the vectorised numpy path. Both give identical results. Arc
lengths must be finite and within [0, length_m]; anything else raises QueryError.

Conventions (docs/architecture.md): local (east, north) metres of the database's projection;
heading clockwise from north; curvature > 0 turning right (FRD: yaw rate gz = v * k); lateral offset
> 0 to the right of the direction of increasing s; grade > 0 climbing.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from functools import cached_property

import numpy as np

from .errors import QueryError
from .geodesy import LocalFrame, check_latlon
from .segments import SegmentIndex
from .smoothing import hermite_derivative, hermite_value, linear_value

__all__ = ["TrackLine"]

#: arc lengths this far outside [0, length] are still accepted (rounding of callers' sums) [m]
_S_SLACK_M = 1e-9


def _shape_like(x, result):
    return result[()] if np.ndim(x) == 0 else result


class TrackLine:
    """One digitised line. Build it with ``TrackDatabase.line(line_id)``."""

    def __init__(
        self,
        *,
        line_id: int,
        name: str,
        frame: LocalFrame,
        s_m: np.ndarray,
        lat_deg: np.ndarray,
        lon_deg: np.ndarray,
        alt_m: np.ndarray,
        east_m: np.ndarray,
        north_m: np.ndarray,
        profile_step_m: float,
        heading_rad: np.ndarray,
        curvature_per_m: np.ndarray,
        grade: np.ndarray,
        has_altitude: bool,
        source: str = "",
        attribution: str = "",
    ) -> None:
        self.line_id = int(line_id)
        self.name = name
        self.source = source
        self.attribution = attribution
        self.has_altitude = bool(has_altitude)
        self._frame = frame
        self.s_m = s_m
        self.lat_deg = lat_deg
        self.lon_deg = lon_deg
        self.alt_m = alt_m  #: per vertex [m]; NaN when the line has no altitude
        self.east_m = east_m
        self.north_m = north_m
        self.length_m = float(s_m[-1])
        self.profile_step_m = float(profile_step_m)
        self.heading_rad = heading_rad  #: profile samples at i * profile_step_m
        self.curvature_per_m = curvature_per_m
        self.grade = grade
        # per-segment constants
        self._ds = np.diff(s_m)
        de = np.diff(east_m)
        dn = np.diff(north_m)
        seg_len = np.hypot(de, dn)
        self._de = de
        self._dn = dn
        self._te = de / seg_len
        self._tn = dn / seg_len
        for arr in (self.s_m, self.lat_deg, self.lon_deg, self.alt_m, self.east_m, self.north_m):
            arr.setflags(write=False)
        # plain-Python copies for the scalar fast path (one query per measurement: no numpy overhead)
        self._s_list = self.s_m.tolist()
        self._seg_list = list(
            zip(
                self.s_m[:-1].tolist(),
                self._ds.tolist(),
                self.east_m[:-1].tolist(),
                self.north_m[:-1].tolist(),
                de.tolist(),
                dn.tolist(),
                self._te.tolist(),
                self._tn.tolist(),
                strict=True,
            )
        )
        self._n_prof = int(self.heading_rad.size)
        self._heading_list = self.heading_rad.tolist()
        self._curv_list = self.curvature_per_m.tolist()
        self._grade_list = self.grade.tolist()

    @property
    def frame(self) -> LocalFrame:
        """The database's local metric frame (east, north) of this line."""
        return self._frame

    def __repr__(self) -> str:
        return f"TrackLine(line_id={self.line_id}, name={self.name!r}, length_m={self.length_m:.3f})"

    # ---- arc length -> geometry -------------------------------------------------------------
    def _scalar_s(self, s: float) -> float:
        if not math.isfinite(s):
            raise QueryError(f"line {self.line_id}: arc length must be finite")
        if s < -_S_SLACK_M or s > self.length_m + _S_SLACK_M:
            raise QueryError(f"line {self.line_id}: arc length {s:.3f} m outside [0, {self.length_m:.3f}] m")
        return min(max(s, 0.0), self.length_m)

    def _scalar_segment(self, s: float):
        i = min(max(bisect_right(self._s_list, s) - 1, 0), len(self._seg_list) - 1)
        return self._seg_list[i]

    def _scalar_cell(self, s: float) -> tuple[int, float]:
        u = s / self.profile_step_m
        i = min(max(int(u), 0), self._n_prof - 2)
        return i, u - i

    def _s(self, s_m) -> np.ndarray:
        s = np.asarray(s_m, dtype=np.float64)
        if not np.all(np.isfinite(s)):
            raise QueryError(f"line {self.line_id}: arc length must be finite")
        if s.size and (s.min() < -_S_SLACK_M or s.max() > self.length_m + _S_SLACK_M):
            raise QueryError(
                f"line {self.line_id}: arc length outside [0, {self.length_m:.3f}] m "
                f"(got {float(s.min()):.3f} .. {float(s.max()):.3f})"
            )
        return np.clip(s, 0.0, self.length_m)

    def _segment(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        i = np.searchsorted(self.s_m, s, side="right") - 1
        i = np.clip(i, 0, self._ds.size - 1)
        return i, (s - self.s_m[i]) / self._ds[i]

    def point_at(self, s_m):
        """(east_m, north_m) of the point at arc length s_m: linear within each segment."""
        if type(s_m) is float or type(s_m) is int:
            s = self._scalar_s(float(s_m))
            s0, ds, e0, n0, de, dn, _, _ = self._scalar_segment(s)
            t = (s - s0) / ds
            return e0 + t * de, n0 + t * dn
        s = self._s(s_m)
        i, t = self._segment(s)
        e = self.east_m[i] + t * self._de[i]
        n = self.north_m[i] + t * self._dn[i]
        return _shape_like(s_m, e), _shape_like(s_m, n)

    def tangent_at(self, s_m):
        """(te, tn): unit tangent of the segment at s_m in the local frame, towards increasing s."""
        if type(s_m) is float or type(s_m) is int:
            seg = self._scalar_segment(self._scalar_s(float(s_m)))
            return seg[6], seg[7]
        s = self._s(s_m)
        i, _ = self._segment(s)
        return _shape_like(s_m, self._te[i]), _shape_like(s_m, self._tn[i])

    def latlon_at(self, s_m):
        """(lat_deg, lon_deg) of the point at arc length s_m."""
        e, n = self.point_at(s_m)
        lat, lon = self._frame.to_geodetic(e, n)
        return _shape_like(s_m, lat), _shape_like(s_m, lon)

    def alt_at(self, s_m):
        """Altitude [m] interpolated linearly between vertices; 0.0 on lines without altitude."""
        s = self._s(s_m)
        if not self.has_altitude:
            return _shape_like(s_m, np.zeros_like(s))
        return _shape_like(s_m, np.interp(s, self.s_m, self.alt_m))

    def heading_at(self, s_m):
        """Smoothed heading [rad], clockwise from north (0 north, pi/2 east), unwrapped along the line."""
        if type(s_m) is float or type(s_m) is int:
            i, t = self._scalar_cell(self._scalar_s(float(s_m)))
            y, dy, h = self._heading_list, self._curv_list, self.profile_step_m
            t2 = t * t
            t3 = t2 * t
            return (
                (2 * t3 - 3 * t2 + 1) * y[i]
                + (t3 - 2 * t2 + t) * h * dy[i]
                + (-2 * t3 + 3 * t2) * y[i + 1]
                + (t3 - t2) * h * dy[i + 1]
            )
        s = self._s(s_m)
        return _shape_like(s_m, hermite_value(s, self.profile_step_m, self.heading_rad, self.curvature_per_m))

    def curvature_at(self, s_m):
        """Smoothed signed curvature [1/m] = d(heading_at)/ds; > 0 turning right (clockwise)."""
        if type(s_m) is float or type(s_m) is int:
            i, t = self._scalar_cell(self._scalar_s(float(s_m)))
            y, dy = self._heading_list, self._curv_list
            t2 = t * t
            return (
                ((6 * t2 - 6 * t) * y[i] + (-6 * t2 + 6 * t) * y[i + 1]) / self.profile_step_m
                + (3 * t2 - 4 * t + 1) * dy[i]
                + (3 * t2 - 2 * t) * dy[i + 1]
            )
        s = self._s(s_m)
        return _shape_like(
            s_m, hermite_derivative(s, self.profile_step_m, self.heading_rad, self.curvature_per_m)
        )

    def grade_at(self, s_m):
        """Smoothed grade dAlt/ds [dimensionless], > 0 climbing; 0 on lines without altitude."""
        if type(s_m) is float or type(s_m) is int:
            i, t = self._scalar_cell(self._scalar_s(float(s_m)))
            g = self._grade_list
            return g[i] + t * (g[i + 1] - g[i])
        s = self._s(s_m)
        return _shape_like(s_m, linear_value(s, self.profile_step_m, self.grade))

    # ---- position -> arc length -----------------------------------------------------------------
    @cached_property
    def _index(self) -> SegmentIndex:
        return SegmentIndex.for_line(self.line_id, self.s_m, self.east_m, self.north_m)

    def project(self, east_m, north_m):
        """(s_m, offset_m) of the nearest point of the line; offset > 0 right of the direction of travel."""
        e = np.asarray(east_m, dtype=np.float64)
        n = np.asarray(north_m, dtype=np.float64)
        if e.shape != n.shape:
            raise QueryError("east_m and north_m differ in shape")
        if not (np.all(np.isfinite(e)) and np.all(np.isfinite(n))):
            raise QueryError("coordinates to project must be finite")
        res = self._index.nearest(e.ravel(), n.ravel())
        return (
            _shape_like(east_m, res.s_m.reshape(e.shape)),
            _shape_like(east_m, res.offset_m.reshape(e.shape)),
        )

    def project_latlon(self, lat_deg, lon_deg):
        """(s_m, offset_m) of the nearest point of the line to (lat_deg, lon_deg)."""
        lat = np.asarray(lat_deg, dtype=np.float64)
        lon = np.asarray(lon_deg, dtype=np.float64)
        check_latlon(lat, lon)
        e, n = self._frame.to_local(lat, lon)
        s, off = self.project(e, n)
        return _shape_like(lat_deg, np.asarray(s)), _shape_like(lat_deg, np.asarray(off))

    def arrays(self) -> dict[str, np.ndarray]:
        """Contiguous float64 arrays for compiled paths (see track_db.compiled).

        Per vertex: s_m, east_m, north_m, lat_deg, lon_deg, alt_m. Per profile sample (at
        i * profile_step_m): heading_rad, curvature_per_m, grade. Scalars as 1-element arrays:
        profile_step_m, length_m.
        """
        return {
            "s_m": np.ascontiguousarray(self.s_m),
            "east_m": np.ascontiguousarray(self.east_m),
            "north_m": np.ascontiguousarray(self.north_m),
            "lat_deg": np.ascontiguousarray(self.lat_deg),
            "lon_deg": np.ascontiguousarray(self.lon_deg),
            "alt_m": np.ascontiguousarray(self.alt_m),
            "heading_rad": np.ascontiguousarray(self.heading_rad),
            "curvature_per_m": np.ascontiguousarray(self.curvature_per_m),
            "grade": np.ascontiguousarray(self.grade),
            "profile_step_m": np.array([self.profile_step_m]),
            "length_m": np.array([self.length_m]),
        }
