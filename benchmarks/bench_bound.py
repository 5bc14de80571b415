"""The information bound of a run with truth: the p95 along-track error the best GNSS + odometer
estimator reaches under a stated GNSS error model (tools.info_bound).

Usage: python benchmarks/bench_bound.py --truth truth.csv --track t.db --gm-sigma 1.5 --gm-tau 30
       --white 1.0 [--rate 1] [--odo-scale-sigma 0.002] [--outage FROM_M TO_M ...] [--first 300]

``truth.csv`` has the columns epoch [s], arc_length [m along the track's line] and speed [m/s] (the
form of ``sfa replay --truth``). Fixes are assumed at ``--rate`` Hz from the first truth epoch, none
inside the ``--outage`` arc-length ranges. Prints the bound's p95 over the whole run and over the
first ``--first`` seconds.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main(argv: list[str] | None = None) -> int:
    import numpy as np

    from tools.info_bound import GnssErrorModel, expected_p95, sigma_on_line
    from track_db import TrackDatabase

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--truth", required=True, help="truth CSV: epoch, arc_length, speed")
    ap.add_argument("--track", required=True, help="track database (sfa track import)")
    ap.add_argument("--line", type=int, default=None, help="line id (default: the database's default)")
    ap.add_argument("--gm-sigma", type=float, required=True, help="GNSS correlated error sigma per axis [m]")
    ap.add_argument("--gm-tau", type=float, required=True, help="its correlation time [s]")
    ap.add_argument("--white", type=float, required=True, help="GNSS white error sigma per axis [m]")
    ap.add_argument("--rate", type=float, default=1.0, help="GNSS rate [Hz] (default 1)")
    ap.add_argument("--odo-scale-sigma", type=float, default=0.01,
                    help="odometer scale-factor sigma [-] (default 0.01)")
    ap.add_argument("--outage", nargs=2, type=float, action="append", default=[], metavar=("FROM_M", "TO_M"),
                    help="no fixes between these arc lengths (repeatable)")
    ap.add_argument("--first", type=float, default=300.0, help="also the p95 of the first N seconds (300)")
    ap.add_argument("--step", type=float, default=0.5, help="error sampling step [s] (default 0.5)")
    args = ap.parse_args(argv)
    for name in ("gm_sigma", "gm_tau", "rate", "step", "first"):
        if not getattr(args, name) > 0:
            ap.error(f"--{name.replace('_', '-')} must be > 0, got {getattr(args, name)!r}")
    if not (args.white >= 0 and args.odo_scale_sigma >= 0):
        ap.error("--white and --odo-scale-sigma must be >= 0")
    try:
        truth = np.genfromtxt(args.truth, delimiter=",", names=True)
        te, ts, tv = truth["epoch"], truth["arc_length"], truth["speed"]
    except (OSError, ValueError) as exc:
        ap.error(f"cannot read the truth {args.truth!r}: {exc}")
    if te.size < 2:
        ap.error(f"the truth {args.truth!r} has fewer than two rows")
    db = TrackDatabase.open(args.track)
    line = db.line(args.line if args.line is not None else db.default_line_id)
    grid = np.arange(te[0], te[-1], args.step)
    fixes = np.arange(te[0] + 1.0 / args.rate, te[-1], 1.0 / args.rate)
    s_fix = np.interp(fixes, te, ts)
    keep = np.ones(fixes.size, dtype=bool)
    for a, b in args.outage:
        keep &= ~((s_fix >= min(a, b)) & (s_fix <= max(a, b)))
    model = GnssErrorModel(args.gm_sigma, args.gm_tau, args.white)
    sigma = sigma_on_line(line, grid, te, ts, tv, fixes[keep], model, args.odo_scale_sigma)
    db.close()
    first = grid - grid[0] <= args.first
    print(f"information bound p95 (GNSS sigma_g {args.gm_sigma:g} m, tau {args.gm_tau:g} s, white "
          f"{args.white:g} m, {args.rate:g} Hz; odometer scale sigma {args.odo_scale_sigma:g}): "
          f"whole run {expected_p95(sigma):.3f} m ({grid[-1] - grid[0]:.0f} s), "
          f"first {args.first:g} s {expected_p95(sigma[first]):.3f} m")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
