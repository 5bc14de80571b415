"""The filter on worlds it was not built with: mismatch families x seeds, SFA beside its baselines.

See tools/bench_generalisation.py for the families (as-built truth paths, actual sensor errors drawn
per seed, the filter on the datasheet presets and the database of the source geometry).

Usage: python benchmarks/bench_generalisation.py [--seeds 20] [--first-seed 0] [--family NAME ...]
       [--jobs 2] [--duration 300] [--step 0.5] [--real | --no-real] [--set FIELD=VALUE ...]
       [--known-gnss]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main(argv: list[str] | None = None) -> int:
    from sfa.errors import FilterConfigError
    from sfa.presets import datasheet_config_for
    from tools import real_windows
    from tools.bench_generalisation import (
        FAMILIES,
        REAL_DATA,
        REAL_WINDOWS,
        markdown_table,
        real_data_row,
        real_windows_row,
        run_families,
    )
    from tools.errors import ToolError
    from tools.field_values import parse_field_values

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20, help="seeds per family (default 20)")
    ap.add_argument("--first-seed", type=int, default=0,
                    help="first seed (default 0): seeds first..first+seeds-1, e.g. held-out worlds")
    ap.add_argument("--family", action="append", help="family to run (repeatable; default: all)")
    ap.add_argument("--jobs", type=int, default=1, help="parallel processes (default 1)")
    ap.add_argument("--duration", type=float, default=300.0, help="simulated seconds per run (default 300)")
    ap.add_argument("--step", type=float, default=0.5, help="error sampling step [s] (default 0.5)")
    ap.add_argument("--real", action=argparse.BooleanOptionalAction, default=None,
                    help="also the real-data rows, smartLoc (real and synthesised GNSS) and Dresden, and "
                         "smartLoc from many start times (default: on when every family runs)")
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                    help="FilterConfig field on top of the datasheet presets, for SFA only (an ablation; "
                         "repeatable), e.g. --set cusum_h_sigma=1e9")
    ap.add_argument("--known-gnss", action="store_true",
                    help="SFA is told each world's actual GNSS error model (sigma_g, tau, sigma_w, sigma_h) "
                         "and learns none of it: perfect knowledge, an ablation that measures what learning "
                         "the model costs (the baselines keep the datasheet's; no real-data rows)")
    args = ap.parse_args(argv)
    if args.known_gnss and args.real:
        ap.error("--known-gnss has no real-data rows: real data have no drawn GNSS model")
    names = args.family or [f.name for f in FAMILIES]
    if args.seeds < 1 or args.jobs < 1 or args.duration <= 0 or args.step <= 0 or args.first_seed < 0:
        ap.error("--seeds and --jobs must be >= 1, --first-seed >= 0, --duration and --step > 0")
    try:
        overrides = parse_field_values(args.set)
        datasheet_config_for().replace(**overrides)  # unknown fields and bad values fail here, not per run
    except (ToolError, FilterConfigError) as exc:
        ap.error(str(exc))
    known = "; SFA told each world's GNSS error model (perfect knowledge)" if args.known_gnss else ""
    t0 = time.time()
    rows = run_families(names, args.seeds, args.jobs, args.step, args.duration,
                        log=lambda m: print(m, file=sys.stderr), overrides=overrides,
                        first_seed=args.first_seed, known_gnss=args.known_gnss)
    windows = []
    if args.real if args.real is not None else not (args.family or args.known_gnss):
        rows += [real_data_row(r[0], overrides, log=lambda m: print(m, file=sys.stderr)) for r in REAL_DATA]
        windows = [real_windows_row(label, overrides=overrides, limit_m=limit)
                   for label, limit in REAL_WINDOWS]
    print(markdown_table(rows))
    if windows:
        print("\nThe real logs with truth from many start times (tools/real_windows.py):\n")
        print(real_windows.markdown_table(windows))
    print(f"\n{args.seeds} seeds (from {args.first_seed}) x {len(names)} families, "
          f"first {args.duration:g} s of each run, errors every {args.step:g} s"
          f"{known}; "
          f"{time.time() - t0:.0f} s",
          file=sys.stderr)
    return 0


if __name__ == "__main__":
    from sfa.cli import configure_numba_cache

    configure_numba_cache()  # keyed on the sources: never a stale compiled kernel after an edit
    raise SystemExit(main())
