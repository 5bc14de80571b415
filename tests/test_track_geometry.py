"""Geometry of TrackLine: arc length, round trips, lateral offsets, curvature, heading, grade.

Synthetic tracks are built with track_db.build.create_database in tmp files; real lines come from
the bundled Jena database and the bundled Euskotren GTFS feed.
"""

from __future__ import annotations

import numpy as np
import pytest
from pyproj import Geod

from track_db import QueryError, TrackDatabase, default_database_path
from track_db.build import BuildConfig, LineGeometry, create_database
from track_db.compiled import compiled_point_tangent, curvature_at
from track_db.importers import ImportOptions, load_source

GEOD = Geod(ellps="WGS84")
LAT0, LON0 = 47.3769, 8.5417  # synthetic tracks are centred here (Zurich)
EUSKOTREN = default_database_path().parent / "sources" / "euskotren-gtfs-2025.zip"


def circle(radius_m: float, arc_rad: float, spacing_m: float, clockwise: bool = True):
    """Vertices on a geodesic circle around (LAT0, LON0), `spacing_m` apart (chord), as lat, lon arrays."""
    theta = np.arange(0.0, arc_rad + 1e-12, spacing_m / radius_m)
    az = np.degrees(theta if clockwise else -theta)
    lon, lat, _ = GEOD.fwd(
        np.full(theta.size, LON0), np.full(theta.size, LAT0), az, np.full(theta.size, radius_m)
    )
    return np.asarray(lat), np.asarray(lon)


def straight(az_deg: float, length_m: float, spacing_m: float, start_m: float = 0.0):
    d = np.arange(0.0, length_m + 1e-9, spacing_m) + start_m
    lon, lat, _ = GEOD.fwd(np.full(d.size, LON0), np.full(d.size, LAT0), np.full(d.size, az_deg), d)
    return np.asarray(lat), np.asarray(lon)


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory) -> TrackDatabase:
    lat50, lon50 = circle(50.0, 4.0, 1.0)
    lat500, lon500 = circle(500.0, 1.2, 1.0)
    lat50c, lon50c = circle(50.0, 3.0, 5.0)
    lat500c, lon500c = circle(500.0, 1.2, 5.0)
    lat_l, lon_l = circle(80.0, 2.0, 2.0, clockwise=False)
    lat_s, lon_s = straight(30.0, 2000.0, 10.0, start_m=600.0)
    lat_s2, lon_s2 = straight(120.0, 1500.0, 37.0, start_m=700.0)
    alt = 200.0 + 0.05 * np.arange(lat_s.size) * 10.0  # 5 % climb
    lines = [
        LineGeometry("circle R50 1 m", lat50, lon50),
        LineGeometry("circle R500 1 m", lat500, lon500),
        LineGeometry("circle R50 5 m", lat50c, lon50c),
        LineGeometry("circle R500 5 m", lat500c, lon500c),
        LineGeometry("left circle R80", lat_l, lon_l),
        LineGeometry("straight 5 % climb", lat_s, lon_s, alt_m=alt),
        LineGeometry("straight, no altitude", lat_s2, lon_s2),
    ]
    path = tmp_path_factory.mktemp("synthetic") / "synthetic.db"
    create_database(path, lines, config=BuildConfig(smoothing_sigma_m=10.0))
    db = TrackDatabase.open(path)
    yield db
    db.close()


@pytest.fixture(scope="module")
def jena() -> TrackDatabase:
    db = TrackDatabase.open(default_database_path())
    yield db
    db.close()


@pytest.fixture(scope="module")
def bilbao_tram(tmp_path_factory) -> TrackDatabase:
    batch = load_source(EUSKOTREN, "gtfs", ImportOptions(route="TR"))
    path = tmp_path_factory.mktemp("eusko") / "tr.db"
    create_database(path, batch.lines)
    db = TrackDatabase.open(path)
    yield db
    db.close()


def all_lines(db: TrackDatabase):
    return [db.line(info.line_id) for info in db.lines()]


