"""``sfa track``: import, info, export, locate. Standard library only at module level."""

from __future__ import annotations

import argparse
import json
import math
import re
import sys

#: ``locate`` warns when the point is further than this from the nearest line [m] (default of --warn-offset-m)
FAR_OFFSET_M = 100.0


def _positive_m(text: str) -> float:
    """argparse type: a positive finite number of metres (argparse names the option and the value)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of metres") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a positive number of metres, got {text!r}")
    return value


def _railway_list(text: str) -> tuple[str, ...]:
    values = tuple(v.strip() for v in text.split(","))
    if not all(re.fullmatch(r"[a-z_]+", v) for v in values):
        raise argparse.ArgumentTypeError(f"expected railway=* values such as tram,rail, got {text!r}")
    return values


def _tag_filter(text: str) -> tuple[str, str | None]:
    key, eq, value = text.partition("=")
    if not key.strip() or (eq and not value):
        raise argparse.ArgumentTypeError(f"expected KEY or KEY=VALUE, got {text!r}")
    return key.strip(), (value if eq else None)


def count_from_1(text: str) -> int:
    """argparse type: a whole number >= 1 (argparse names the option and the value)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {text!r}")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="track_command", metavar="SUBCOMMAND")
    sub.required = True

    p = sub.add_parser(
        "import",
        help="digitise a track (OSM .osm.pbf/.osm, GeoJSON, GTFS shapes, CSV) into an SQLite track database",
        description="Import lines into a track database. One transaction: on any error nothing is written.",
    )
    p.add_argument(
        "src",
        metavar="SRC",
        help="OSM .osm.pbf/.osm (needs the [osm] extra), GeoJSON file (an OSM export too), GTFS directory "
        "or .zip, or CSV file (lat,lon[,alt])",
    )
    p.add_argument("-o", "--output", required=True, metavar="TRACK.db", help="track database to create")
    p.add_argument(
        "--format", choices=("geojson", "gtfs", "csv", "osm"), help="source format (default: from the name)"
    )
    p.add_argument(
        "--route",
        metavar="NAME",
        help="GTFS route (short/long name or id); GeoJSON feature or OSM route relation ref/name/id",
    )
    p.add_argument("--shape", metavar="ID", help="GTFS shape_id to import")
    p.add_argument(
        "--railway",
        type=_railway_list,
        default=(),
        metavar="TYPES",
        help="OSM/GeoJSON: import these railway=* values only, e.g. tram or tram,light_rail (with their "
        "route=* relations: rail -> train; default: all track)",
    )
    p.add_argument(
        "--tag",
        type=_tag_filter,
        action="append",
        default=[],
        metavar="KEY[=VALUE]",
        help="OSM/GeoJSON: import only relations/ways/features with this tag (repeatable: all must match)",
    )
    p.add_argument(
        "--routes-only",
        action="store_true",
        help="OSM: import the route relations only, not the ways that are in no relation",
    )
    p.add_argument("--name", metavar="LINE", help="name of the line (when the source gives exactly one)")
    p.add_argument("--attribution", metavar="TEXT", help="attribution statement (default: from the source)")
    p.add_argument(
        "--max-gap-m",
        type=_positive_m,
        default=1000.0,
        metavar="M",
        help="reject vertices further apart (default 1000)",
    )
    p.add_argument(
        "--append", action="store_true", help="add the lines to an existing database (its settings are kept)"
    )
    p.add_argument("--force", action="store_true", help="replace an existing output file")
    p.add_argument(
        "--smoothing-sigma-m",
        type=_positive_m,
        default=20.0,
        metavar="M",
        help="Gaussian smoothing of heading/curvature/grade along the track, std dev (default 20)",
    )
    p.add_argument(
        "--profile-step-m", type=_positive_m, default=2.0, metavar="M", help="profile grid step (default 2)"
    )
    p.add_argument(
        "--junction-tolerance-m",
        type=_positive_m,
        default=1.0,
        metavar="M",
        help="vertices closer than this are one network node (default 1)",
    )
    p.add_argument(
        "--default-line", type=count_from_1, default=1, metavar="N", help="1-based default line (default 1)"
    )
    p.set_defaults(_track=_run_import)

    p = sub.add_parser(
        "info",
        help="lines, lengths, vertices, tightest curve, junctions",
        description="Summary of a track database.",
    )
    p.add_argument(
        "track", nargs="?", metavar="TRACK.db", help="track database (default: the bundled Jena network)"
    )
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(_track=_run_info)

    p = sub.add_parser(
        "export", help="export the lines, junctions and stops as GeoJSON", description="Export for QGIS."
    )
    p.add_argument("track", nargs="?", metavar="TRACK.db", help="track database (default: the bundled one)")
    p.add_argument(
        "--geojson", required=True, metavar="OUT", help="GeoJSON file to write ('-': standard output)"
    )
    p.set_defaults(_track=_run_export)

    p = sub.add_parser(
        "locate",
        help="project a position onto the network (or one line)",
        description="Nearest line, arc length and signed lateral offset (> 0 right of the direction of "
        "travel). Default database: the bundled Jena network.",
    )
    p.add_argument("lat", type=float, metavar="LAT", help="latitude [deg]")
    p.add_argument("lon", type=float, metavar="LON", help="longitude [deg]")
    p.add_argument("--track", metavar="TRACK.db", help="track database (default: the bundled one)")
    p.add_argument("--line", type=int, metavar="ID", help="project onto this line only")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.add_argument(
        "--warn-offset-m",
        type=_positive_m,
        default=FAR_OFFSET_M,
        metavar="M",
        help=f"warn on stderr when the point is further than this from the line (default {FAR_OFFSET_M:g})",
    )
    p.set_defaults(_track=_run_locate)


