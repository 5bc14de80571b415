"""Geodesy of the track database: WGS84 geodesic arc length and the per-database local metric frame.

Arc length on the wire is the WGS84 geodesic length of the digitised polyline, measured along its
straight segments from the first vertex (wire protocol). It is computed here with pyproj's ``Geod``
(Karney's algorithm, accurate to nanometres), one inverse problem per segment.

Local metric coordinates (east, north) come from a transverse Mercator projection centred on the
network, chosen once when the database is created and recorded in it as a PROJ string. The pyproj
``Transformer`` pair is built once per database and reused (building one per call costs ~25,000x more).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pyproj import CRS, Geod, Transformer

__all__ = [
    "WGS84",
    "LocalFrame",
    "check_latlon",
    "geodesic_arc_length_m",
    "segment_lengths_m",
    "tmerc_proj_string",
]

#: the WGS84 ellipsoid used for every arc length in the project
WGS84 = Geod(ellps="WGS84")

#: geographic WGS84 (EPSG:4326) used with ``always_xy=True``: (lon, lat) order in every transform
_GEOGRAPHIC = CRS.from_epsg(4326)


def check_latlon(lat_deg, lon_deg) -> None:
    """Raise QueryError naming the first latitude outside -90..90 deg or longitude outside -180..180 deg
    (or non-finite value); a projection of such a point would be meaningless, not an error later on."""
    from .errors import QueryError

    for what, values, limit in (("latitude", lat_deg, 90.0), ("longitude", lon_deg, 180.0)):
        v = np.atleast_1d(np.asarray(values, dtype=np.float64)).ravel()
        bad = ~(np.isfinite(v) & (np.abs(v) <= limit))
        if bad.any():
            raise QueryError(f"{what} {float(v[bad][0]):g} deg is outside -{limit:g}..{limit:g} deg")


def segment_lengths_m(lat_deg: np.ndarray, lon_deg: np.ndarray) -> np.ndarray:
    """WGS84 geodesic length of each segment (n-1 values) of the polyline through the given vertices."""
    lat = np.asarray(lat_deg, dtype=np.float64)
    lon = np.asarray(lon_deg, dtype=np.float64)
    if lat.size < 2:
        return np.zeros(0)
    _, _, dist = WGS84.inv(lon[:-1], lat[:-1], lon[1:], lat[1:])
    return np.asarray(dist, dtype=np.float64)


def geodesic_arc_length_m(lat_deg: np.ndarray, lon_deg: np.ndarray) -> np.ndarray:
    """Per-vertex arc length: cumulative WGS84 geodesic length from the first vertex (s[0] = 0)."""
    seg = segment_lengths_m(lat_deg, lon_deg)
    return np.concatenate(([0.0], np.cumsum(seg)))


def tmerc_proj_string(lat0_deg: float, lon0_deg: float) -> str:
    """PROJ string of a transverse Mercator (scale 1, false origin 0) centred at (lat0, lon0) on WGS84."""
    return (
        f"+proj=tmerc +lat_0={lat0_deg:.7f} +lon_0={lon0_deg:.7f} +k=1 +x_0=0 +y_0=0 "
        "+ellps=WGS84 +units=m +no_defs +type=crs"
    )


def centred_proj_string(lat_deg: np.ndarray, lon_deg: np.ndarray) -> str:
    """Projection of a new database: transverse Mercator centred on the bounding box of its vertices."""
    lat = np.asarray(lat_deg, dtype=np.float64)
    lon = np.asarray(lon_deg, dtype=np.float64)
    lat0 = 0.5 * (float(lat.min()) + float(lat.max()))
    lon0 = 0.5 * (float(lon.min()) + float(lon.max()))
    return tmerc_proj_string(round(lat0, 7), round(lon0, 7))


@dataclass(frozen=True)
class LocalFrame:
    """The local metric frame of one database: east/north metres of its recorded projection.

    Build it once (``LocalFrame.from_proj(proj)``) and reuse it: the transformers are created here only.
    """

    proj: str
    _forward: Transformer = field(repr=False, compare=False)
    _inverse: Transformer = field(repr=False, compare=False)

    @classmethod
    def from_proj(cls, proj: str) -> LocalFrame:
        crs = CRS.from_user_input(proj)
        forward = Transformer.from_crs(_GEOGRAPHIC, crs, always_xy=True)
        inverse = Transformer.from_crs(crs, _GEOGRAPHIC, always_xy=True)
        return cls(proj, forward, inverse)

    def to_local(self, lat_deg, lon_deg) -> tuple[np.ndarray, np.ndarray]:
        """(lat, lon) degrees -> (east_m, north_m) in this frame. Accepts floats or arrays."""
        east, north = self._forward.transform(
            np.asarray(lon_deg, dtype=np.float64), np.asarray(lat_deg, dtype=np.float64)
        )
        return np.asarray(east, dtype=np.float64), np.asarray(north, dtype=np.float64)

    def to_geodetic(self, east_m, north_m) -> tuple[np.ndarray, np.ndarray]:
        """(east_m, north_m) in this frame -> (lat_deg, lon_deg). Accepts floats or arrays."""
        lon, lat = self._inverse.transform(
            np.asarray(east_m, dtype=np.float64), np.asarray(north_m, dtype=np.float64)
        )
        return np.asarray(lat, dtype=np.float64), np.asarray(lon, dtype=np.float64)
