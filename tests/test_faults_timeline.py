"""tools.faults.timeline: a run's outputs against its truth, thinned, as outputs.csv."""

from __future__ import annotations

import csv

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from tools.accuracy import accuracy
from tools.faults.evaluate import Observation
from tools.faults.timeline import COLUMNS, thinned, timeline, write_outputs_csv


def _observation(epoch, arc, half, status=None, reasons=None, faults=()):
    epoch = np.asarray(epoch, dtype=float)
    arc = np.asarray(arc, dtype=float)
    return Observation(
        name="x", mode="replay", simulated_s=10.0, truth_epoch=np.array([100.0, 110.0]),
        truth_arc=np.array([0.0, 100.0]), start_epoch_s=100.0, fresh_arrival=epoch - 100.0,
        fresh_epoch=epoch, fresh_arc=arc, fresh_lo=arc - half, fresh_hi=arc + half,
        fresh_age=np.zeros(epoch.size), fresh_reasons=reasons, metrics={}, link_transitions=[],
        input_proxy={}, output_proxy={}, input_blackouts=(), output_blackouts=(),
        sensor_fault_windows=list(faults), crashes=0, fresh_status=status,
    )


def test_rows_carry_the_error_interval_status_and_fault_window(tmp_path):
    epoch = 100.0 + np.array([1.0, 1.05, 2.0, 3.0, 12.0])  # the last is beyond the truth's span
    arc = np.array([10.5, 10.6, 23.0, 30.0, 120.0])  # truth 10, 10.5, 20, 30, -
    obs = _observation(epoch, arc, 1.0, status=np.array([1, 1, 2, 1, 1]),
                       reasons=[(), (), ("gnss_ramp", "gnss_timeout"), (), ()], faults=[(1.5, 2.5)])
    rows = timeline(obs, step_s=0.1)
    assert [r[0] for r in rows] == [1.0, 2.0, 3.0]  # 1.05 s shares 1.0 s's bin; 12 s has no truth
    t, truth, est, err, lo, hi, covered, status, in_fault, reasons = rows[1]
    assert (truth, est, err, lo, hi) == (20.0, 23.0, 3.0, 22.0, 24.0)
    assert (covered, status, in_fault, reasons) == (0, 2, 1, "gnss_ramp gnss_timeout")
    assert [r[6] for r in rows] == [1, 0, 1] and [r[8] for r in rows] == [0, 1, 0]
    path = tmp_path / "outputs.csv"
    assert write_outputs_csv(obs, path, step_s=0.1) == 3
    with open(path, newline="") as fh:
        lines = list(csv.reader(fh))
    assert tuple(lines[0]) == COLUMNS and len(lines) == 4
    assert lines[2][7] == "2" and lines[2][9] == "gnss_ramp gnss_timeout"


def test_unobservable_status_and_reasons_are_empty_and_step_zero_keeps_every_output():
    epoch = 100.0 + np.array([1.0, 1.05, 2.0])
    obs = _observation(epoch, np.array([10.0, 10.5, 20.0]), 0.2)
    rows = timeline(obs, step_s=0.0)
    assert len(rows) == 3 and all(r[7] == "" and r[9] == "" for r in rows)


@given(st.lists(st.floats(0.0, 9.9, allow_nan=False), min_size=1, max_size=60),
       st.floats(0.0, 2.0, allow_nan=False), st.sampled_from([0.0, 0.05, 0.1, 1.0]))
def test_covered_column_agrees_with_the_rows_coverage_figure(times, half, step):
    epoch = 100.0 + np.sort(np.asarray(times))
    arc = 10.0 * (epoch - 100.0) + np.sin(epoch)  # errors within +-1 m
    obs = _observation(epoch, arc, half)
    rows = timeline(obs, step_s=step)
    idx = thinned(epoch - 100.0, step)
    assert len(rows) == idx.size  # every output is inside the truth's span
    bins = np.floor((epoch[idx] - 100.0) / step) if step > 0 else idx
    assert np.all(np.diff(bins) > 0)  # one output per bin, the first of each
    ref = accuracy(epoch[idx], arc[idx], obs.truth_epoch, obs.truth_arc, arc[idx] - half, arc[idx] + half)
    assert np.mean([r[6] for r in rows]) == ref.coverage
