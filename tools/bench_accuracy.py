"""Accuracy rows of ``sfa bench``: SFA and the three baselines on the shipped scenarios, same data.

Reuses the filter developer's benchmark (benchmarks/bench_filter_accuracy.py: measurement mapping,
per-message TrackFilter sampling, baseline sampling) rather than re-implementing it. Per scenario
and seed the simulator output runs through SFA (per-message ``TrackFilter``), odometer-only dead
reckoning, raw GNSS projection and the plain per-message FilterPy EKF; the along-track error is
sampled every ``step_s`` of simulated time. Rows: SFA p95 with each baseline's p95 measured on the
same samples, and the 95 % interval coverage.

Targets (from the filter's benchmark and docs/filter.md): 95 % interval coverage within 93-98 %, and
SFA's p95 below every baseline's p95 on every scenario.
"""

from __future__ import annotations

import math

import numpy as np

from tools.bench_table import Row

SECTION = "accuracy"
BASELINES = {"odo-dr": "odometer only", "gnss-proj": "raw GPS projection", "plain-ekf": "plain FilterPy EKF"}


def accuracy_rows(
    quick: bool,
    seeds: int,
    step_s: float = 0.5,
    max_duration_s: float | None = None,
    names: list[str] | None = None,
    log=print,
) -> list[Row]:
    from interface_modules.offline import generate
    from interface_modules.scenario import load_scenario, scenario_names
    from interface_modules.tracks import database_path
    from sfa import baselines
    from sfa.presets import filter_config_for
    from tools.bench_replay import load_benchmark_module
    from track_db import TrackDatabase

    acc = load_benchmark_module("bench_filter_accuracy")
    rows: list[Row] = []
    known = scenario_names()
    for name in names or known:
        if name not in known:
            from tools.errors import ToolError

            raise ToolError(f"unknown scenario {name!r} (shipped: {', '.join(known)})")
        sc = load_scenario(name)
        db_path = database_path(sc)
        if db_path is None:
            rows.append(
                Row(
                    SECTION,
                    f"{name}: SFA p95 |along-track error|",
                    None,
                    "m",
                    note="synthetic track without a database: not measurable with the per-message filter",
                )
            )
            continue
        track = TrackDatabase.open(db_path)
        cfg = filter_config_for(sc.imu.preset, sc.odometer.preset, sc.gps.preset)
        errs: dict[str, list[np.ndarray]] = {k: [] for k in ("sfa", *BASELINES)}
        cover: list[np.ndarray] = []
        log(f"accuracy: {name} x{seeds} seeds")
        for seed in range(seeds):
            run = generate(sc, seed, max_duration_s=max_duration_s) if max_duration_s else generate(sc, seed)
            meas = acc.to_measurements(run.messages())
            te, ts = run.truth["epoch"], run.truth["arc_length"]
            grid = np.arange(te[0] + step_s, te[-1], step_s)
            est, _ = acc.run_sfa(track, cfg, meas, grid)
            ok = np.isfinite(est[:, 0])
            e = est[ok, 1] - np.interp(est[ok, 0], te, ts)
            errs["sfa"].append(np.abs(e))
            cover.append(np.abs(e) <= cfg.interval_z() * est[ok, 2])
            for key, res in (
                ("plain-ekf", baselines.plain_filterpy_ekf(track, meas, cfg)),
                ("odo-dr", baselines.odometer_dead_reckoning(meas)),
                ("gnss-proj", baselines.gnss_projection(track, meas)),
            ):
                b = acc.sample_baseline(res, grid)
                okb = np.isfinite(b[:, 0])
                errs[key].append(np.abs(b[okb, 1] - np.interp(b[okb, 0], te, ts)))
        track.close()
        p95 = {k: _p95(v) for k, v in errs.items()}
        sfa = p95["sfa"]
        beaten = [k for k in BASELINES if math.isfinite(p95[k]) and p95[k] <= sfa]
        compared = "; ".join(
            f"{label} {p95[k]:.2f} m ({p95[k] / sfa:.1f}x)"
            if math.isfinite(p95[k]) and sfa > 0
            else f"{label} n/a"
            for k, label in BASELINES.items()
        )
        samples = int(sum(a.size for a in errs["sfa"]))
        dur = "" if not max_duration_s else f", first {max_duration_s:g} s"
        rows.append(
            Row(
                SECTION,
                f"{name}: SFA p95 |along-track error| ({seeds} seeds{dur}, {samples:,} samples)",
                sfa,
                "m",
                compared=compared,
                target="below every baseline",
                met=not beaten,
                repeats=seeds,
                note=""
                if not beaten
                else f"not better than {', '.join(BASELINES[k] for k in beaten)} on this scenario",
            )
        )
        cov = float(np.mean(np.concatenate(cover))) * 100.0 if cover else math.nan
        rows.append(
            Row(
                SECTION,
                f"{name}: 95 % interval coverage",
                cov,
                "%",
                compared=f"SFA max |error| {_max(errs['sfa']):.2f} m",
                target="93-98 %",
                met=bool(93.0 <= cov <= 98.0),
                repeats=seeds,
                note="" if 93.0 <= cov <= 98.0 else _coverage_note(cov),
            )
        )
    return rows


def _p95(parts: list[np.ndarray]) -> float:
    a = np.concatenate(parts) if parts else np.array([])
    return float(np.percentile(a, 95)) if a.size else math.nan


def _max(parts: list[np.ndarray]) -> float:
    a = np.concatenate(parts) if parts else np.array([])
    return float(a.max()) if a.size else math.nan


def _coverage_note(cov: float) -> str:
    side = "optimistic (intervals too narrow)" if cov < 93.0 else "pessimistic (intervals too wide)"
    return (
        f"the filter's sigma is {side} on this scenario; the process and measurement noise of the "
        "sensor presets (sfa/presets.py, docs/filter.md) would need tuning against this scenario's "
        "error sources"
    )
