"""Schema: tables, meta, versioning and migration; bundled default database; the build API."""

from __future__ import annotations

import hashlib
import sqlite3

import numpy as np
import pytest
import sqlite_utils

from track_db import ImportFailed, SchemaError, TrackDatabase, default_database_path
from track_db.build import BuildConfig, LineGeometry, create_database
from track_db.build_default import build as build_default
from track_db.schema import SCHEMA_VERSION, migrate

TABLES = {"meta", "lines", "vertices", "profiles", "junctions", "stops"}


def s_curve(n: int = 400):
    """An S-curve: 200 m right turn then 200 m left turn of radius 100 m, 1 m steps (local approx.)."""
    k = np.where(np.arange(n) < n // 2, 1 / 100.0, -1 / 100.0)
    heading = np.concatenate(([0.0], np.cumsum(k[:-1])))
    north = np.concatenate(([0.0], np.cumsum(np.cos(heading[:-1]))))
    east = np.concatenate(([0.0], np.cumsum(np.sin(heading[:-1]))))
    return 48.0 + north / 111_200.0, 2.0 + east / (111_200.0 * np.cos(np.radians(48.0)))


@pytest.fixture
def small_db(tmp_path):
    lat, lon = s_curve()
    path = tmp_path / "s.db"
    create_database(path, [LineGeometry("s-curve", lat, lon, source="synthetic", attribution="none")])
    return path


def test_tables_meta_and_version(small_db):
    db = sqlite_utils.Database(small_db)
    assert set(db.table_names()) == TABLES
    meta = {r["key"]: r["value"] for r in db["meta"].rows}
    assert int(meta["schema_version"]) == SCHEMA_VERSION == 1
    assert meta["projection"].startswith("+proj=tmerc +lat_0=")
    for key in (
        "smoothing_sigma_m",
        "profile_step_m",
        "junction_tolerance_m",
        "max_gap_m",
        "default_line_id",
    ):
        float(meta[key])
    assert db["vertices"].pks == ["line_id", "idx"]


def test_profile_blobs_are_little_endian_float64_arrays(small_db):
    with sqlite3.connect(small_db) as conn:
        step, n, blob = conn.execute("SELECT step_m, n_samples, curvature_per_m FROM profiles").fetchone()
    k = np.frombuffer(blob, dtype="<f8")
    assert k.size == n and 0 < step <= 2.0
    line = TrackDatabase.open(small_db).line()
    np.testing.assert_array_equal(k, line.curvature_per_m)
    # the S-curve: right turn then left turn of radius 100 m (away from the transition and the ends)
    s = np.array([80.0, 120.0, 280.0, 320.0])
    np.testing.assert_allclose(line.curvature_at(s) * 100.0, [1, 1, -1, -1], atol=0.02)


def test_open_rejects_what_is_not_a_track_database(tmp_path):
    with pytest.raises(SchemaError, match="no such file"):
        TrackDatabase.open(tmp_path / "missing.db")
    text = tmp_path / "text.db"
    text.write_text("hello, this is not SQLite" * 100)
    with pytest.raises(SchemaError, match="not"):
        TrackDatabase.open(text)
    empty = tmp_path / "empty.db"
    sqlite3.connect(empty).close()
    with pytest.raises(SchemaError, match="empty file"):
        TrackDatabase.open(empty)
    other = tmp_path / "other.db"
    sqlite_utils.Database(other)["things"].insert({"a": 1})
    with pytest.raises(SchemaError, match="no meta table"):
        TrackDatabase.open(other)


def test_newer_schema_is_refused(small_db):
    with sqlite3.connect(small_db) as conn:
        conn.execute("UPDATE meta SET value = '99' WHERE key = 'schema_version'")
    with pytest.raises(SchemaError, match="schema version 99"):
        TrackDatabase.open(small_db)
    with pytest.raises(SchemaError, match="newer than this software"):
        migrate(sqlite_utils.Database(small_db))


def test_migrate_creates_the_current_schema_and_is_idempotent(tmp_path):
    db = sqlite_utils.Database(tmp_path / "m.db")
    assert migrate(db) == SCHEMA_VERSION
    assert set(db.table_names()) == TABLES
    assert migrate(db) == SCHEMA_VERSION  # nothing to do


def test_damaged_profile_is_a_schema_error(small_db):
    with sqlite3.connect(small_db) as conn:
        conn.execute("UPDATE profiles SET grade = x'0000'")
    db = TrackDatabase.open(small_db)
    with pytest.raises(SchemaError, match="damaged"):
        db.line()


def test_create_database_builds_synthetic_tracks_in_one_call(tmp_path):
    lat, lon = s_curve()
    path = create_database(
        tmp_path / "t.db",
        [
            LineGeometry("straight", [48.0, 48.005, 48.01], [2.0, 2.0, 2.0]),
            LineGeometry("s", lat, lon, alt_m=np.linspace(100.0, 104.0, lat.size)),
        ],
        default_line=1,
        config=BuildConfig(smoothing_sigma_m=5.0, profile_step_m=1.0),
    )
    db = TrackDatabase.open(path)
    assert db.default_line_id == 2 and db.line().name == "s"
    assert db.line(2).grade_at(200.0) == pytest.approx(4.0 / db.line(2).length_m, rel=1e-3)
    assert db.meta["smoothing_sigma_m"] == "5.0"


@pytest.mark.parametrize(
    "field", ["smoothing_sigma_m", "profile_step_m", "junction_tolerance_m", "max_gap_m"]
)
@pytest.mark.parametrize("value", [0.0, -1.0, float("nan")])
def test_bad_build_config_is_an_import_error(field, value):
    with pytest.raises(ImportFailed, match=field):
        BuildConfig(**{field: value})


# ---- bundled default database -----------------------------------------------------------------------
def test_bundled_default_database():
    path = default_database_path()
    assert path.stat().st_size < 5_000_000
    db = TrackDatabase.open(path)
    line = db.line()
    info = next(i for i in db.lines() if i.line_id == db.default_line_id)
    assert info.properties["@id"] == "rel/147373" and info.properties["ref"] == "3"
    assert line.length_m > 10_000.0
    assert "OpenStreetMap" in info.attribution and "ODbL" in info.attribution
    stops = db.stops()
    assert len(stops) >= 25 and stops[0].name.startswith("Lobeda")
    assert all(abs(st.offset_m) <= 30.0 for st in stops)
    assert np.all(np.diff([st.s_m for st in stops]) >= 0)
    attribution = (path.parent / "ATTRIBUTION.md").read_text(encoding="utf-8")
    assert "ODbL" in attribution and "Share alike" in attribution
    assert (path.parent / "LICENSE-ODbL-1.0.txt").is_file()


def test_default_database_rebuilds_byte_for_byte(tmp_path):
    out = build_default(tmp_path / "jena.db")
    digest = hashlib.sha256(out.read_bytes()).hexdigest()
    assert digest == hashlib.sha256(default_database_path().read_bytes()).hexdigest()
