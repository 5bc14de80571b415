"""GTFS importer: ``shapes.txt`` polylines (one line per shape), selected by route or by shape.

``src`` is a feed directory or a .zip. With ``--route`` (route_short_name, route_long_name or
route_id) every shape used by that route's trips is imported; with ``--shape`` that one shape;
with neither, every shape of the feed. Stops come from ``stops.txt`` (location_type 0 or empty).
``shape_dist_traveled`` is kept nowhere: arc length is always recomputed as the WGS84 geodesic length.
"""

from __future__ import annotations

import csv
import io
import math
import zipfile
from collections import defaultdict
from pathlib import Path

import numpy as np

from ..build import LineGeometry, StopPoint
from ..errors import ImportFailed
from . import ImportBatch, ImportOptions

__all__ = ["load_gtfs"]


class _Feed:
    def __init__(self, src: Path) -> None:
        self.src = src
        self._zip = None
        if src.is_file():
            try:
                self._zip = zipfile.ZipFile(src)
            except (zipfile.BadZipFile, OSError) as exc:
                raise ImportFailed(f"{src}: not a GTFS directory or zip ({exc})") from None

    def has(self, name: str) -> bool:
        if self._zip is not None:
            return name in self._zip.namelist()
        return (self.src / name).is_file()

    def rows(self, name: str, required: tuple[str, ...]) -> list[tuple[int, dict[str, str]]]:
        """(file line number, row) pairs; ImportFailed if the file or a required column is missing."""
        if not self.has(name):
            raise ImportFailed(f"{self.src}: {name} missing from the GTFS feed")
        try:
            if self._zip is not None:
                text = self._zip.read(name).decode("utf-8-sig")
            else:
                text = (self.src / name).read_text(encoding="utf-8-sig")
        except (OSError, UnicodeDecodeError, KeyError) as exc:
            raise ImportFailed(f"{self.src}: cannot read {name}: {exc}") from None
        reader = csv.DictReader(io.StringIO(text))
        missing = [c for c in required if c not in (reader.fieldnames or [])]
        if missing:
            raise ImportFailed(f"{name}: missing column(s) {', '.join(missing)}")
        return [(reader.line_num, {k: (v or "").strip() for k, v in row.items() if k}) for row in reader]


def _float(row: dict[str, str], col: str, where: str) -> float:
    try:
        value = float(row[col])
    except (ValueError, TypeError):
        raise ImportFailed(f"{where}: {col} is not a number ({row.get(col)!r})") from None
    if not math.isfinite(value):
        raise ImportFailed(f"{where}: non-finite {col} ({row[col]})")
    return value


