"""CSV importer: one line from rows of ``lat, lon[, alt]`` (degrees WGS84, metres above MSL).

A header row is optional: if the first row is not numeric, its column names are matched
(lat/latitude/lat_deg, lon/lng/longitude/lon_deg, alt/alt_m/altitude/ele/elevation); otherwise the
columns are lat, lon[, alt] in that order. Blank lines and lines starting with ``#`` are skipped.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from ..build import LineGeometry
from ..errors import ImportFailed
from . import ImportBatch, ImportOptions

__all__ = ["load_csv"]

_NAMES = {
    "lat": ("lat", "latitude", "lat_deg"),
    "lon": ("lon", "lng", "long", "longitude", "lon_deg"),
    "alt": ("alt", "alt_m", "altitude", "ele", "elevation", "height"),
}


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def load_csv(src: Path, options: ImportOptions) -> ImportBatch:
    try:
        with src.open(newline="", encoding="utf-8-sig") as fh:
            rows = [(k + 1, row) for k, row in enumerate(csv.reader(fh))]
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise ImportFailed(f"{src}: cannot read CSV: {exc}") from None
    rows = [(n, [c.strip() for c in r]) for n, r in rows if r and any(c.strip() for c in r)]
    rows = [(n, r) for n, r in rows if not r[0].startswith("#")]
    if not rows:
        raise ImportFailed(f"{src}: empty geometry (no rows)")
    cols = {"lat": 0, "lon": 1, "alt": 2}
    first_n, first = rows[0]
    if not all(_is_number(c) for c in first[:2]):
        header = [c.casefold() for c in first]
        cols = {}
        for key, names in _NAMES.items():
            idx = next((header.index(n) for n in names if n in header), None)
            if idx is not None:
                cols[key] = idx
        if "lat" not in cols or "lon" not in cols:
            raise ImportFailed(f"{src} line {first_n}: header needs lat and lon columns, got {first!r}")
        rows = rows[1:]
        if not rows:
            raise ImportFailed(f"{src}: empty geometry (header only)")
    has_alt = None
    lat, lon, alt, refs = [], [], [], []
    for n, r in rows:
        where = f"{src.name} line {n}"
        values = {}
        for key in ("lat", "lon", "alt"):
            idx = cols.get(key)
            if idx is None or idx >= len(r) or r[idx] == "":
                continue
            try:
                values[key] = float(r[idx])
            except ValueError:
                raise ImportFailed(f"{where}: {key} is not a number ({r[idx]!r})") from None
            if not math.isfinite(values[key]):
                raise ImportFailed(f"{where}: non-finite {key} ({r[idx]})")
        for key in ("lat", "lon"):
            if key not in values:
                raise ImportFailed(f"{where}: {key} missing")
        row_has_alt = "alt" in values
        if has_alt is not None and row_has_alt != has_alt:
            raise ImportFailed(f"{where}: altitude given for some rows only")
        has_alt = row_has_alt
        lat.append(values["lat"])
        lon.append(values["lon"])
        alt.append(values.get("alt", 0.0))
        refs.append(f"line {n}")
    line = LineGeometry(
        name=src.stem,
        lat_deg=np.array(lat),
        lon_deg=np.array(lon),
        alt_m=np.array(alt) if has_alt else None,
        source=src.name,
        attribution=options.attribution or "",
        label=src.name,
        vertex_refs=refs,
    )
    return ImportBatch([line])
