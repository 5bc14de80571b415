"""The information bound of a run with truth: the p95 along-track error the best GNSS + odometer
estimator reaches under a stated GNSS error model (tools.info_bound).

Usage: python benchmarks/bench_bound.py --truth truth.csv --track t.db --gm-sigma 1.5 --gm-tau 30
       --white 1.0 [--rate 1] [--odo-scale-sigma 0.002] [--outage FROM_M TO_M ...] [--first 300]
       python benchmarks/bench_bound.py --campaign tools/faults/campaigns/reliability.toml
       [--row baseline-10min ...]

``truth.csv`` has the columns epoch [s], arc_length [m along the track's line] and speed [m/s] (the
form of ``sfa replay --truth``). Fixes are assumed at ``--rate`` Hz from the first truth epoch, none
inside the ``--outage`` arc-length ranges. Prints the bound's p95 over the whole run and over the
first ``--first`` seconds.

With ``--campaign``, the bound of a fault campaign's rows instead: each row's journeys (all of its
``seeds``) simulated as the campaign does, the bound under the world's actual sensor model at the
fixes the receiver delivered, pooled over the row's seeds, beside the row's own p95 bound. The fixes
a lossy input link drops are not taken out, so on such a row the figure is lower still than what the
listener can reach. Default rows: those with a ``p95_m`` expectation and no sensor fault (a faulted
receiver is outside the bound's model).
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
    ap.add_argument("--campaign", help="fault campaign TOML: the bound of its rows (options below unused)")
    ap.add_argument("--row", action="append", default=[], help="with --campaign: this row (repeatable)")
    ap.add_argument("--truth", help="truth CSV: epoch, arc_length, speed")
    ap.add_argument("--track", help="track database (sfa track import)")
    ap.add_argument("--line", type=int, default=None, help="line id (default: the database's default)")
    ap.add_argument("--gm-sigma", type=float, help="GNSS correlated error sigma per axis [m]")
    ap.add_argument("--gm-tau", type=float, help="its correlation time [s]")
    ap.add_argument("--white", type=float, help="GNSS white error sigma per axis [m]")
    ap.add_argument("--rate", type=float, default=1.0, help="GNSS rate [Hz] (default 1)")
    ap.add_argument("--odo-scale-sigma", type=float, default=0.01,
                    help="odometer scale-factor sigma [-] (default 0.01)")
    ap.add_argument("--outage", nargs=2, type=float, action="append", default=[], metavar=("FROM_M", "TO_M"),
                    help="no fixes between these arc lengths (repeatable)")
    ap.add_argument("--first", type=float, default=300.0, help="also the p95 of the first N seconds (300)")
    ap.add_argument("--step", type=float, default=0.5, help="error sampling step [s] (default 0.5)")
    args = ap.parse_args(argv)
    if args.campaign:
        return _campaign(ap, args)
    missing = [f"--{n.replace('_', '-')}" for n in ("truth", "track", "gm_sigma", "gm_tau", "white")
               if getattr(args, n) is None]
    if missing:
        ap.error(f"without --campaign these are required: {', '.join(missing)}")
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


def _campaign(ap: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    import numpy as np

    from interface_modules.offline import generate
    from interface_modules.tracks import database_path
    from tools.bench_replay import load_benchmark_module
    from tools.errors import ToolError
    from tools.faults.runner import build_scenario
    from tools.faults.spec import load_campaign
    from tools.info_bound import expected_p95, scenario_sigma
    from track_db import TrackDatabase

    if not args.step > 0:
        ap.error(f"--step must be > 0, got {args.step!r}")
    try:
        campaign = load_campaign(args.campaign)
    except ToolError as exc:
        ap.error(f"cannot load the campaign {args.campaign!r}: {exc}")
    rows = {s.name: s for s in campaign.scenarios}
    unknown = [r for r in args.row if r not in rows]
    if unknown:
        ap.error(f"no such row in {args.campaign!r}: {', '.join(unknown)} (rows: {', '.join(rows)})")
    chosen = [rows[r] for r in args.row] or [s for s in campaign.scenarios
                                             if "p95_m" in s.expect and not s.sensor_faults]
    acc = load_benchmark_module("bench_filter_accuracy")
    for spec in chosen:
        sigmas = []
        for k in range(spec.seeds):
            sc = build_scenario(spec.repetition(k))
            run = generate(sc)
            te = np.asarray(run.truth["epoch"], float)
            grid = np.arange(te[0] + args.step, te[-1], args.step)
            with TrackDatabase.open(database_path(sc)) as track:
                sigmas.append(scenario_sigma(sc, run, track, acc.to_measurements(run.messages()), grid))
        target = spec.expect.get("p95_m")
        print(f"{spec.name}: information bound p95 {expected_p95(np.concatenate(sigmas)):.3f} m "
              f"({spec.seeds} seed(s) x {spec.duration_s:g} s pooled; the row's p95 bound "
              f"{'-' if target is None else f'{target:g} m'})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
