"""Rebuild the bundled default database: ``python -m track_db.build_default [--output PATH]``.

Source: track_db/data/sources/jena-trams-2014.geojson, the OSM route=tram relations of the Jena
network (Overpass export 2014-11-30, (c) OpenStreetMap contributors, ODbL 1.0; see
track_db/data/ATTRIBUTION.md). One line per route relation, stitched from its unordered ways
(track_db.stitch). The default line is the longest line without a reversal cusp (no vertex where the
polyline turns by more than 150 degrees), so that it can be driven end to end: route 3,
Lobeda-Ost -> Jena-Ost (OSM relation 147373), 14.2 km. The output is deterministic: the same source
gives the same file, byte for byte.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from .build import BuildConfig, create_database
from .importers import ImportOptions, load_source
from .validate import CUSP_DEG, max_turn_deg

__all__ = ["DATA_DIR", "SOURCE", "OUTPUT", "CONFIG", "build", "main"]

DATA_DIR = Path(__file__).resolve().parent / "data"
SOURCE = DATA_DIR / "sources" / "jena-trams-2014.geojson"
OUTPUT = DATA_DIR / "jena-tram.db"
ATTRIBUTION = (
    "(c) OpenStreetMap contributors, ODbL 1.0 (https://www.openstreetmap.org/copyright); "
    "Jena tram route relations, Overpass export 2014-11-30 via github.com/OffenesJena/OSMImports"
)
#: build parameters of the bundled database (the defaults, spelled out so that they stay fixed)
CONFIG = BuildConfig(
    smoothing_sigma_m=20.0,
    profile_step_m=2.0,
    junction_tolerance_m=1.0,
    max_gap_m=1000.0,
    stop_tolerance_m=30.0,
)


def build(output: Path = OUTPUT, source: Path = SOURCE) -> Path:
    batch = load_source(source, "geojson", ImportOptions(attribution=ATTRIBUTION, max_gap_m=CONFIG.max_gap_m))
    lengths = []
    for k, line in enumerate(batch.lines):
        lat = np.asarray(line.lat_deg)
        lon = np.asarray(line.lon_deg)
        if max_turn_deg(lat, lon) <= CUSP_DEG:
            x = np.radians(lon) * np.cos(np.radians(lat.mean()))
            lengths.append((float(np.hypot(np.diff(x), np.diff(np.radians(lat))).sum()), -k))
    default = -max(lengths)[1]
    return create_database(
        output, batch.lines, config=CONFIG, stops=batch.stops, default_line=default, overwrite=True
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m track_db.build_default", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--output", type=Path, default=OUTPUT, help=f"database to write (default {OUTPUT})")
    args = parser.parse_args(argv)
    path = build(args.output)
    print(f"wrote {path} ({path.stat().st_size} bytes)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
