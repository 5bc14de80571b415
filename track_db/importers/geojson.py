"""GeoJSON importer: LineString features (one line each) and MultiLineString features whose parts are
unordered and unoriented (one line each, stitched: see track_db.stitch). Point features with a name are
stops when tagged as one (OSM stop tags) or carrying no other property. Features with a null geometry
and features that are neither lines nor points are skipped and counted. Positions are [lon, lat] or
[lon, lat, alt] (RFC 7946).

An OpenStreetMap export with ways (``way/N`` features) or memberships (``@relations``), as
overpass-turbo writes it, is read as OSM data instead: route relations stitched from their member ways,
stops from their stop members (track_db.importers.osm)."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np

from ..build import LineGeometry, StopPoint
from ..errors import ImportFailed
from ..stitch import stitch_parts
from . import ImportBatch, ImportOptions
from .osm import ROUTES_OF, STOP_TAGS, feature_parts, from_geojson_features, is_osm_geojson, osm_to_batch

__all__ = ["load_geojson"]



def _norm(name: str) -> str:
    return re.sub(r"[^0-9a-z]", "", name.casefold())


def _positions(raw, where: str) -> np.ndarray:
    if not isinstance(raw, list) or not raw:
        raise ImportFailed(f"{where}: empty geometry")
    width = None
    rows = []
    for v, pos in enumerate(raw):
        if not isinstance(pos, list) or len(pos) not in (2, 3):
            raise ImportFailed(f"{where} vertex {v}: a position must be [lon, lat] or [lon, lat, alt]")
        if not all(isinstance(x, int | float) and not isinstance(x, bool) for x in pos):
            raise ImportFailed(f"{where} vertex {v}: coordinates must be numbers, got {pos!r}")
        if not all(math.isfinite(x) for x in pos):
            raise ImportFailed(f"{where} vertex {v}: non-finite coordinate {pos!r}")
        if width is not None and len(pos) != width:
            raise ImportFailed(f"{where} vertex {v}: altitude given for some vertices only")
        width = len(pos)
        rows.append([float(x) for x in pos])
    return np.array(rows, dtype=np.float64)


def _features(doc, src: Path) -> list[dict]:
    if not isinstance(doc, dict) or "type" not in doc:
        raise ImportFailed(f"{src}: not a GeoJSON object")
    if doc["type"] == "FeatureCollection":
        feats = doc.get("features")
        if not isinstance(feats, list):
            raise ImportFailed(f"{src}: FeatureCollection without a features list")
        return feats
    if doc["type"] == "Feature":
        return [doc]
    return [{"type": "Feature", "properties": {}, "geometry": doc}]


def _line_name(props: dict, k: int) -> str:
    if props.get("name"):
        return str(props["name"])
    ref = props.get("ref")
    if ref and props.get("from") and props.get("to"):
        return f"{ref}: {props['from']} -> {props['to']}"
    if ref:
        return str(ref)
    return f"feature {k}"


#: properties that say nothing about what a point is
_NEUTRAL = {"name", "id", "description", "ref"}


def _is_stop(props: dict) -> bool:
    if not props.get("name"):
        return False
    if any(props.get(k) in v for k, v in STOP_TAGS.items()) or props.get("public_transport") == "platform":
        return True
    return all(str(k).startswith("@") or k in _NEUTRAL for k in props)


def _selected(props: dict, options: ImportOptions) -> bool:
    """--railway (railway=* of a way, route=* of a relation) and --tag filters."""
    if options.railway:
        routes = {r for rw in options.railway for r in ROUTES_OF.get(rw, (rw,))}
        if props.get("railway") not in options.railway and props.get("route") not in routes:
            return False
    return all(k in props and (v is None or str(props[k]) == v) for k, v in options.tags)


def _matches(props: dict, feature: dict, route: str) -> bool:
    keys = (props.get("ref"), props.get("name"), props.get("@id"), props.get("id"), feature.get("id"))
    return any(k is not None and str(k) == route for k in keys)


def load_geojson(src: Path, options: ImportOptions) -> ImportBatch:
    try:
        doc = json.loads(src.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise ImportFailed(f"{src}: cannot read: {exc}") from None
    except json.JSONDecodeError as exc:
        raise ImportFailed(f"{src}: not valid JSON: {exc}") from None
    feats = _features(doc, src)
    if is_osm_geojson(feats):
        return osm_to_batch(from_geojson_features(feats, _positions), src, options)
    attribution = options.attribution or str(doc.get("copyright", ""))
    notes: list[str] = []
    stops: list[StopPoint] = []
    stop_pos: dict[str, list[tuple[float, float]]] = {}
    candidates: list[tuple[int, dict, dict]] = []
    ignored = 0
    nulls = 0
    unselected = 0
    for k, feat in enumerate(feats):
        where, props, geom = feature_parts(k, feat)
        if geom is None:
            nulls += 1  # e.g. a relation an export could not give a geometry
            continue
        gtype = geom.get("type") if isinstance(geom, dict) else None
        if gtype == "Point":
            name = props.get("name")
            if _is_stop(props):
                pos = _positions([geom.get("coordinates")], where)[0]
                stops.append(StopPoint(str(name), float(pos[1]), float(pos[0])))
                stop_pos.setdefault(_norm(str(name)), []).append((float(pos[1]), float(pos[0])))
            continue
        if gtype not in ("LineString", "MultiLineString"):
            ignored += 1
            continue
        if not _selected(props, options):
            unselected += 1
            continue
        candidates.append((k, feat, props))
    if ignored:
        notes.append(f"{ignored} features that are neither lines nor points ignored")
    if nulls:
        notes.append(f"{nulls} features with null geometry skipped")
    if unselected:
        notes.append(f"{unselected} line features not matching --railway/--tag skipped")
    if options.route is not None:
        chosen = [c for c in candidates if _matches(c[2], c[1], options.route)]
        if not chosen:
            known = sorted({str(c[2].get("ref") or c[2].get("name") or c[0]) for c in candidates})
            raise ImportFailed(f"{src}: unknown route {options.route!r} (features have: {', '.join(known)})")
        candidates = chosen
    if not candidates:
        why = ", ".join(notes) or "empty geometry"
        raise ImportFailed(f"{src}: no LineString or MultiLineString feature selected ({why})")
    lines: list[LineGeometry] = []
    for k, feat, props in candidates:
        fid = props.get("@id") or feat.get("id")
        label = f"feature {k}" + (f" ({fid})" if fid else "")
        geom = feat["geometry"]
        coords_raw = geom.get("coordinates")
        if geom["type"] == "LineString":
            coords = _positions(coords_raw, label)
            refs = [f"vertex {v}" for v in range(len(coords))]
        else:
            if not isinstance(coords_raw, list) or not coords_raw:
                raise ImportFailed(f"{label}: empty geometry")
            parts = [_positions(p, f"{label} part {j}") for j, p in enumerate(coords_raw)]
            if len({p.shape[1] for p in parts}) > 1:
                raise ImportFailed(f"{label}: altitude given for some parts only")
            for j, p in enumerate(parts):
                if len(p) < 2:
                    raise ImportFailed(f"{label} part {j}: empty geometry (fewer than 2 vertices)")
            hints = {}
            for key in ("from", "to"):
                pts = stop_pos.get(_norm(str(props.get(key, ""))))
                if pts:
                    lat, lon = np.mean(pts, axis=0)
                    hints[key] = (float(lat), float(lon))
            res = stitch_parts(
                parts,
                label=label,
                snap_m=options.snap_m,
                max_gap_m=options.max_gap_m,
                start_hint=hints.get("from"),
                end_hint=hints.get("to"),
            )
            coords, refs = res.coords, res.refs
            if res.parts_dropped or res.gaps_bridged_m:
                notes.append(
                    f"{label}: {res.parts_used} parts stitched, {res.parts_dropped} off the main path "
                    "dropped "
                    f"({res.dropped_length_m:.0f} m), {len(res.gaps_bridged_m)} gaps bridged"
                )
        lines.append(
            LineGeometry(
                name=_line_name(props, k),
                lat_deg=coords[:, 1],
                lon_deg=coords[:, 0],
                alt_m=coords[:, 2] if coords.shape[1] == 3 else None,
                source=f"{src.name} {label}",
                attribution=attribution,
                properties=props,
                label=f"{src.name} {label}",
                vertex_refs=refs,
            )
        )
    return ImportBatch(lines, stops, notes)