# ---- arc length ---------------------------------------------------------------------------------
@pytest.mark.parametrize("which", ["jena", "bilbao_tram", "synthetic"])
def test_arc_length_is_the_pyproj_geodesic_polyline_length(which, request):
    db = request.getfixturevalue(which)
    for line in all_lines(db):
        reference = GEOD.line_length(line.lon_deg, line.lat_deg)
        assert abs(line.length_m - reference) <= 1e-3 * reference / 1000.0, line.name  # 1 mm per km
        _, _, seg = GEOD.inv(line.lon_deg[:-1], line.lat_deg[:-1], line.lon_deg[1:], line.lat_deg[1:])
        np.testing.assert_allclose(line.s_m, np.concatenate(([0.0], np.cumsum(seg))), rtol=0, atol=1e-6)


def test_gtfs_line_length_against_shapes_txt_read_independently(bilbao_tram):
    import csv
    import io
    import zipfile

    with zipfile.ZipFile(EUSKOTREN) as z:
        rows = list(csv.DictReader(io.StringIO(z.read("shapes.txt").decode("utf-8-sig"))))
    for info in bilbao_tram.lines():
        sid = info.properties["shape_id"]
        pts = sorted(
            (int(r["shape_pt_sequence"]), float(r["shape_pt_lat"]), float(r["shape_pt_lon"]))
            for r in rows
            if r["shape_id"] == sid
        )
        lat = np.array([p[1] for p in pts])
        lon = np.array([p[2] for p in pts])
        reference = GEOD.line_length(lon, lat)
        assert abs(info.length_m - reference) <= 1e-3 * reference / 1000.0


# ---- round trips and offsets ----------------------------------------------------------------------
@pytest.mark.parametrize("which", ["jena", "bilbao_tram", "synthetic"])
def test_s_to_latlon_to_s_round_trip_within_1_cm(which, request):
    db = request.getfixturevalue(which)
    rng = np.random.default_rng(7)
    for line in all_lines(db):
        s = np.concatenate((line.s_m, rng.uniform(0.0, line.length_m, 3000)))
        lat, lon = line.latlon_at(s)
        s_back, offset = line.project_latlon(lat, lon)
        assert np.max(np.abs(offset)) < 0.01, line.name
        # where the line passes over itself (loops) the nearest point may be another visit: same place
        e1, n1 = line.point_at(s)
        e2, n2 = line.point_at(s_back)
        assert np.max(np.hypot(e1 - e2, n1 - n2)) < 0.01, line.name
        unique = np.abs(s_back - s) < 0.01
        assert unique.mean() > 0.99, line.name


def _segment_distance(px, py, x0, y0, x1, y1):
    dx, dy = x1 - x0, y1 - y0
    t = np.clip(((px[:, None] - x0) * dx + (py[:, None] - y0) * dy) / (dx * dx + dy * dy), 0, 1)
    return np.hypot(px[:, None] - (x0 + t * dx), py[:, None] - (y0 + t * dy))


@pytest.mark.parametrize("which", ["jena", "bilbao_tram", "synthetic"])
@pytest.mark.parametrize("offset_m", [-3.0, -0.5, 0.5, 3.0])
def test_projection_returns_known_lateral_offsets_within_1_cm(which, offset_m, request):
    db = request.getfixturevalue(which)
    tested = 0
    candidates = 0
    for line in all_lines(db):
        # mid-segment points displaced along the right-hand normal (tn, -te) by offset_m
        s = 0.5 * (line.s_m[:-1] + line.s_m[1:])
        e, n = line.point_at(s)
        te, tn = line.tangent_at(s)
        pe, pn = e + offset_m * tn, n - offset_m * te
        # keep the points whose nearest segment is unambiguously their own (brute force, independent)
        x0, y0, x1, y1 = line.east_m[:-1], line.north_m[:-1], line.east_m[1:], line.north_m[1:]
        dist = _segment_distance(pe, pn, x0, y0, x1, y1)
        own = np.arange(s.size)
        dist[own, own] = np.inf
        clear = dist.min(axis=1) > abs(offset_m) + 1e-3
        candidates += s.size
        tested += int(clear.sum())
        lat, lon = db.to_geodetic(pe[clear], pn[clear])
        s_back, off_back = line.project_latlon(lat, lon)
        np.testing.assert_allclose(off_back, offset_m, atol=0.01, err_msg=line.name)
        np.testing.assert_allclose(s_back, s[clear], atol=0.01, err_msg=line.name)
    assert tested > 0.7 * candidates  # the check is not vacuous


