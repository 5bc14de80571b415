"""Accuracy, consistency and baselines of the SFA filter: Monte Carlo over seeds on simulator scenarios.

For every scenario and seed the simulator (``interface_modules.offline.generate``) produces the
datagrams; they are decoded, mapped to filter measurements, put in time order (as the listener's
merge does) and run through, side by side on the same data:

- ``sfa``: ``TrackFilter`` (per message, with its line/direction hypotheses), config from
  ``sfa.presets.filter_config_for`` with the scenario's sensor presets,
- ``plain-ekf``: a per-message FilterPy EKF without track-aware GNSS handling (``sfa.baselines``),
- ``odo-dr``: odometer-only dead reckoning, ``gnss-proj``: raw GNSS projected onto the line.

Errors are along-track, estimate minus truth interpolated at the estimate's epoch, sampled every
``--step`` seconds of simulated time (the newest estimate at that time). Printed per scenario:
p95 / max |error| for each method, the 95 % interval coverage, the average NEES (Monte Carlo mean
over seeds at each sample time, Bar-Shalom) against its two-sided 95 % chi-square band, and the max
error inside GNSS outages (from the simulator's gnss_lost/gnss_fix events).

Usage: python benchmarks/bench_filter_accuracy.py [--seeds 20] [--scenario NAME ...] [--step 0.5]
"""

from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np


def to_measurements(messages):
    """Decoded INPUT_PROTOCOL messages -> sfa measurements, in time order (stable for equal epochs)."""
    from listener.codec import GpsFix, GroundTruth, ImuSample, OdometerSample
    from sfa.measurements import GpsMeas, ImuMeas, InitMeas, OdoMeas

    out = []
    for m in messages:
        if getattr(m, "epoch", None) is None:
            continue
        if isinstance(m, ImuSample):
            out.append(ImuMeas(m.epoch, (m.ax, m.ay, m.az), (m.gx, m.gy, m.gz)))
        elif isinstance(m, OdometerSample):
            out.append(OdoMeas(m.epoch, m.speed, m.sigma))
        elif isinstance(m, GpsFix):
            out.append(GpsMeas(m.epoch, m.lat, m.lon, m.alt, m.sigma_h, m.fix_quality, m.num_sv))
        elif isinstance(m, GroundTruth):
            out.append(InitMeas(m.epoch, m.arc_length, m.vx, m.line_id))
    out.sort(key=lambda x: x.t_s)
    return out


def run_sfa(track, cfg, meas, grid):
    """Per-message TrackFilter; the newest estimate at each grid time: (epoch, s, sigma, line_id)."""
    from sfa.filter import TrackFilter

    f = TrackFilter(track, cfg)
    n = grid.size
    out = np.full((n, 4), math.nan)
    k = 0
    for i, m in enumerate(meas):
        f.process(m)
        t_next = meas[i + 1].t_s if i + 1 < len(meas) else math.inf
        while k < n and grid[k] < t_next:
            if grid[k] >= m.t_s:
                e = f.estimate()
                out[k] = (e.epoch_s, e.arc_length_m, e.sigma_s_m, -1 if e.line_id is None else e.line_id)
            k += 1
    return out, f.counters()


def sample_baseline(res, grid):
    """Newest baseline estimate at each grid time: (epoch, s)."""
    t = res.epoch_s
    ok = np.isfinite(t)
    t, s = t[ok], res.arc_length_m[ok]
    idx = np.searchsorted(t, grid, side="right") - 1
    out = np.full((grid.size, 2), math.nan)
    good = idx >= 0
    out[good, 0] = t[idx[good]]
    out[good, 1] = s[idx[good]]
    return out


