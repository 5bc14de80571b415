"""GeoJSON export of a track database (for QGIS and other GIS tools).

One LineString feature per line ([lon, lat] or [lon, lat, alt] positions, RFC 7946), one Point feature
per junction and per stop; ``properties.feature`` says which ("line", "junction", "stop").
"""

from __future__ import annotations

import math

from .database import TrackDatabase

__all__ = ["to_geojson"]


def _num(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def to_geojson(db: TrackDatabase) -> dict:
    feats = []
    attributions = []
    for info in db.lines():
        line = db.line(info.line_id)
        if line.has_altitude:
            coords = [[lo, la, al] for la, lo, al in zip(line.lat_deg, line.lon_deg, line.alt_m, strict=True)]
        else:
            coords = [[lo, la] for la, lo in zip(line.lat_deg.tolist(), line.lon_deg.tolist(), strict=True)]
        feats.append(
            {
                "type": "Feature",
                "id": f"line/{info.line_id}",
                "properties": {
                    "feature": "line",
                    "line_id": info.line_id,
                    "name": info.name,
                    "length_m": info.length_m,
                    "n_vertices": info.n_vertices,
                    "min_radius_m": _num(info.min_radius_m),
                    "source": info.source,
                    "attribution": info.attribution,
                },
                "geometry": {"type": "LineString", "coordinates": coords},
            }
        )
        if info.attribution and info.attribution not in attributions:
            attributions.append(info.attribution)
        for k, st in enumerate(db.stops(info.line_id)):
            feats.append(
                {
                    "type": "Feature",
                    "id": f"stop/{info.line_id}/{k}",
                    "properties": {"feature": "stop", "name": st.name, "line_id": st.line_id, "s_m": st.s_m},
                    "geometry": {"type": "Point", "coordinates": [st.lon_deg, st.lat_deg]},
                }
            )
    for k, j in enumerate(db.junctions()):
        feats.append(
            {
                "type": "Feature",
                "id": f"junction/{k + 1}",
                "properties": {
                    "feature": "junction",
                    "node_id": j.node_id,
                    "kind": j.kind,
                    "line_a": j.line_a,
                    "s_a_m": j.s_a_m,
                    "line_b": j.line_b,
                    "s_b_m": j.s_b_m,
                },
                "geometry": {"type": "Point", "coordinates": [j.lon_deg, j.lat_deg]},
            }
        )
    return {"type": "FeatureCollection", "attribution": " | ".join(attributions), "features": feats}
