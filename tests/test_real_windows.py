"""tools.real_windows: a real log judged from many start times."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tools import bench_generalisation as G
from tools import real_windows as W
from tools.errors import ToolError


def test_window_starts_fit_the_log():
    """Every window lies inside the log, the first starts at its first measurement, one step apart;
    a log shorter than one window is an error naming both lengths."""
    wc = W.WindowConfig(window_s=140.0, step_s=10.0)
    starts = W.window_starts(5.0, 288.0, wc)
    assert starts[0] == 5.0 and np.all(np.diff(starts) == 10.0)
    assert starts[-1] + 140.0 <= 288.0 < starts[-1] + 150.0
    assert len(W.window_starts(0.0, 140.0, wc)) == 1
    with pytest.raises(ToolError, match="lasts 100.0 s, shorter than one 140 s window"):
        W.window_starts(0.0, 100.0, wc)
    for bad in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(ToolError, match="step_s"):
            W.WindowConfig(step_s=bad)


def test_summary_counts_windows_against_the_limit_and_the_baselines():
    """Three windows: the median, mean and worst of SFA's p95, the windows under the limit and those
    where SFA is not worse than each baseline."""
    ws = [{"sfa_p95": a, "sfa_max": a + 1.0, "sfa_coverage": c, "plain-ekf_p95": e, "odo-dr_p95": o}
          for a, c, e, o in ((1.0, 1.0, 5.0, 0.5), (2.0, 0.9, 2.0, 3.0), (6.0, 0.8, 4.0, 7.0))]
    s = W.summary(ws, 3.0)
    assert (s["sfa_p95_median"], s["sfa_p95_mean"], s["sfa_p95_worst"]) == (2.0, 3.0, 6.0)
    assert s["within_limit"] == 2 and s["sfa_max_median"] == 3.0
    assert s["windows_sfa_le_ekf"] == 2 and s["windows_sfa_le_odo"] == 2
    assert s["sfa_coverage_mean"] == pytest.approx(0.9) and s["sfa_coverage_min"] == 0.8
    line = W.markdown_table([{**s, "family": "log"}]).splitlines()[-1]
    assert line.startswith("| log | 3 | 2.000 / 3.000 / 6.000 | 2 (<= 3 m) | 90.0 % (80.0 %) |")


def test_smartloc_windows_are_repeatable_and_start_where_they_say():
    """smartLoc with synthesised GNSS, 60 s windows every 100 s: two runs give the same bits; each
    window's SFA p95 is below the plain EKF's (the synthesised receiver is the standalone preset's own
    model; over 60 s the real odometer alone can be better, 1.0 against 1.9 m in one window, so it is not
    asserted on); the coverage is a fraction."""
    wc = W.WindowConfig(window_s=60.0, step_s=100.0)
    a = G.real_windows_row("smartloc-synth-gnss", wc)
    b = G.real_windows_row("smartloc-synth-gnss", wc)
    assert a["per_window"] == b["per_window"]
    assert [w["t0"] for w in a["per_window"]] == [0.0, 100.0, 200.0]
    assert a["windows"] == 3 and a["family"].startswith("smartloc-synth-gnss (3 windows of 60 s")
    for w in a["per_window"]:
        assert 0.0 < w["sfa_p95"] < w["plain-ekf_p95"] and w["odo-dr_p95"] > 0.0
        assert 0.0 <= w["sfa_coverage"] <= 1.0


def test_bench_rows_judge_the_median_window_against_the_limit():
    """``sfa bench``'s rows of the windows: one per log of REAL_WINDOWS, the median window's p95 as the
    value, every window's p95 as the samples, met exactly when the median is within the limit; a log
    without truth (Dresden) is refused with its name."""
    wc = W.WindowConfig(window_s=60.0, step_s=100.0)
    rows = G.real_windows_rows(wc, log=lambda m: None)
    assert [r.name.split(" (")[0] for r in rows] == [label for label, _ in G.REAL_WINDOWS]
    for r, (_, limit) in zip(rows, G.REAL_WINDOWS, strict=True):
        assert len(r.samples) == r.repeats == 3
        assert r.value == float(np.median(r.samples))
        assert r.met == (r.value <= limit) and r.target == f"<= {limit:g} m"
        assert "plain FilterPy EKF" in r.compared and "odometer only" in r.compared
    with pytest.raises(ToolError, match="dresden: the log has no truth"):
        G.real_windows_row("dresden", wc)
