"""A synthetic track line made of constant-curvature, constant-grade segments.

It offers the subset of the ``track_db.TrackLine`` interface the simulator uses (``line_id``,
``length_m``, ``latlon_at``, ``alt_at``, ``heading_at``, ``curvature_at``, ``grade_at``), all
vectorised, so that physics and sensor tests can use geometry whose curvature and grade are known
exactly. Positions come from integrating the heading on a fine grid and mapping the local east/north
plane to WGS84 with the local radii of curvature at the origin (exact enough for a few km).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import ScenarioError

WGS84_A_M = 6378137.0  #: WGS84 semi-major axis [m]
WGS84_E2 = 6.69437999014e-3  #: WGS84 first eccentricity squared [-]


def meridian_radius_m(lat_deg):
    """Meridian radius of curvature M(lat) [m]."""
    s = np.sin(np.radians(lat_deg))
    return WGS84_A_M * (1 - WGS84_E2) / (1 - WGS84_E2 * s * s) ** 1.5


def normal_radius_m(lat_deg):
    """Prime-vertical radius of curvature N(lat) [m]."""
    s = np.sin(np.radians(lat_deg))
    return WGS84_A_M / np.sqrt(1 - WGS84_E2 * s * s)


@dataclass(frozen=True)
class Segment:
    """One piece of a synthetic line."""

    length_m: float  #: segment length [m]
    curvature_per_m: float = 0.0  #: signed curvature, > 0 turning right [1/m]
    grade: float = 0.0  #: dz/ds, > 0 climbing [-]


class SyntheticTrack:
    """Track line from segments (see module doc)."""

    def __init__(
        self,
        segments: list[Segment],
        *,
        origin_lat_deg: float = 50.93,
        origin_lon_deg: float = 11.59,
        origin_alt_m: float = 150.0,
        heading0_rad: float = 0.0,
        line_id: int = 1,
        step_m: float = 0.25,
    ):
        if not segments or any(seg.length_m <= 0 for seg in segments):
            raise ScenarioError("a synthetic track needs segments of positive length")
        self.line_id = line_id
        self.name = "synthetic"
        self._bounds = np.concatenate(([0.0], np.cumsum([seg.length_m for seg in segments])))
        self.length_m = float(self._bounds[-1])
        self._k = np.array([seg.curvature_per_m for seg in segments], dtype=float)
        self._g = np.array([seg.grade for seg in segments], dtype=float)
        n = int(math.ceil(self.length_m / step_m)) + 1
        s = np.linspace(0.0, self.length_m, n)
        k = self.curvature_at(s)
        heading = heading0_rad + np.concatenate(([0.0], np.cumsum(0.5 * (k[1:] + k[:-1]) * np.diff(s))))
        ds = np.diff(s)
        hm = 0.5 * (heading[1:] + heading[:-1])
        east = np.concatenate(([0.0], np.cumsum(np.sin(hm) * ds)))
        north = np.concatenate(([0.0], np.cumsum(np.cos(hm) * ds)))
        g = self.grade_at(s)
        alt = origin_alt_m + np.concatenate(([0.0], np.cumsum(0.5 * (g[1:] + g[:-1]) * ds)))
        self._s, self._heading, self._east, self._north, self._alt = s, heading, east, north, alt
        self._lat0, self._lon0 = origin_lat_deg, origin_lon_deg
        self._m = float(meridian_radius_m(origin_lat_deg))
        self._n = float(normal_radius_m(origin_lat_deg))

    def _segment(self, s_m):
        s = np.clip(np.asarray(s_m, dtype=float), 0.0, self.length_m)
        return np.clip(np.searchsorted(self._bounds, s, side="right") - 1, 0, self._k.size - 1)

    def curvature_at(self, s_m):
        """Signed curvature [1/m]."""
        return self._k[self._segment(s_m)]

    def grade_at(self, s_m):
        """Grade dz/ds [-]."""
        return self._g[self._segment(s_m)]

    def heading_at(self, s_m):
        """Heading clockwise from north [rad]."""
        return np.interp(s_m, self._s, self._heading)

    def point_at(self, s_m):
        """Local (east, north) [m] from the first vertex."""
        return np.interp(s_m, self._s, self._east), np.interp(s_m, self._s, self._north)

    def alt_at(self, s_m):
        """Altitude [m]."""
        return np.interp(s_m, self._s, self._alt)

    def latlon_at(self, s_m):
        """WGS84 latitude and longitude [deg]."""
        east, north = self.point_at(s_m)
        lat = self._lat0 + np.degrees(north / self._m)
        lon = self._lon0 + np.degrees(east / (self._n * math.cos(math.radians(self._lat0))))
        return lat, lon
