"""Baselines replayed side by side with SFA on the same capture (same dated measurements).

The measurements are the ones the listener pipeline handed to the SFA filter (after sequencing,
dating and the time-ordered merge), so every estimator sees exactly the same input. The estimators
themselves are in :mod:`sfa.baselines` (odometer dead reckoning, raw GNSS projection onto the track,
a plain per-message FilterPy EKF without track-aware GNSS handling).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from tools.accuracy import accuracy

#: baselines that hold their last value between measurements (sfa.baselines.gnss_projection holds each
#: 1 Hz fix): the report draws them as steps at their fresh values, labelled as held
HELD_BASELINES = frozenset({"GNSS projection"})


def baseline_estimates(track, measurements) -> dict[str, dict[str, np.ndarray]]:
    """Run each baseline over ``measurements``; arrays of epoch and arc length per baseline name."""
    from sfa.baselines import gnss_projection, odometer_dead_reckoning, plain_filterpy_ekf

    out: dict[str, dict[str, np.ndarray]] = {}
    for res in (
        odometer_dead_reckoning(measurements),
        gnss_projection(track, measurements),
        plain_filterpy_ekf(track, measurements),
    ):
        ok = np.isfinite(res.epoch_s) & np.isfinite(res.arc_length_m)
        out[res.name] = {
            "epoch": res.epoch_s[ok],
            "arc_length": res.arc_length_m[ok],
            "held": res.name in HELD_BASELINES,
        }
    return out


def run_baselines(capture, track, options, truth, sfa_metrics: dict[str, Any]):
    """Replay again recording the measurements, run the baselines, and return a comparison table.

    Returns ``(rows, estimates)``: rows of {label, p95_m, max_m, rms_m, interval_coverage} with SFA
    first, and the baselines' estimate arrays (for the figures).
    """
    from tools.replay import replay_capture

    result = replay_capture(capture, track, replace(options, record_measurements=True))
    estimates = baseline_estimates(track, result.measurements)
    rows = [
        {
            "label": "sfa",
            "p95_m": sfa_metrics.get("p95_m"),
            "max_m": sfa_metrics.get("max_m"),
            "rms_m": sfa_metrics.get("rms_m"),
            "interval_coverage": sfa_metrics.get("interval_coverage"),
        }
    ]
    for name, est in estimates.items():
        row: dict[str, Any] = {"label": name}
        if truth is not None and est["epoch"].size:
            a = accuracy(est["epoch"], est["arc_length"], truth["epoch"], truth["arc_length"])
            row.update(p95_m=a.p95_m, max_m=a.max_m, rms_m=a.rms_m, interval_coverage=None)
        rows.append(row)
    return rows, estimates