def test_offset_sign_right_is_positive(synthetic):
    line = synthetic.line(6)  # straight, azimuth 30 deg
    s = 500.0
    e, n = line.point_at(s)
    te, tn = line.tangent_at(s)
    _, off_right = line.project(e + 2.0 * tn, n - 2.0 * te)  # right of travel
    _, off_left = line.project(e - 2.0 * tn, n + 2.0 * te)
    assert off_right == pytest.approx(2.0, abs=1e-9)
    assert off_left == pytest.approx(-2.0, abs=1e-9)


# ---- curvature, heading, grade --------------------------------------------------------------------
@pytest.mark.parametrize(("line_id", "radius_m"), [(1, 50.0), (2, 500.0)])
def test_curvature_of_densely_sampled_circle_within_1_percent_everywhere(synthetic, line_id, radius_m):
    line = synthetic.line(line_id)
    s = np.linspace(0.0, line.length_m, 4001)
    k = line.curvature_at(s)
    assert np.max(np.abs(k * radius_m - 1.0)) < 0.01
    info = next(i for i in synthetic.lines() if i.line_id == line_id)
    assert info.min_radius_m == pytest.approx(radius_m, rel=0.01)


@pytest.mark.parametrize(("line_id", "radius_m"), [(3, 50.0), (4, 500.0)])
def test_curvature_of_coarse_circle_within_1_percent_away_from_the_ends(synthetic, line_id, radius_m):
    """5 m chords: full accuracy once the smoothing window (3 sigma = 30 m) fits inside the line."""
    line = synthetic.line(line_id)
    s = np.linspace(30.0, line.length_m - 30.0, 4001)
    assert np.max(np.abs(line.curvature_at(s) * radius_m - 1.0)) < 0.01


def test_left_turn_has_negative_curvature(synthetic):
    line = synthetic.line(5)
    s = np.linspace(0.0, line.length_m, 500)
    np.testing.assert_allclose(line.curvature_at(s) * 80.0, -1.0, atol=0.01)


@pytest.mark.parametrize("line_id", [6, 7])
def test_straight_line_curvature_below_1e_5(synthetic, line_id):
    line = synthetic.line(line_id)
    s = np.linspace(0.0, line.length_m, 5000)
    assert np.max(np.abs(line.curvature_at(s))) < 1e-5


def test_heading_is_clockwise_from_grid_north(synthetic):
    line = synthetic.line(6)  # azimuth 30 deg
    s = np.linspace(0.0, line.length_m, 200)
    te, tn = line.tangent_at(s)
    np.testing.assert_allclose(line.heading_at(s), np.arctan2(te, tn), atol=1e-9)
    # grid north differs from true north by the meridian convergence (< 0.01 rad within ~1 km here)
    np.testing.assert_allclose(line.heading_at(s), np.radians(30.0), atol=0.01)


@pytest.mark.parametrize("which", ["jena", "synthetic"])
def test_heading_derivative_equals_curvature(which, request):
    db = request.getfixturevalue(which)
    h = 1e-3
    for line in all_lines(db):
        s = np.linspace(h, line.length_m - h, 20000)
        dheading = (line.heading_at(s + h) - line.heading_at(s - h)) / (2 * h)
        np.testing.assert_allclose(dheading, line.curvature_at(s), atol=1e-6, err_msg=line.name)
        # and the heading follows the track's direction: smoothed, so within a few degrees on real lines
        te, tn = line.tangent_at(s)
        err = np.angle(np.exp(1j * (line.heading_at(s) - np.arctan2(te, tn))))
        assert np.median(np.abs(err)) < np.radians(3.0), line.name


