"""Resolve a scenario's track reference to a line object (track_db.TrackLine or SyntheticTrack).

``[track] database`` forms:

- ``"default"``: the bundled database, ``track_db.default_database_path()`` (the Jena tram network);
- ``"synthetic"``: a :class:`~interface_modules.synthetic.SyntheticTrack` from ``[[track.segments]]``;
- ``"gtfs:DIR"``: a GTFS feed extract shipped with the scenarios (``DIR`` relative to the scenario's
  directory); the shape ``gtfs_shape_id`` is imported with the track_db GTFS importer into a cache
  database (``$SFA_CACHE_DIR`` or ``~/.cache/sfa/tracks``) on first use, keyed by the SHA-256 of the
  feed files and the shape id, and reused afterwards (the build is atomic: written then renamed);
- ``"geojson:FILE"``: a GeoJSON source shipped with the scenarios (``FILE`` relative to the scenario's
  directory), imported with the track_db GeoJSON importer (``sfa track import``'s path) into the same
  cache, keyed by the SHA-256 of the file (the field ring: ``data/field-ring/field-ring.geojson``);
- anything else: a path to a track database (relative to the scenario's directory).
"""

from __future__ import annotations

import functools
import hashlib
import os
from pathlib import Path

from .errors import ScenarioError, SimError
from .scenario import Scenario
from .synthetic import Segment, SyntheticTrack


def cache_dir() -> Path:
    """Directory for track databases built from shipped sources."""
    env = os.environ.get("SFA_CACHE_DIR")
    return Path(env) if env else Path.home() / ".cache" / "sfa" / "tracks"


def database_path(sc: Scenario) -> Path | None:
    """Path of the scenario's track database (building it if needed); None for synthetic tracks."""
    ref = sc.track.database
    if ref == "synthetic":
        return None
    if ref == "default":
        try:
            from track_db import default_database_path
        except ImportError as exc:
            raise SimError(f"track_db has no bundled database in this checkout: {exc}") from exc
        return Path(default_database_path())
    if ref.startswith("gtfs:"):
        return _gtfs_database(sc, Path(sc.base_dir) / ref[5:])
    if ref.startswith("geojson:"):
        return _geojson_database(Path(sc.base_dir) / ref[8:])
    path = Path(ref)
    if not path.is_absolute():
        path = Path(sc.base_dir) / path
    if not path.is_file():
        raise ScenarioError(f"track database {str(path)!r} not found")
    return path


def open_line(sc: Scenario):
    """The line the scenario runs on."""
    if sc.track.database == "synthetic":
        segs = [Segment(z.length_m, z.curvature_per_m, z.grade) for z in sc.track.segments]
        return SyntheticTrack(segs, line_id=sc.track.line_id if sc.track.line_id is not None else 1)
    path = database_path(sc)
    from track_db import TrackDatabase
    from track_db.errors import TrackDbError

    try:
        db = TrackDatabase.open(path)
        return db.line(sc.track.line_id)
    except TrackDbError as exc:
        raise ScenarioError(f"track {str(path)!r}: {exc}") from exc


def _gtfs_database(sc: Scenario, source: Path) -> Path:
    if not source.exists():
        raise ScenarioError(f"GTFS source {str(source)!r} not found")
    if not sc.track.gtfs_shape_id:
        raise ScenarioError("track.gtfs_shape_id is required for a gtfs: database")
    h = hashlib.sha256(sc.track.gtfs_shape_id.encode())
    files = sorted(source.glob("*.txt")) if source.is_dir() else [source]
    for f in files:
        h.update(f.name.encode())
        h.update(f.read_bytes())
    shape = sc.track.gtfs_shape_id
    return _cached(source, h.hexdigest(), lambda tmp: build_gtfs_database(source, shape, tmp))


def _geojson_database(source: Path) -> Path:
    if not source.is_file():
        raise ScenarioError(f"GeoJSON source {str(source)!r} not found")
    digest = hashlib.sha256(b"geojson\0" + source.read_bytes()).hexdigest()
    return _cached(source, digest, lambda tmp: build_source_database(source, "geojson", tmp))


@functools.cache
def builder_digest() -> str:
    """sha256 of the sources that build a database (the track_db package and this module): a cache
    database made by other code is not reused (one built before an importer change once kept the E1
    line's old geometry, and its golden capture hash with it, on the machine that had it)."""
    import track_db

    h = hashlib.sha256()
    files = sorted(Path(track_db.__file__).parent.rglob("*.py")) + [Path(__file__)]
    for f in files:
        h.update(f.name.encode() + b"\0" + f.read_bytes())
    return h.hexdigest()


def _cached(source: Path, digest: str, build) -> Path:
    """The cache database for ``source`` with ``digest`` (and the builder's sources), built atomically by
    ``build(tmp)`` if missing."""
    digest = hashlib.sha256((digest + builder_digest()).encode()).hexdigest()
    target = cache_dir() / f"{source.name}-{digest[:16]}.db"
    if target.is_file():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.with_suffix(f".tmp{os.getpid()}")
    build(tmp)
    os.replace(tmp, target)
    return target


def build_source_database(source: Path, fmt: str, target: Path) -> None:
    """Import every line of ``source`` (format ``fmt``, as ``sfa track import`` does) into ``target``."""
    from track_db.build import create_database
    from track_db.errors import TrackDbError
    from track_db.importers import ImportOptions, load_source

    try:
        batch = load_source(source, fmt, ImportOptions())
        create_database(target, batch.lines, stops=batch.stops, overwrite=True)
    except TrackDbError as exc:
        raise SimError(f"cannot build the track database from {str(source)!r}: {exc}") from exc


def build_gtfs_database(source: Path, shape_id: str, target: Path) -> None:
    """Import one GTFS shape (``source``: a feed directory or zip) into a new track database at ``target``."""
    from track_db.build import create_database
    from track_db.errors import TrackDbError
    from track_db.importers import ImportOptions, load_source

    try:
        batch = load_source(source, "gtfs", ImportOptions(shape=shape_id))
        create_database(target, batch.lines, stops=batch.stops, overwrite=True)
    except TrackDbError as exc:
        raise SimError(f"cannot build the track database from {str(source)!r}: {exc}") from exc
