"""tools.bench_generalisation: held-out seed ranges and the real-data rows of the generalisation table."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tools import bench_generalisation as G


def test_first_seed_selects_held_out_worlds(monkeypatch):
    """--first-seed 8 --seeds 2 runs seeds 8 and 9 (worlds a change chosen on seeds 0-7 never saw)."""
    seen = []

    def fake_run_one(task):
        name, seed = task[0], task[1]
        seen.append((name, seed))
        e = np.array([0.1 * (seed + 1)])
        return {"family": name, "seed": seed, "sfa": e, "sfa-gyro": e, "plain-ekf": e, "odo-dr": e,
                "sfa-covered": np.array([True]), "sfa-gyro-covered": np.array([True])}

    monkeypatch.setattr(G, "run_one", fake_run_one)
    rows = G.run_families(["jena-tram"], 2, first_seed=8, log=lambda m: None)
    assert seen == [("jena-tram", 8), ("jena-tram", 9)]
    assert rows[0]["seeds"] == 2 and rows[0]["sfa_max"] == pytest.approx(1.0)


def test_real_data_rows_smartloc_and_dresden():
    """The smartLoc row with synthesised GNSS has truth: SFA, the plain EKF and odometer dead reckoning
    are all measured against it, and SFA's interval coverage is a fraction; the Dresden row has no
    truth: SFA's figure is the distance from the fixes on the track, the baselines print as '-'."""
    sl = G.real_data_row("smartloc-synth-gnss", log=lambda m: None)
    assert 0.0 < sl["sfa_p95"] <= sl["sfa_max"] < 20.0
    assert 0.0 <= sl["sfa_coverage"] <= 1.0
    assert math.isfinite(sl["plain-ekf_p95"]) and sl["plain-ekf_p95"] > 0.0
    assert sl["odo-dr_p95"] > sl["sfa_p95"]  # the real odometer alone drifts
    dr = G.real_data_row("dresden", log=lambda m: None)
    assert 0.0 < dr["sfa_p95"] < 50.0
    assert math.isnan(dr["plain-ekf_p95"]) and math.isnan(dr["sfa_coverage"])
    table = G.markdown_table([sl, dr])
    line = next(ln for ln in table.splitlines() if ln.startswith("| dresden "))
    assert "| - |" in line and "nan" not in line