def test_jena_curvature_is_smooth(jena):
    """Away from the ends (3 sigma = 60 m, where the smoothing window shrinks) curvature has no jumps."""
    line = jena.line()
    sigma = float(jena.meta["smoothing_sigma_m"])
    s = np.arange(3 * sigma, line.length_m - 3 * sigma, 0.5)
    k = line.curvature_at(s)
    assert np.max(np.abs(np.diff(k))) < 1e-3  # per 0.5 m: continuous, no spikes at vertices
    assert 20.0 < 1.0 / np.max(np.abs(k)) < 200.0  # tram curves, not vertex spikes


def test_grade(synthetic):
    climb = synthetic.line(6)
    s = np.linspace(0.0, climb.length_m, 300)
    np.testing.assert_allclose(climb.grade_at(s), 0.05, atol=1e-6)
    assert climb.alt_at(0.0) == pytest.approx(200.0, abs=1e-9)
    flat = synthetic.line(7)
    assert not flat.has_altitude
    np.testing.assert_array_equal(flat.grade_at(s[s < flat.length_m]), 0.0)
    assert flat.alt_at(10.0) == 0.0
    assert np.all(np.isnan(flat.alt_m))


# ---- query contract ---------------------------------------------------------------------------------
def test_scalar_in_scalar_out_and_vectorised(jena):
    line = jena.line()
    e, n = line.point_at(100.0)
    assert np.ndim(e) == 0 and isinstance(float(e), float)
    ev, nv = line.point_at(np.array([100.0, 200.0]))
    assert ev.shape == (2,) and ev[0] == e and nv[0] == n
    assert np.ndim(line.curvature_at(5.0)) == 0


@pytest.mark.parametrize("bad", [-0.5, 1e9, float("nan"), float("inf")])
def test_bad_arc_length_is_a_query_error(jena, bad):
    line = jena.line()
    for query in (line.point_at, line.tangent_at, line.latlon_at, line.heading_at, line.curvature_at):
        with pytest.raises(QueryError):
            query(np.array([10.0, bad]))


def test_unknown_line_and_bad_positions_are_query_errors(jena):
    with pytest.raises(QueryError, match="no line 999"):
        jena.line(999)
    with pytest.raises(QueryError):
        jena.locate(float("nan"), 11.6)
    with pytest.raises(QueryError):
        jena.line().project_latlon(50.9, float("inf"))


def test_point_at_vertices_is_exact(jena):
    line = jena.line()
    e, n = line.point_at(line.s_m)
    np.testing.assert_allclose(e, line.east_m, atol=1e-9)
    np.testing.assert_allclose(n, line.north_m, atol=1e-9)
    lat, lon = line.latlon_at(line.s_m)
    np.testing.assert_allclose(lat, line.lat_deg, atol=1e-11)
    np.testing.assert_allclose(lon, line.lon_deg, atol=1e-11)


def test_compiled_kernels_match_track_line(jena):
    line = jena.line()
    s = np.random.default_rng(3).uniform(0.0, line.length_m, 10000)
    e, n, te, tn = compiled_point_tangent(line.arrays(), s)
    e2, n2 = line.point_at(s)
    te2, tn2 = line.tangent_at(s)
    for a, b in ((e, e2), (n, n2), (te, te2), (tn, tn2)):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
    arrays = line.arrays()
    out = np.empty_like(s)
    curvature_at(arrays["heading_rad"], arrays["curvature_per_m"], arrays["profile_step_m"][0], s, out)
    np.testing.assert_allclose(out, line.curvature_at(s), rtol=0, atol=1e-12)


