"""Importers: read a source file into validated-to-be ``LineGeometry`` objects (no database access).

Each returns an :class:`ImportBatch`; :mod:`track_db.build` then validates, computes and writes it in
one transaction. Errors are ``ImportFailed`` naming the feature/row and the reason.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from ..build import LineGeometry, StopPoint
from ..errors import ImportFailed
from ..validate import CUSP_DEG, max_turn_deg

__all__ = ["FORMATS", "ImportBatch", "ImportOptions", "guess_format", "load_source"]

FORMATS = ("geojson", "gtfs", "csv", "osm")
#: file name endings read as OpenStreetMap data (pyosmium, the optional extra [osm])
OSM_SUFFIXES = (".osm.pbf", ".pbf", ".osm", ".osm.gz", ".osm.bz2")


@dataclass(frozen=True)
class ImportOptions:
    """What to take from a source file."""

    route: str | None = None  #: GTFS route (short name, long name or id); GeoJSON feature ref/name/id
    shape: str | None = None  #: GTFS shape_id
    name: str | None = None  #: name of the line (only when the source yields exactly one line)
    max_gap_m: float = 1000.0  #: longest accepted distance between consecutive vertices [m]
    attribution: str | None = None  #: attribution statement; default: what the source says
    snap_m: float = 0.5  #: MultiLineString parts whose ends are this close are joined [m]
    railway: tuple[str, ...] = ()  #: OSM/GeoJSON: railway=* values (and their route=* relations); (): all
    tags: tuple[tuple[str, str | None], ...] = ()  #: OSM/GeoJSON: every (key, value or None: any) must match
    routes_only: bool = False  #: OSM: import route relations only, not the ways in no relation


@dataclass(frozen=True)
class ImportBatch:
    lines: list[LineGeometry]
    stops: list[StopPoint] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  #: what was dropped, bridged or ignored


def guess_format(src: Path) -> str:
    if src.is_dir() or src.suffix.lower() == ".zip":
        return "gtfs"
    if src.name.lower().endswith(OSM_SUFFIXES):
        return "osm"
    suffix = src.suffix.lower()
    if suffix in (".geojson", ".json"):
        return "geojson"
    if suffix in (".csv", ".txt"):
        return "csv"
    raise ImportFailed(f"{src}: cannot tell the format from the name; give --format {'|'.join(FORMATS)}")


def load_source(src: str | Path, fmt: str | None, options: ImportOptions) -> ImportBatch:
    """Read ``src`` in format ``fmt`` (None: guessed from the name)."""
    src = Path(src)
    if not src.exists():
        raise ImportFailed(f"{src}: no such file or directory")
    fmt = fmt or guess_format(src)
    if fmt == "geojson":
        from .geojson import load_geojson

        batch = load_geojson(src, options)
    elif fmt == "gtfs":
        from .gtfs import load_gtfs

        batch = load_gtfs(src, options)
    elif fmt == "osm":
        from .osm import osm_to_batch, read_osm_file

        batch = osm_to_batch(read_osm_file(src), src, options)
    elif fmt == "csv":
        from .csvfile import load_csv

        batch = load_csv(src, options)
    else:
        raise ImportFailed(f"unknown format {fmt!r} (known: {', '.join(FORMATS)})")
    notes = list(batch.notes)
    for line in batch.lines:
        try:
            turn = max_turn_deg(line.lat_deg, line.lon_deg)
        except (TypeError, ValueError):
            continue  # not numeric: validation reports it with its row
        if turn > CUSP_DEG:
            notes.append(
                f"{line.label or line.name}: the polyline turns by {turn:.0f} deg at one vertex "
                "(a reversal cusp: the route doubles back); its curvature there is not drivable"
            )
    batch = ImportBatch(batch.lines, batch.stops, notes)
    if options.name is not None:
        if len(batch.lines) != 1:
            raise ImportFailed(f"--name needs exactly one line, but {src} gives {len(batch.lines)}")
        from dataclasses import replace

        batch = ImportBatch([replace(batch.lines[0], name=options.name)], batch.stops, batch.notes)
    return batch