def run(args: argparse.Namespace) -> int:
    return int(args._track(args) or 0)


def _open(path: str | None):
    from . import TrackDatabase, default_database_path

    return TrackDatabase.open(path if path else default_database_path())


def _run_import(args: argparse.Namespace) -> int:
    from pathlib import Path

    from .build import BuildConfig, append_lines, create_database
    from .errors import ImportFailed
    from .importers import ImportOptions, load_source

    out = Path(args.output)
    options = ImportOptions(
        route=args.route,
        shape=args.shape,
        name=args.name,
        max_gap_m=args.max_gap_m,
        attribution=args.attribution,
        railway=args.railway,
        tags=tuple(args.tag),
        routes_only=args.routes_only,
    )
    batch = load_source(args.src, args.format, options)
    if args.append:
        if not out.exists():
            raise ImportFailed(f"{out}: --append needs an existing track database")
        ids = append_lines(out, batch.lines, stops=batch.stops, max_gap_m=args.max_gap_m)
    else:
        if out.exists() and not args.force:
            raise ImportFailed(f"{out} already exists (use --append to add lines, or --force to replace it)")
        config = BuildConfig(
            smoothing_sigma_m=args.smoothing_sigma_m,
            profile_step_m=args.profile_step_m,
            junction_tolerance_m=args.junction_tolerance_m,
            max_gap_m=args.max_gap_m,
        )
        create_database(
            out,
            batch.lines,
            config=config,
            stops=batch.stops,
            default_line=args.default_line - 1,
            overwrite=args.force,
        )
        ids = list(range(1, len(batch.lines) + 1))
    for note in batch.notes:
        print(f"note: {note}", file=sys.stderr)
    print(f"{out}: imported {len(ids)} line(s), ids {ids[0]}..{ids[-1]}")
    _print_radius_report(out, ids)
    return 0


#: ``import`` flags a line whose smoothed minimum radius is below this [m] (tram standard minimum ~ 18-25)
TIGHT_RADIUS_M = 25.0


def _print_radius_report(path, ids: list[int]) -> None:
    """Per imported line: length and minimum curve radius (smoothed profile), tight curves flagged."""
    from . import TrackDatabase

    with TrackDatabase.open(path) as db:
        rows = [i for i in db.lines() if i.line_id in set(ids)]
    total = sum(i.length_m for i in rows)
    print(f"{len(rows)} lines, {total / 1000:.3f} km; minimum curve radius per line (smoothed):")
    for i in rows:
        r = i.min_radius_m
        radius = f"{r:9.1f} m" if r else "  straight"
        flag = f"  tight (< {TIGHT_RADIUS_M:g} m)" if r and r < TIGHT_RADIUS_M else ""
        print(f"{i.line_id:>4}  {i.length_m:10.1f} m  {radius}  {i.name}{flag}")


#: branch points closer than this are reported as one junction area by ``info`` [m]
JUNCTION_AREA_M = 100.0


def _junction_areas(db, junctions) -> int:
    """Number of clusters of branch points (single linkage at JUNCTION_AREA_M)."""
    import numpy as np
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    nodes = {}
    for j in junctions:
        nodes.setdefault(j.node_id, (j.lat_deg, j.lon_deg))
    if not nodes:
        return 0
    lat, lon = np.array(list(nodes.values())).T
    e, n = db.to_local(lat, lon)
    tree = cKDTree(np.column_stack((e, n)))
    return int(connected_components(tree.sparse_distance_matrix(tree, JUNCTION_AREA_M), directed=False)[0])


