"""Track query rows of ``sfa bench``: projections of GNSS-like points onto the bundled network.

Points are drawn (seeded) along the lines of the bundled Jena tram database with a 3 m lateral
scatter, then projected onto the whole network per call (``TrackDatabase.locate``) and vectorised
(``TrackDatabase.locate_many``) in the same run. Target (issue of the track database, as in
benchmarks/bench_track.py): >= 20,000 projections/s.
"""

from __future__ import annotations

import numpy as np

from tools.bench_table import Row, median_of, timed

SECTION = "track"


def query_rows(n_points: int, repeats: int, seed: int = 7, log=print) -> list[Row]:
    from track_db import TrackDatabase, default_database_path

    db = TrackDatabase.open(default_database_path())
    try:
        lines = [db.line(i.line_id) for i in db.lines()]
        rng = np.random.default_rng(seed)
        which = rng.integers(0, len(lines), n_points)
        lat = np.empty(n_points)
        lon = np.empty(n_points)
        for k, ln in enumerate(lines):
            sel = which == k
            s = rng.uniform(0.0, ln.length_m, int(sel.sum()))
            e, n = ln.point_at(s)
            te, tn = ln.tangent_at(s)
            off = rng.normal(0.0, 3.0, s.size)
            lat[sel], lon[sel] = db.to_geodetic(e + off * tn, n - off * te)
        db.locate_many(lat[:10], lon[:10])  # spatial index built outside the timing
        db.locate(lat[0], lon[0])
        n_call = min(n_points, 2000)
        log(f"track: {n_points:,} projections vectorised, {n_call:,} per call, x{repeats}")

        def per_call():
            for k in range(n_call):
                db.locate(lat[k], lon[k])

        vec, vec_all = median_of(lambda: n_points / timed(lambda: db.locate_many(lat, lon)), repeats)
        one, one_all = median_of(lambda: n_call / timed(per_call), repeats)
        name = f"projections onto the whole network ({len(lines)} lines), vectorised locate_many"
        return [
            Row(
                SECTION,
                name,
                vec,
                "queries/s",
                compared=f"per call TrackDatabase.locate {one:,.0f}/s ({vec / one:.0f}x)",
                target=">= 20,000/s",
                met=vec >= 20000.0,
                repeats=repeats,
                samples=vec_all,
            ),
            Row(
                SECTION,
                "projections per call, TrackDatabase.locate",
                one,
                "queries/s",
                compared="the scalar path the listener uses per GNSS fix",
                repeats=repeats,
                samples=one_all,
            ),
        ]
    finally:
        db.close()