def load_gtfs(src: Path, options: ImportOptions) -> ImportBatch:
    feed = _Feed(src)
    routes = {r["route_id"]: r for _, r in feed.rows("routes.txt", ("route_id",))}
    trips = feed.rows("trips.txt", ("route_id", "trip_id")) if feed.has("trips.txt") else []
    shape_routes: dict[str, list[str]] = defaultdict(list)
    shape_trips: dict[str, int] = defaultdict(int)
    shape_headsigns: dict[str, set[str]] = defaultdict(set)
    for _, t in trips:
        sid = t.get("shape_id", "")
        if sid:
            if t["route_id"] not in shape_routes[sid]:
                shape_routes[sid].append(t["route_id"])
            shape_trips[sid] += 1
            if t.get("trip_headsign"):
                shape_headsigns[sid].add(t["trip_headsign"])

    points: dict[str, list[tuple[int, int, dict[str, str]]]] = defaultdict(list)
    for line_no, r in feed.rows(
        "shapes.txt", ("shape_id", "shape_pt_lat", "shape_pt_lon", "shape_pt_sequence")
    ):
        try:
            seq = int(r["shape_pt_sequence"])
        except ValueError:
            raise ImportFailed(
                f"shapes.txt line {line_no}: shape_pt_sequence is not an integer ({r['shape_pt_sequence']!r})"
            ) from None
        points[r["shape_id"]].append((seq, line_no, r))

    if options.shape is not None:
        if options.shape not in points:
            raise ImportFailed(f"unknown shape {options.shape!r}: not in shapes.txt ({len(points)} shapes)")
        selected = [options.shape]
    elif options.route is not None:
        want = options.route
        rids = [
            rid
            for rid, r in routes.items()
            if want in (rid, r.get("route_short_name"), r.get("route_long_name"))
        ]
        if not rids:
            rids = [
                rid
                for rid, r in routes.items()
                if want.casefold()
                in (r.get("route_short_name", "").casefold(), r.get("route_long_name", "").casefold())
            ]
        if not rids:
            known = ", ".join(sorted(r.get("route_short_name") or rid for rid, r in routes.items()))
            raise ImportFailed(f"unknown route {want!r} (routes.txt has: {known})")
        selected = sorted(sid for sid, rs in shape_routes.items() if any(r in rids for r in rs))
        missing = [sid for sid in selected if sid not in points]
        if missing:
            raise ImportFailed(f"route {want!r}: trips use shape {missing[0]!r}, which is not in shapes.txt")
        if not selected:
            raise ImportFailed(f"route {want!r} has no trips with a shape_id: empty geometry")
    else:
        selected = sorted(points)

    agencies = (
        [a.get("agency_name", "") for _, a in feed.rows("agency.txt", ())] if feed.has("agency.txt") else []
    )
    publisher = ""
    if feed.has("feed_info.txt"):
        info = feed.rows("feed_info.txt", ())
        if info:
            fi = info[0][1]
            publisher = f"{fi.get('feed_publisher_name', '')} (feed version {fi.get('feed_version', '?')})"
    attribution = options.attribution or "; ".join(
        x for x in (f"GTFS feed {publisher}".strip(), "operators: " + ", ".join(sorted(set(agencies)))) if x
    )

    lines: list[LineGeometry] = []
    for sid in selected:
        pts = sorted(points[sid], key=lambda p: p[0])
        seqs = [p[0] for p in pts]
        dup = next((k for k in range(1, len(seqs)) if seqs[k] == seqs[k - 1]), None)
        if dup is not None:
            raise ImportFailed(
                f"shapes.txt line {pts[dup][1]}: shape {sid!r} repeats shape_pt_sequence {seqs[dup]}"
            )
        lat = np.array([_float(r, "shape_pt_lat", f"shapes.txt line {ln}") for _, ln, r in pts])
        lon = np.array([_float(r, "shape_pt_lon", f"shapes.txt line {ln}") for _, ln, r in pts])
        rids = shape_routes.get(sid, [])
        route = routes.get(rids[0], {}) if rids else {}
        short = route.get("route_short_name") or route.get("route_id", "")
        heads = sorted(shape_headsigns.get(sid, ()))
        name = " ".join(x for x in (short, "/".join(heads[:2]), f"[{sid}]") if x)
        lines.append(
            LineGeometry(
                name=name,
                lat_deg=lat,
                lon_deg=lon,
                alt_m=None,
                source=f"{src.name} shapes.txt shape_id={sid}",
                attribution=attribution,
                properties={
                    "shape_id": sid,
                    "route_ids": rids,
                    "route_short_name": route.get("route_short_name", ""),
                    "route_long_name": route.get("route_long_name", ""),
                    "route_type": route.get("route_type", ""),
                    "headsigns": heads,
                    "n_trips": shape_trips.get(sid, 0),
                },
                label=f"shape {sid!r}",
                vertex_refs=[f"shapes.txt line {ln}" for _, ln, _ in pts],
            )
        )

    stops: list[StopPoint] = []
    if feed.has("stops.txt"):
        for line_no, r in feed.rows("stops.txt", ("stop_id", "stop_lat", "stop_lon")):
            if r.get("location_type", "") not in ("", "0"):
                continue
            where = f"stops.txt line {line_no}"
            stops.append(
                StopPoint(
                    r.get("stop_name") or r["stop_id"],
                    _float(r, "stop_lat", where),
                    _float(r, "stop_lon", where),
                )
            )
    return ImportBatch(lines, stops, [])
