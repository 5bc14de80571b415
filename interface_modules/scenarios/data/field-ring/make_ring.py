"""Write field-ring.geojson: the documented synthetic test ring of the field scenario (see SOURCE.md).

A centrally symmetric stadium: two straights of ``STRAIGHT_M`` and two 180-degree turns, each a
clothoid of ``CLOTHOID_M`` (curvature 0 -> 1/R), a circular arc of radius ``RADIUS_M`` and a clothoid
back to 0. Both halves are the same shape rotated by 180 degrees, so the loop closes exactly; the
vertices are integrated in a local east/north plane (0.05 m steps, kept every ``VERTEX_M``) and
placed with a local tangent-plane approximation around ``ORIGIN`` (the seed's test circuit is near
Bologna; this is NOT that circuit's geometry, only its size: ~5.7 km, a full turn).

    python make_ring.py            # rewrites field-ring.geojson next to this file
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

STRAIGHT_M = 1670.0  #: each straight [m]
RADIUS_M = 350.0  #: radius of the two arcs [m]
CLOTHOID_M = 80.0  #: each transition (clothoid) [m]
VERTEX_M = 5.0  #: vertex spacing of the GeoJSON line [m]
STEP_M = 0.05  #: integration step [m]
ORIGIN = (44.5200, 11.3900)  #: (lat, lon) of the ring's start, the middle of the first straight [deg]
HEADING_DEG = 20.0  #: heading of the first straight, clockwise from north [deg]
EARTH_R_M = 6_371_008.8  #: mean Earth radius for the tangent-plane placement [m]


def curvature_profile() -> tuple[np.ndarray, float]:
    """Curvature [1/m] at every integration step over the full loop, and the loop length [m]."""
    k = 1.0 / RADIUS_M
    arc = RADIUS_M * math.pi - CLOTHOID_M  # the arc turns pi minus both clothoids' Lc/(2R)
    half = [(STRAIGHT_M / 2, 0.0, 0.0), (CLOTHOID_M, 0.0, k), (arc, k, k), (CLOTHOID_M, k, 0.0),
            (STRAIGHT_M / 2, 0.0, 0.0)]
    pieces = half + half
    out = []
    for length, k0, k1 in pieces:
        n = int(round(length / STEP_M))
        out.append(k0 + (k1 - k0) * (np.arange(n) + 0.5) / n)
    curv = np.concatenate(out)
    return curv, curv.size * STEP_M


def ring_latlon() -> tuple[np.ndarray, np.ndarray, float, float]:
    curv, length = curvature_profile()
    heading = math.radians(HEADING_DEG) + np.concatenate(([0.0], np.cumsum(curv * STEP_M)))
    mid = 0.5 * (heading[1:] + heading[:-1])  # midpoint rule for the positions
    east = np.concatenate(([0.0], np.cumsum(np.sin(mid) * STEP_M)))
    north = np.concatenate(([0.0], np.cumsum(np.cos(mid) * STEP_M)))
    keep = int(round(VERTEX_M / STEP_M))
    gap_m = math.hypot(east[-1], north[-1])  # closure error of the integration
    east = np.append(east[:-1:keep], 0.0)  # the last vertex is the start: a closed ring
    north = np.append(north[:-1:keep], 0.0)
    lat0, lon0 = ORIGIN
    lat = lat0 + np.degrees(north / EARTH_R_M)
    lon = lon0 + np.degrees(east / (EARTH_R_M * math.cos(math.radians(lat0))))
    return lat, lon, length, gap_m


def main() -> None:
    lat, lon, length, gap_m = ring_latlon()
    feature = {
        "type": "Feature",
        "properties": {
            "name": "field ring (synthetic, 5.7 km)",
            "ref": "ring",
            "railway": "rail",
            "note": f"synthetic stadium loop: straights {STRAIGHT_M} m, R {RADIUS_M} m, clothoids "
                    f"{CLOTHOID_M} m, length {length:.1f} m; not surveyed data",
        },
        "geometry": {
            "type": "LineString",
            "coordinates": [[round(float(a), 8), round(float(b), 8)] for a, b in zip(lon, lat, strict=True)],
        },
    }
    doc = {"type": "FeatureCollection", "features": [feature]}
    Path(__file__).with_name("field-ring.geojson").write_text(json.dumps(doc, indent=None) + "\n")
    print(f"{len(lat)} vertices, {length:.1f} m, integration closure error {gap_m * 1000:.1f} mm")


if __name__ == "__main__":
    main()