# ---- network ----------------------------------------------------------------------------------------
def test_locate_on_network_matches_per_line_projection(jena):
    rng = np.random.default_rng(11)
    line = jena.line()
    s = rng.uniform(0.0, line.length_m, 500)
    lat, lon = line.latlon_at(s)
    lat = lat + rng.normal(0.0, 2e-5, s.size)
    lon = lon + rng.normal(0.0, 3e-5, s.size)
    many = jena.locate_many(lat, lon)
    assert len(many) == s.size
    for k in range(0, s.size, 50):
        one = jena.locate(lat[k], lon[k])
        assert one == many[k]
    # the network answer is never farther than the projection onto the default line
    _, off = line.project_latlon(lat, lon)
    assert np.all(many.distance_m <= np.abs(off) + 1e-9)
    # and it is a true nearest point: brute force over every segment of every line
    e, n = jena.to_local(lat[:40], lon[:40])
    best = np.full(40, np.inf)
    for ln in all_lines(jena):
        d = _segment_distance(e, n, ln.east_m[:-1], ln.north_m[:-1], ln.east_m[1:], ln.north_m[1:])
        best = np.minimum(best, d.min(axis=1))
    np.testing.assert_allclose(many.distance_m[:40], best, atol=1e-9)


def test_locate_ties_go_to_the_lowest_line_id(jena):
    # routes 3 (line 2) and 5 (line 1) share the trunk from Lobeda-Ost: a point on it belongs to line 1
    l2 = jena.line(2)
    lat, lon = l2.latlon_at(300.0)
    p = jena.locate(lat, lon)
    assert p.distance_m < 1e-6
    assert p.line_id == min(j for j in (1, 2, 4, 10) if jena.line(j).project_latlon(lat, lon)[1] ** 2 < 1e-12)


@pytest.mark.parametrize("which", ["jena", "synthetic"])
def test_scalar_fast_path_equals_vectorised_path(which, request):
    db = request.getfixturevalue(which)
    rng = np.random.default_rng(5)
    for line in all_lines(db):
        s = np.concatenate(([0.0, line.length_m], line.s_m[1:-1:7], rng.uniform(0.0, line.length_m, 300)))
        for name in ("point_at", "tangent_at", "heading_at", "curvature_at", "grade_at"):
            query = getattr(line, name)
            vectorised = query(s)
            scalar = [query(float(x)) for x in s]
            if isinstance(vectorised, tuple):
                for j in range(2):
                    np.testing.assert_array_equal([v[j] for v in scalar], vectorised[j], err_msg=name)
            else:
                np.testing.assert_array_equal(scalar, vectorised, err_msg=name)
        assert isinstance(line.curvature_at(1), float)  # ints take the scalar path too


@pytest.mark.parametrize("bad", [-0.5, 1e9, float("nan"), float("inf")])
def test_bad_scalar_arc_length_is_a_query_error(jena, bad):
    line = jena.line()
    for query in (line.point_at, line.tangent_at, line.heading_at, line.curvature_at, line.grade_at):
        with pytest.raises(QueryError):
            query(bad)


def test_duplicated_and_reversed_lines_tie_to_the_lowest_line_id(tmp_path):
    lat, lon = straight(75.0, 500.0, 25.0, start_m=100.0)
    lat2, lon2 = straight(160.0, 300.0, 30.0, start_m=100.0)
    lines = [
        LineGeometry("other", lat2, lon2),
        LineGeometry("reversed", lat[::-1], lon[::-1]),
        LineGeometry("forward", lat, lon),
        LineGeometry("forward again", lat, lon),
    ]
    db = TrackDatabase.open(create_database(tmp_path / "dup.db", lines))
    rng = np.random.default_rng(2)
    fwd = db.line(3)
    s = rng.uniform(60.0, fwd.length_m, 200)  # away from the shared start with "other"
    e, n = fwd.point_at(s)
    te, tn = fwd.tangent_at(s)
    off = rng.uniform(-4.0, 4.0, s.size)
    lat_q, lon_q = db.to_geodetic(e + off * tn, n - off * te)
    res = db.locate_many(lat_q, lon_q)
    assert np.all(res.line_id == 2)  # "reversed" has the lowest id among the three identical geometries
    np.testing.assert_allclose(res.s_m, fwd.length_m - s, atol=1e-6)  # its own arc length, reversed
    np.testing.assert_allclose(res.offset_m, -off, atol=1e-6)  # right of "forward" is left of "reversed"