def outage_windows(events):
    wins, start = [], None
    for t, kind, _ in events:
        if kind == "gnss_lost" and start is None:
            start = t
        elif kind == "gnss_fix" and start is not None:
            wins.append((start, t))
            start = None
    if start is not None:
        wins.append((start, math.inf))
    return wins


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--scenario", action="append", help="scenario name or path (default: all shipped)")
    ap.add_argument("--step", type=float, default=0.5, help="error sampling step [s]")
    ap.add_argument("--no-baselines", action="store_true")
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                    help="override a FilterConfig field (number or true/false)")
    args = ap.parse_args(argv)

    from scipy.stats import chi2

    from interface_modules.offline import generate
    from interface_modules.scenario import load_scenario, scenario_names
    from interface_modules.tracks import database_path
    from sfa import baselines
    from sfa.presets import filter_config_for
    from track_db import TrackDatabase

    overrides: dict[str, object] = {}
    for item in args.set:
        key, _, value = item.partition("=")
        low = value.strip().lower()
        overrides[key.strip()] = (low == "true") if low in ("true", "false") else (
            int(value) if value.strip().lstrip("-").isdigit() else float(value))
    names = args.scenario or scenario_names()
    if not names:
        print("no scenarios found", file=sys.stderr)
        return 2
    print(f"# SFA accuracy benchmark: {args.seeds} seeds per scenario, error sampled every {args.step} s"
          + (f"; overrides {overrides}" if overrides else ""))
    for name in names:
        sc = load_scenario(name)
        db_path = database_path(sc)
        if db_path is None:
            print(f"\n## {name}: synthetic track without a database, skipped (needs a TrackDatabase)")
            continue
        track = TrackDatabase.open(db_path)
        cfg = filter_config_for(sc.imu.preset, sc.odometer.preset, sc.gps.preset, **overrides)
        errs = {k: [] for k in ("sfa", "plain-ekf", "odo-dr", "gnss-proj")}
        cover, nees_rows, outage_err, wrong_line = [], [], [], 0
        n_samples = 0
        t_run = time.perf_counter()
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            run = generate(sc, seed)
            meas = to_measurements(run.messages())
            te, ts = run.truth["epoch"], run.truth["arc_length"]
            t_line = run.truth["line_id"]
            grid = np.arange(te[0] + args.step, te[-1], args.step)
            est, _ = run_sfa(track, cfg, meas, grid)
            ok = np.isfinite(est[:, 0])
            truth = np.interp(est[:, 0], te, ts)
            e = est[:, 1] - truth
            errs["sfa"].append(np.abs(e[ok]))
            wrong_line += int(np.sum(est[ok, 3] != np.interp(est[ok, 0], te, t_line)))
            n_samples += int(ok.sum())
            z = cfg.interval_z()
            cover.append(np.abs(e[ok]) <= z * est[ok, 2])
            nees_rows.append(np.where(ok, e * e / np.maximum(est[:, 2], 1e-9) ** 2, np.nan))
            for a, b in outage_windows(run.events):
                inside = ok & (est[:, 0] >= a) & (est[:, 0] <= b)
                if inside.any():
                    outage_err.append(float(np.max(np.abs(e[inside]))))
            if not args.no_baselines:
                for key, res in (
                    ("plain-ekf", baselines.plain_filterpy_ekf(track, meas, cfg)),
                    ("odo-dr", baselines.odometer_dead_reckoning(meas)),
                    ("gnss-proj", baselines.gnss_projection(track, meas)),
                ):
                    b = sample_baseline(res, grid)
                    okb = np.isfinite(b[:, 0])
                    errs[key].append(np.abs(b[okb, 1] - np.interp(b[okb, 0], te, ts)))
        elapsed = time.perf_counter() - t_run
        m = len(nees_rows)
        width = min(len(r) for r in nees_rows)
        nees = np.nanmean(np.vstack([r[:width] for r in nees_rows]), axis=0)
        lo, hi = chi2.ppf(0.025, m) / m, chi2.ppf(0.975, m) / m
        inside = float(np.mean((nees >= lo) & (nees <= hi)))
        cov = float(np.mean(np.concatenate(cover)))
        print(f"\n## {name}  (gps {sc.gps.preset}, imu {sc.imu.preset}, odometer {sc.odometer.preset}; "
              f"{m} seeds, {n_samples} samples, {elapsed:.1f} s)")
        print(f"{'method':<11} {'p95 [m]':>9} {'max [m]':>9} {'rms [m]':>9}  p95 ratio vs sfa")
        p95_sfa = None
        for key, rows in errs.items():
            if not rows:
                continue
            a = np.concatenate(rows)
            p95 = float(np.percentile(a, 95))
            p95_sfa = p95 if key == "sfa" else p95_sfa
            ratio = "" if key == "sfa" else f"{p95 / p95_sfa:8.2f}x"
            rms = float(np.sqrt(np.mean(a * a)))
            print(f"{key:<11} {p95:9.3f} {float(a.max()):9.3f} {rms:9.3f}  {ratio}")
        print(f"95 % interval coverage: {cov * 100:.1f} % (target 93-98 %)")
        print(f"average NEES: mean {float(np.nanmean(nees)):.3f}, chi-square 95 % band for {m} runs "
              f"[{lo:.3f}, {hi:.3f}], samples inside the band {inside * 100:.1f} %")
        if outage_err:
            print(f"max |error| inside GNSS outages: {max(outage_err):.3f} m "
                  f"over {len(outage_err)} outages")
        print(f"samples on a different line than the truth: {wrong_line}")
    return 0


if __name__ == "__main__":
    from sfa.cli import configure_numba_cache

    configure_numba_cache()  # keyed on the sources: never a stale compiled kernel after an edit
    sys.exit(main())