def _summary(db) -> dict:
    lines = db.lines()
    junctions = db.junctions()
    kinds: dict[str, int] = {}
    for j in junctions:
        kinds[j.kind] = kinds.get(j.kind, 0) + 1
    return {
        "path": str(db.path),
        "projection": db.projection,
        "default_line_id": db.default_line_id,
        "smoothing_sigma_m": float(db.meta["smoothing_sigma_m"]),
        "lines": [
            {
                "line_id": i.line_id,
                "name": i.name,
                "length_m": i.length_m,
                "n_vertices": i.n_vertices,
                "min_radius_m": i.min_radius_m,
                "has_altitude": i.has_altitude,
            }
            for i in lines
        ],
        "total_length_m": sum(i.length_m for i in lines),
        "junction_nodes": len({j.node_id for j in junctions}),
        "junction_areas": _junction_areas(db, junctions),
        "junction_pairs": len(junctions),
        "junction_kinds": kinds,
        "tightest_radius_m": min((i.min_radius_m for i in lines if i.min_radius_m), default=None),
    }


def _run_info(args: argparse.Namespace) -> int:
    with _open(args.track) as db:
        info = _summary(db)
        if args.json:
            print(json.dumps(info, indent=2, ensure_ascii=False))
            return 0
        print(f"{info['path']}")
        print(f"projection: {info['projection']}")
        total_km = info["total_length_m"] / 1000
        print(
            f"{len(info['lines'])} lines, {total_km:.3f} km in total; default line {info['default_line_id']}"
        )
        print(f"{'id':>4}  {'length_m':>10}  {'vertices':>8}  {'min_radius_m':>12}  name")
        for ln in info["lines"]:
            r = ln["min_radius_m"]
            radius = f"{r:12.1f}" if r else f"{'straight':>12}"
            mark = "*" if ln["line_id"] == info["default_line_id"] else " "
            row = f"{ln['line_id']:>4}{mark} {ln['length_m']:10.1f}  {ln['n_vertices']:8d}  {radius}"
            print(f"{row}  {ln['name']}")
        kinds = ", ".join(f"{v} {k}" for k, v in sorted(info["junction_kinds"].items())) or "none"
        tight = info["tightest_radius_m"]
        print(f"tightest radius: {tight:.1f} m" if tight else "tightest radius: none (all straight)")
        print(
            f"junctions: {info['junction_nodes']} branch points in {info['junction_areas']} areas"
            f" (branch points within {JUNCTION_AREA_M:g} m merged),"
            f" {info['junction_pairs']} line pairs ({kinds})"
        )
    return 0


def _run_export(args: argparse.Namespace) -> int:
    from .errors import TrackDbError
    from .export import to_geojson

    with _open(args.track) as db:
        doc = to_geojson(db)
    text = json.dumps(doc, ensure_ascii=False)
    if args.geojson == "-":
        print(text)
    else:
        try:
            with open(args.geojson, "w", encoding="utf-8") as fh:
                fh.write(text)
        except OSError as exc:
            raise TrackDbError(f"cannot write {args.geojson}: {exc}") from None
        print(f"{args.geojson}: {len(doc['features'])} features")
    return 0


def _run_locate(args: argparse.Namespace) -> int:
    from .geodesy import WGS84, check_latlon

    check_latlon(args.lat, args.lon)  # before opening anything: a clear error naming the value
    with _open(args.track) as db:
        if args.line is not None:
            line = db.line(args.line)
            s, off = line.project_latlon(args.lat, args.lon)
            line_id, s, off = line.line_id, float(s), float(off)
        else:
            p = db.locate(args.lat, args.lon)
            line_id, s, off = p.line_id, p.s_m, p.offset_m
        line = db.line(line_id)
        lat, lon = line.latlon_at(s)
        result = {
            "line_id": line_id,
            "line_name": line.name,
            "s_m": s,
            "offset_m": off,
            "on_track_lat_deg": float(lat),
            "on_track_lon_deg": float(lon),
            "heading_deg": float(line.heading_at(s)) * 57.29577951308232 % 360.0,
            "curvature_per_m": float(line.curvature_at(s)),
        }
    # the geodesic distance: the local frame's offset is distorted far from the network
    distance_m = float(WGS84.inv(args.lon, args.lat, float(lon), float(lat))[2])
    if distance_m > args.warn_offset_m:
        where = f"line {line_id} ({result['line_name']})"
        where = where if args.line is not None else f"the nearest line, {where}"
        print(
            f"warning: ({args.lat:g}, {args.lon:g}) is {_distance_text(distance_m)} from {where}"
            f" (more than --warn-offset-m {args.warn_offset_m:g} m): not on this track",
            file=sys.stderr,
        )
    if args.json:
        print(json.dumps(result, indent=2, ensure_ascii=False))
    else:
        side = "right" if off > 0 else "left" if off < 0 else "on the line"
        print(
            f"line {line_id} ({result['line_name']}): s = {s:.3f} m, offset {abs(off):.3f} m {side}"
            f" (on track {result['on_track_lat_deg']:.7f}, {result['on_track_lon_deg']:.7f};"
            f" heading {result['heading_deg']:.1f} deg, curvature {result['curvature_per_m']:.5f} 1/m)"
        )
    return 0


def _distance_text(distance_m: float) -> str:
    return f"{distance_m / 1000:,.1f} km" if distance_m >= 10_000 else f"{distance_m:,.1f} m"
