"""Importers: the Jena and Euskotren data import with their junctions; bad inputs fail cleanly with
nothing written; MultiLineString stitching; appending."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from track_db import ImportFailed, TrackDatabase, default_database_path
from track_db.build import BuildConfig, LineGeometry, append_lines, create_database
from track_db.importers import ImportOptions, load_source
from track_db.stitch import stitch_parts

SOURCES = default_database_path().parent / "sources"
JENA = SOURCES / "jena-trams-2014.geojson"
EUSKOTREN = SOURCES / "euskotren-gtfs-2025.zip"


def exact_branch_points(db: TrackDatabase) -> int:
    """Independent count: graph of identical vertex coordinates (1e-7 deg), nodes with >= 3 neighbours."""
    neighbours: dict[tuple, set] = {}
    for info in db.lines():
        line = db.line(info.line_id)
        keys = list(zip(np.round(line.lat_deg, 7), np.round(line.lon_deg, 7), strict=True))
        for a, b in zip(keys[:-1], keys[1:], strict=True):
            neighbours.setdefault(a, set()).add(b)
            neighbours.setdefault(b, set()).add(a)
    return sum(1 for nb in neighbours.values() if len(nb) >= 3)


def build(path: Path, src: Path, fmt: str, config: BuildConfig | None = None, **options) -> TrackDatabase:
    batch = load_source(src, fmt, ImportOptions(**options))
    create_database(path, batch.lines, stops=batch.stops, config=config)
    return TrackDatabase.open(path)


def junctions_lie_on_their_lines(db: TrackDatabase, tolerance_m: float) -> None:
    for j in db.junctions():
        e, n = db.to_local(j.lat_deg, j.lon_deg)
        for line_id, s in ((j.line_a, j.s_a_m), (j.line_b, j.s_b_m)):
            pe, pn = db.line(line_id).point_at(s)
            assert np.hypot(pe - e, pn - n) <= tolerance_m, j


# ---- real data --------------------------------------------------------------------------------------
def test_jena_imports_with_its_junctions(tmp_path):
    db = build(tmp_path / "jena.db", JENA, "geojson")
    assert len(db.lines()) == 17  # one line per OSM route relation
    junctions = db.junctions()
    nodes = {j.node_id for j in junctions}
    # docs/track-db.md explains these numbers: 52 shared OSM nodes + 2 near misses (< 1 m)
    assert len(nodes) == 54
    assert exact_branch_points(db) == 52
    assert {j.kind for j in junctions} == {"diverge", "crossing", "end"}
    junctions_lie_on_their_lines(db, 1.0)
    assert len(db.stops()) >= 20  # the default line's stops, projected onto it


def test_jena_junctions_match_an_independent_count_at_zero_tolerance(tmp_path):
    db = build(tmp_path / "jena0.db", JENA, "geojson", config=BuildConfig(junction_tolerance_m=1e-3))
    assert len({j.node_id for j in db.junctions()}) == exact_branch_points(db) == 52
    junctions_lie_on_their_lines(db, 1e-3)


def test_bundled_database_is_the_jena_import(tmp_path):
    bundled = TrackDatabase.open(default_database_path())
    rebuilt = build(tmp_path / "jena.db", JENA, "geojson")
    assert [i.length_m for i in bundled.lines()] == [i.length_m for i in rebuilt.lines()]
    assert len(bundled.junctions()) == len(rebuilt.junctions())


def test_whole_euskotren_network_imports_with_its_junctions(tmp_path):
    db = build(
        tmp_path / "eusko.db", EUSKOTREN, "gtfs", config=BuildConfig(max_gap_m=4000.0), max_gap_m=4000.0
    )
    assert len(db.lines()) == 105  # every shape of the feed
    nodes = {j.node_id for j in db.junctions()}
    assert len(nodes) == 196  # docs/track-db.md: 144 identical shared vertices + near misses within 1 m
    assert exact_branch_points(db) == 144
    junctions_lie_on_their_lines(db, 1.0)


def test_vitoria_tram_network_by_route_with_append(tmp_path):
    path = tmp_path / "vitoria.db"
    build(path, EUSKOTREN, "gtfs", route="TG1")
    for route in ("TG2", "41"):
        batch = load_source(EUSKOTREN, "gtfs", ImportOptions(route=route))
        append_lines(path, batch.lines)
    db = TrackDatabase.open(path)
    names = {i.properties["route_short_name"] for i in db.lines()}
    assert names == {"TG1", "TG2", "41"}
    assert len({j.node_id for j in db.junctions()}) == exact_branch_points(db) == 10
    junctions_lie_on_their_lines(db, 1.0)


def test_gtfs_by_shape(tmp_path):
    db = build(tmp_path / "one.db", EUSKOTREN, "gtfs", shape="ES:Euskotren:RoutePoints:2717:")
    (info,) = db.lines()
    assert info.properties["route_short_name"] == "TG1"
    assert "Euskotren" in info.attribution or "Eusko" in info.attribution


# ---- failures: nothing written ----------------------------------------------------------------------
def assert_fails_cleanly(tmp_path: Path, src: Path, fmt: str, match: str, **options) -> None:
    out = tmp_path / "out" / "t.db"
    out.parent.mkdir(exist_ok=True)
    with pytest.raises(ImportFailed, match=match):
        batch = load_source(src, fmt, ImportOptions(**options))
        create_database(out, batch.lines, config=BuildConfig(max_gap_m=options.get("max_gap_m", 1000.0)))
    assert list(out.parent.iterdir()) == []  # no database, no temporary file


def test_euskotren_gap_is_reported_with_its_row(tmp_path):
    assert_fails_cleanly(
        tmp_path,
        EUSKOTREN,
        "gtfs",
        r"shape 'ES:Euskotren:RoutePoints:1060:': shapes.txt line 3: gap of 1132\.2 m",
    )


def write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("lat,lon\n50.0,11.0\nnan,11.001\n50.002,11.002\n", r"t\.csv line 3: non-finite lat"),
        ("lat,lon\n50.0,11.0\n50.001,11.001\n50.001,11.001\n", r"t\.csv: line 4: duplicated point"),
        (
            "lat,lon\n50.0,11.0\n50.1,11.0\n",
            r"t\.csv: line 3: gap of 11123\.0 m from the previous vertex exceeds max_gap_m = 1000 m",
        ),
        ("lat,lon\n", r"empty geometry"),
        ("lat,lon\n50.0,11.0\n", r"empty geometry \(a line needs at least 2 vertices"),
        ("lat,lon\n50.0,11.0\n50.001,east\n", r"t\.csv line 3: lon is not a number"),
        ("lat,lon,alt\n50.0,11.0,100\n50.001,11.0,\n", r"line 3: altitude given for some rows only"),
        ("lat,lon\n95.0,11.0\n50.001,11.0\n", r"line 2: latitude 95.0 outside"),
        ("x,y\n1,2\n", r"header needs lat and lon"),
    ],
)
def test_bad_csv_fails_naming_the_row(tmp_path, text, match):
    assert_fails_cleanly(tmp_path, write(tmp_path, "t.csv", text), "csv", match)


def feature(geometry, **props) -> dict:
    return {"type": "Feature", "properties": props, "geometry": geometry}


@pytest.mark.parametrize(
    ("doc", "match"),
    [
        ({"type": "FeatureCollection", "features": []}, "empty geometry"),
        (feature({"type": "LineString", "coordinates": []}, name="a"), r"feature 0: empty geometry"),
        (
            feature(None, name="a"),
            r"no LineString or MultiLineString feature selected \(1 features with null geometry skipped\)",
        ),
        (
            feature({"type": "LineString", "coordinates": [[11.0, 50.0], [11.001, float("nan")]]}),
            r"feature 0 vertex 1: non-finite coordinate",
        ),
        (
            feature({"type": "LineString", "coordinates": [[11.0, 50.0], [11.0, 50.0], [11.1, 50.0]]}),
            r"feature 0: vertex 1: duplicated point",
        ),
        (
            feature(
                {
                    "type": "MultiLineString",
                    "coordinates": [[[11.0, 50.0], [11.001, 50.0]], [[11.1, 50.0], [11.2, 50.0]]],
                }
            ),
            r"feature 0: its parts form 2 disconnected pieces; the nearest are 7\d\d\d\.\d m apart",
        ),
        (
            feature({"type": "LineString", "coordinates": [[11.0, 50.0], "x"]}),
            r"vertex 1: a position must be",
        ),
        ("[1, 2", "not valid JSON"),
    ],
)
def test_bad_geojson_fails_naming_the_feature(tmp_path, doc, match):
    text = doc if isinstance(doc, str) else json.dumps(doc)
    assert_fails_cleanly(tmp_path, write(tmp_path, "t.geojson", text), "geojson", match)


def test_unknown_routes_and_shapes(tmp_path):
    assert_fails_cleanly(
        tmp_path, EUSKOTREN, "gtfs", r"unknown route 'T9' \(routes.txt has: 41, E1", route="T9"
    )
    assert_fails_cleanly(tmp_path, EUSKOTREN, "gtfs", r"unknown shape 'nope'", shape="nope")
    assert_fails_cleanly(
        tmp_path, JENA, "geojson", r"unknown route '99' \(features have: 1, 2, 3", route="99"
    )


def gtfs_dir(tmp_path: Path, shapes: str) -> Path:
    d = tmp_path / "feed"
    d.mkdir()
    (d / "routes.txt").write_text("route_id,route_short_name,route_type\nR,T1,0\n")
    (d / "trips.txt").write_text("route_id,service_id,trip_id,shape_id\nR,S,t1,A\n")
    (d / "shapes.txt").write_text("shape_id,shape_pt_lat,shape_pt_lon,shape_pt_sequence\n" + shapes)
    return d


@pytest.mark.parametrize(
    ("shapes", "match"),
    [
        ("A,50.0,11.0,1\nA,abc,11.001,2\n", r"shapes.txt line 3: shape_pt_lat is not a number"),
        ("A,50.0,11.0,1\nA,50.001,11.001,1\n", r"shapes.txt line 3: shape 'A' repeats shape_pt_sequence 1"),
        ("A,50.0,11.0,1\nA,50.001,inf,2\n", r"shapes.txt line 3: non-finite shape_pt_lon"),
        ("A,50.0,11.0,2\nA,50.0,11.0,1\n", r"shape 'A': shapes.txt line 2: duplicated point"),
        ("B,50.0,11.0,1\nB,50.001,11.0,2\n", r"route 'T1': trips use shape 'A', which is not in shapes.txt"),
    ],
)
def test_bad_gtfs_fails_naming_the_row(tmp_path, shapes, match):
    assert_fails_cleanly(tmp_path, gtfs_dir(tmp_path, shapes), "gtfs", match, route="T1")


def test_failed_append_leaves_the_database_byte_for_byte_unchanged(tmp_path):
    path = tmp_path / "t.db"
    create_database(path, [LineGeometry("a", [50.0, 50.001, 50.002], [11.0, 11.0, 11.0])])
    before = hashlib.sha256(path.read_bytes()).hexdigest()
    good = LineGeometry("b", [50.0, 50.0005], [11.0, 11.001])
    bad = LineGeometry("c", [50.0, float("nan")], [11.0, 11.001], label="line c")
    with pytest.raises(ImportFailed, match="line c: vertex 1: non-finite latitude"):
        append_lines(path, [good, bad])
    assert hashlib.sha256(path.read_bytes()).hexdigest() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.db"]
    assert append_lines(path, [good]) == [2]
    assert [i.name for i in TrackDatabase.open(path).lines()] == ["a", "b"]


def test_existing_file_is_not_overwritten_without_asking(tmp_path):
    path = tmp_path / "t.db"
    path.write_bytes(b"precious")
    with pytest.raises(ImportFailed, match="already exists"):
        create_database(path, [LineGeometry("a", [50.0, 50.001], [11.0, 11.0])])
    assert path.read_bytes() == b"precious"


def test_name_option_needs_one_line(tmp_path):
    with pytest.raises(ImportFailed, match="--name needs exactly one line"):
        load_source(JENA, "geojson", ImportOptions(name="x"))
    batch = load_source(JENA, "geojson", ImportOptions(route="rel/147373", name="route 3"))
    assert [ln.name for ln in batch.lines] == ["route 3"]


# ---- stitching --------------------------------------------------------------------------------------
def polyline(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    steps = np.column_stack((rng.uniform(1e-4, 3e-4, n), rng.uniform(-1e-4, 1e-4, n)))  # heads east
    return np.array([11.0, 50.0]) + np.concatenate((np.zeros((1, 2)), np.cumsum(steps, axis=0)))


@given(st.integers(0, 10_000), st.integers(2, 12))
def test_stitching_shuffled_and_reversed_parts_restores_the_polyline(seed, n_parts):
    line = polyline(60, seed)
    rng = np.random.default_rng(seed)
    cuts = np.sort(rng.choice(np.arange(1, 60), n_parts - 1, replace=False))
    bounds = [0, *cuts.tolist(), 60]
    parts = [line[a : b + 1] for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
    parts = [p[::-1] if rng.random() < 0.5 else p for p in parts]
    order = rng.permutation(len(parts))
    res = stitch_parts([parts[k] for k in order], label="t", start_hint=(50.0, 11.0))
    np.testing.assert_array_equal(res.coords, line)
    assert res.parts_used == n_parts and res.parts_dropped == 0


def test_stitching_drops_a_spur_and_bridges_a_small_gap():
    line = polyline(40, 1)
    spur = np.array([line[20], line[20] + [0.0, 2e-4]])  # 22 m stub off the middle
    a, b = line[:26], line[25:] + [1e-5, 0.0]  # b starts 0.7 m east of where a ends
    res = stitch_parts([b, spur, a], label="t", start_hint=(50.0, 11.0), snap_m=0.5, max_gap_m=5.0)
    assert res.parts_dropped == 1 and len(res.gaps_bridged_m) == 1
    assert 0.5 < res.gaps_bridged_m[0] < 1.0
    assert res.coords.shape[0] == line.shape[0] + 1  # both ends of the bridge are kept
    np.testing.assert_array_equal(res.coords[:26], line[:26])


def test_geojson_railway_and_tag_filters_select_features(tmp_path):
    three = load_source(JENA, "geojson", ImportOptions(railway=("tram",), tags=(("ref", "3"),)))
    assert [g.properties["@id"] for g in three.lines] == [
        "rel/147373",
        "rel/3474897",
        "rel/3474898",
        "rel/3474899",
    ]
    assert "13 line features not matching --railway/--tag skipped" in three.notes
    assert len(load_source(JENA, "geojson", ImportOptions(railway=("tram",))).lines) == 17
    assert_fails_cleanly(
        tmp_path,
        JENA,
        "geojson",
        r"no LineString or MultiLineString feature selected \(17 line features not matching --railway/--tag",
        railway=("rail",),
    )


def test_geojson_null_and_non_line_features_are_skipped_and_counted(tmp_path):
    line = {"type": "LineString", "coordinates": [[11.0, 50.0], [11.001, 50.0], [11.002, 50.0]]}
    doc = {
        "type": "FeatureCollection",
        "features": [
            feature(None, name="relation without geometry"),
            feature(line, name="a"),
            feature({"type": "Polygon", "coordinates": [[[11, 50], [11.1, 50], [11.1, 50.1], [11, 50]]]}),
            feature(None),
            feature({"type": "Point", "coordinates": [11.001, 50.0]}, name="Stop", railway="tram_stop"),
            feature({"type": "Point", "coordinates": [11.002, 50.0]}, name="Plain"),
            feature({"type": "Point", "coordinates": [11.0015, 50.0]}, name="Bakery", shop="bakery"),
        ],
    }
    batch = load_source(write(tmp_path, "t.geojson", json.dumps(doc)), None, ImportOptions())
    assert [g.name for g in batch.lines] == ["a"]
    assert "2 features with null geometry skipped" in batch.notes
    assert "1 features that are neither lines nor points ignored" in batch.notes
    assert [s.name for s in batch.stops] == ["Stop", "Plain"]  # a named shop is not a stop
