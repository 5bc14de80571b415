"""A run's fresh outputs against its truth as a time series: ``outputs.csv`` beside ``row.json``.

A row's figures (p95, coverage, fault coverage) say that it failed; this file says when and how: the
error, the interval and the status through each fault, for a plot or a diff between two variants of
one row. One line per fresh output, thinned to the first output in each ``step_s`` of sensor time (a
10-minute row sends about 110 outputs a second). Errors and coverage are computed as the row's figures
are (:func:`tools.accuracy.along_track_errors`, the truth interpolated at each output's epoch).
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from tools.accuracy import along_track_errors
from tools.faults.evaluate import Observation, fault_mask

#: the columns of ``outputs.csv``: sensor time from the scenario start [s], the truth's and the output's
#: arc length [m], their difference [m], the interval [m], whether it holds the truth, the STATUS byte
#: as the OBCU received it (empty where not observable), whether a sensor fault is active, and the
#: status reasons (space-separated)
COLUMNS = ("t_s", "truth_arc_m", "arc_m", "error_m", "low_m", "high_m", "covered", "status", "in_fault",
           "reasons")
STEP_S = 0.1  #: default thinning: at most one line per this much sensor time [s]


def thinned(rel_s: np.ndarray, step_s: float) -> np.ndarray:
    """Indices of the first element of ``rel_s`` (non-decreasing times [s]) in each ``step_s`` bin;
    every index when ``step_s`` <= 0."""
    if step_s <= 0.0 or rel_s.size == 0:
        return np.arange(rel_s.size)
    b = np.floor(rel_s / step_s)
    return np.flatnonzero(np.concatenate(([True], b[1:] > b[:-1])))


def timeline(obs: Observation, step_s: float = STEP_S) -> list[tuple]:
    """The rows of ``outputs.csv`` (:data:`COLUMNS`) for one run, outputs outside the truth's span
    left out (as in the row's figures)."""
    rel = obs.fresh_epoch - obs.start_epoch_s
    err = along_track_errors(obs.fresh_epoch, obs.fresh_arc, obs.truth_epoch, obs.truth_arc)
    truth_at = np.interp(obs.fresh_epoch, obs.truth_epoch, obs.truth_arc)  # as tools.accuracy's coverage
    in_fault = fault_mask(obs)
    rows = []
    for i in thinned(rel, step_s):
        if not math.isfinite(err[i]):
            continue
        truth = float(truth_at[i])
        lo, hi = float(obs.fresh_lo[i]), float(obs.fresh_hi[i])
        status = "" if obs.fresh_status is None else int(obs.fresh_status[i])
        reasons = "" if obs.fresh_reasons is None else " ".join(obs.fresh_reasons[i])
        rows.append((round(float(rel[i]), 3), round(truth, 3), round(float(obs.fresh_arc[i]), 3),
                     round(float(err[i]), 3), round(lo, 3), round(hi, 3), int(lo <= truth <= hi), status,
                     int(in_fault[i]), reasons))
    return rows


def write_outputs_csv(obs: Observation, path: Path, step_s: float = STEP_S) -> int:
    """Write :func:`timeline` to ``path`` with a header line; returns the rows written."""
    rows = timeline(obs, step_s)
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(COLUMNS)
        w.writerows(rows)
    return len(rows)
