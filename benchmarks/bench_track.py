"""Track database query speed, measured side by side in one run.

    /work/.venv/bin/python benchmarks/bench_track.py [--n 1000000] [--points 50000] [--repeat 3]

1. Point + tangent at arc length s on the bundled Jena default line (route 3, 14.2 km, 549 vertices):
   naive per-call Python through the numpy path (``point_at(np.float64)`` + ``tangent_at(np.float64)`` in a
   loop), the same loop with Python floats (the pure-Python scalar fast path), the vectorised numpy path
   (``point_at(array)`` + ``tangent_at(array)``), and the numba kernel
   (``track_db.compiled.point_tangent_at``).
   Target: >= 1,000,000 queries/s vectorised or compiled.
2. Projection of (lat, lon) onto the whole Euskotren network (all 105 GTFS shapes of the bundled feed,
   ~62,000 segments): naive per-point brute force over every segment (numpy), per-call
   ``TrackDatabase.locate``, and vectorised ``locate_many`` (shapely 2 STRtree + numpy).
   Target: >= 20,000 projections/s.

Rates are the best of ``--repeat`` runs (wall clock, time.perf_counter); ratios are against the naive
baseline of the same run. Random inputs come from numpy.random.default_rng(seed).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from track_db import TrackDatabase, default_database_path
from track_db.build import BuildConfig, create_database
from track_db.compiled import point_tangent_at
from track_db.importers import ImportOptions, load_source

EUSKOTREN = default_database_path().parent / "sources" / "euskotren-gtfs-2025.zip"


def best_rate(fn, n_queries: int, repeat: int) -> float:
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return n_queries / best


def report(title: str, rows: list[tuple[str, float]], target: float) -> None:
    base = rows[0][1]
    print(f"\n{title}")
    print(f"  {'method':<58} {'queries/s':>14} {'x naive':>9}")
    for name, rate in rows:
        print(f"  {name:<58} {rate:14,.0f} {rate / base:9.1f}")
    best = max(r for _, r in rows[1:])
    print(f"  target >= {target:,.0f}/s: {'met' if best >= target else 'NOT met'} (best {best:,.0f}/s)")


def bench_point_tangent(n: int, repeat: int, seed: int) -> None:
    db = TrackDatabase.open(default_database_path())
    line = db.line()
    rng = np.random.default_rng(seed)
    s = rng.uniform(0.0, line.length_m, n)
    n_naive = min(n, 20_000)
    s_numpy_scalars = list(s[:n_naive])  # np.float64 values: the generic numpy path, one call each
    s_floats = [float(x) for x in s[:n_naive]]  # Python floats: the pure-Python scalar fast path

    def naive():
        for x in s_numpy_scalars:
            line.point_at(x)
            line.tangent_at(x)

    def scalar_fast_path():
        for x in s_floats:
            line.point_at(x)
            line.tangent_at(x)

    def vectorised():
        line.point_at(s)
        line.tangent_at(s)

    arrays = line.arrays()
    out = [np.empty_like(s) for _ in range(4)]

    def compiled():
        point_tangent_at(arrays["s_m"], arrays["east_m"], arrays["north_m"], s, *out)

    compiled()  # JIT compilation (or cache load) outside the timing
    rows = [
        (f"naive: per-call, numpy path (np.float64, {n_naive:,} calls)", best_rate(naive, n_naive, repeat)),
        (
            f"per-call, scalar fast path (float, {n_naive:,} calls)",
            best_rate(scalar_fast_path, n_naive, repeat),
        ),
        (f"numpy vectorised point_at + tangent_at ({n:,} s values)", best_rate(vectorised, n, repeat)),
        (f"numba point_tangent_at ({n:,} s values)", best_rate(compiled, n, repeat)),
    ]
    report(f"Point + tangent at s, Jena line {line.line_id} ({line.name}, {line.length_m:.0f} m)", rows, 1e6)


def bench_projection(n_points: int, repeat: int, seed: int) -> None:
    batch = load_source(EUSKOTREN, "gtfs", ImportOptions(max_gap_m=4000.0))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "euskotren.db"
        t0 = time.perf_counter()
        create_database(path, batch.lines, config=BuildConfig(max_gap_m=4000.0))
        elapsed = time.perf_counter() - t0
        print(f"\n(import of the whole Euskotren feed: {len(batch.lines)} lines, {elapsed:.1f} s)")
        db = TrackDatabase.open(path)
        lines = [db.line(i.line_id) for i in db.lines()]
        n_seg = sum(ln.s_m.size - 1 for ln in lines)
        rng = np.random.default_rng(seed)
        which = rng.integers(0, len(lines), n_points)
        lat = np.empty(n_points)
        lon = np.empty(n_points)
        for k, ln in enumerate(lines):
            sel = which == k
            s = rng.uniform(0.0, ln.length_m, int(sel.sum()))
            e, n = ln.point_at(s)
            te, tn = ln.tangent_at(s)
            off = rng.normal(0.0, 3.0, s.size)  # GNSS-like lateral scatter
            lat[sel], lon[sel] = db.to_geodetic(e + off * tn, n - off * te)
        db.locate_many(lat[:10], lon[:10])  # builds the STRtree once, outside the timing

        x0 = np.concatenate([ln.east_m[:-1] for ln in lines])
        y0 = np.concatenate([ln.north_m[:-1] for ln in lines])
        dx = np.concatenate([np.diff(ln.east_m) for ln in lines])
        dy = np.concatenate([np.diff(ln.north_m) for ln in lines])
        n_brute = min(n_points, 300)
        pe, pn = db.to_local(lat[:n_brute], lon[:n_brute])

        def brute():
            for k in range(n_brute):
                t = np.clip(((pe[k] - x0) * dx + (pn[k] - y0) * dy) / (dx * dx + dy * dy), 0.0, 1.0)
                np.argmin(np.hypot(pe[k] - x0 - t * dx, pn[k] - y0 - t * dy))

        n_call = min(n_points, 3000)

        def per_call():
            for k in range(n_call):
                db.locate(lat[k], lon[k])

        def vectorised():
            db.locate_many(lat, lon)

        rows = [
            (f"naive: brute force over all segments ({n_brute:,} points)", best_rate(brute, n_brute, repeat)),
            (f"per-call TrackDatabase.locate ({n_call:,} points)", best_rate(per_call, n_call, repeat)),
            (
                f"vectorised locate_many, STRtree ({n_points:,} points)",
                best_rate(vectorised, n_points, repeat),
            ),
        ]
        report(
            f"Projection onto the whole Euskotren network ({len(lines)} lines, {n_seg:,} segments)", rows, 2e4
        )
        db.close()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--n", type=int, default=1_000_000, help="arc lengths for point/tangent (default 1e6)"
    )
    parser.add_argument("--points", type=int, default=50_000, help="positions to project (default 50,000)")
    parser.add_argument("--repeat", type=int, default=3, help="runs per method; the best is reported")
    parser.add_argument("--seed", type=int, default=20261121)
    args = parser.parse_args()
    bench_point_tangent(args.n, args.repeat, args.seed)
    bench_projection(args.points, args.repeat, args.seed)
    return 0


if __name__ == "__main__":
    from sfa.cli import configure_numba_cache

    configure_numba_cache()  # keyed on the sources: never a stale compiled kernel after an edit
    raise SystemExit(main())
