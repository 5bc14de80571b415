"""tools.bench_generalisation: held-out seed ranges and the real-data rows of the generalisation table."""

from __future__ import annotations

import math

import numpy as np

from tools import bench_generalisation as G
from tools.info_bound import expected_p95


def test_first_seed_selects_held_out_worlds():
    """--first-seed 8 --seeds 2 runs seeds 8 and 9 (worlds a change chosen on seeds 0-7 never saw): the
    summary row pools exactly their errors, and differs from seeds 0 and 1."""
    kw = dict(step_s=0.5, max_duration_s=20.0, log=lambda m: None)
    held = G.run_families(["jena-tram"], 2, first_seed=8, **kw)[0]
    first = G.run_families(["jena-tram"], 2, **kw)[0]
    runs = [G.run_one(("jena-tram", seed, 0.5, 20.0, (), False)) for seed in (8, 9)]
    pooled = np.concatenate([r["sfa"] for r in runs])
    assert held["seeds"] == 2
    assert held["sfa_max"] == pooled.max()
    assert held["sfa_p95"] == float(np.percentile(pooled, 95))
    assert held["sfa_max"] != first["sfa_max"]
    # the information bound's column pools the same seeds' bound sigmas (tools.info_bound)
    assert held["bound_p95"] == expected_p95(np.concatenate([r["bound-sigma"] for r in runs]))
    assert all(r["bound-sigma"].shape == r["sfa"].shape for r in runs)
    # seed by seed against the plain EKF: counted and the median ratio of the same runs' own p95s
    sfa = [float(np.percentile(r["sfa"], 95)) for r in runs]
    ekf = [float(np.percentile(r["plain-ekf"], 95)) for r in runs]
    assert held["seeds_sfa_le_ekf"] == sum(a <= b for a, b in zip(sfa, ekf, strict=True))
    assert held["seed_ratio_median"] == float(np.median(np.array(ekf) / np.array(sfa)))
    line = G.markdown_table([held]).splitlines()[-1]
    assert f"| {held['seeds_sfa_le_ekf']} / 2 ({held['seed_ratio_median']:.2f}x) |" in line


def test_seed_comparison_counts_the_seeds_where_sfa_is_not_worse():
    """Three worlds: SFA better on one, equal on one, worse on one; the median ratio is the middle."""
    runs = [{"sfa": np.full(10, a), "plain-ekf": np.full(10, b)} for a, b in ((1.0, 2.0), (1.0, 1.0),
                                                                              (2.0, 1.0))]
    assert G.seed_comparison(runs) == {"seeds_sfa_le_ekf": 2, "seed_ratio_median": 1.0}


def test_the_bound_uses_the_worlds_gnss_error():
    """The bound of a run is computed from the seed's drawn GNSS error: a larger drawn error, a larger
    bound (jena seed 0 draws sigma_g 1.43 m, tau 118 s; seed 16 draws 0.58 m, 5.8 s)."""
    big = G.run_one(("jena-tram", 0, 0.5, 120.0, (), False))["bound-sigma"]
    small = G.run_one(("jena-tram", 16, 0.5, 120.0, (), False))["bound-sigma"]
    assert expected_p95(small) < 0.8 * expected_p95(big)


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
    assert "- %" not in line and "-x" not in line  # no unit after a missing value


def test_coverage_interval_resamples_whole_seeds():
    """The coverage interval is a seed bootstrap: it holds the pooled coverage, is the same on every
    call, is wide when one seed misses for long (one seed in twenty at 20 %) and has no spread when
    every seed covers alike; a single seed gives none."""
    rng = np.random.default_rng(3)
    seeds = [rng.random(600) < 0.97 for _ in range(19)] + [rng.random(600) < 0.2]
    pooled = float(np.mean(np.concatenate(seeds)))
    lo, hi = G.coverage_interval(seeds)
    assert lo < pooled < hi
    assert (lo, hi) == G.coverage_interval(seeds)
    assert hi - lo > 0.04  # samples taken as independent would give about +-0.006
    assert G.coverage_interval([np.ones(50, bool)] * 4) == (1.0, 1.0)
    assert all(math.isnan(v) for v in G.coverage_interval([np.ones(50, bool)]))
    row = {"family": "x", "seeds": 20, "sfa_p95": 1.0, "sfa_max": 2.0, "sfa_coverage": pooled,
           "sfa_coverage_ci": (lo, hi), "sfa-gyro_p95": 1.0, "sfa-gyro_max": 2.0,
           "sfa-gyro_coverage": pooled, "plain-ekf_p95": 1.1, "odo-dr_p95": 9.0}
    line = G.markdown_table([row]).splitlines()[-1]
    assert f"{100 * pooled:.1f} % ({100 * lo:.1f}-{100 * hi:.1f})" in line


def test_known_gnss_tells_sfa_the_world_s_gnss_model_and_only_sfa():
    """--known-gnss: SFA's configuration carries the seed's drawn GNSS error model with the adaptive
    model off; the baselines and the bound are those of the plain run, SFA's errors are not."""
    sc, _run, _meas, cfg = G.family_world("jena-tram", 0, 60.0)
    told = G.known_gnss_config(cfg, sc)
    drawn = dict(sc.gps.actual)
    assert told.gps_gm_sigma_m == drawn["gm_sigma_m"] != cfg.gps_gm_sigma_m
    assert told.gps_gm_tau_s == drawn["gm_tau_s"]
    assert told.gps_white_sigma_m == drawn["white_sigma_m"]
    assert told.gps_nominal_sigma_h_m == drawn["reported_sigma_h_m"]
    assert told.gps_adaptive_window_s == 0.0 < cfg.gps_adaptive_window_s
    plain = G.run_one(("jena-tram", 0, 0.5, 60.0, (), False))
    known = G.run_one(("jena-tram", 0, 0.5, 60.0, (), True))
    for key in ("plain-ekf", "odo-dr", "bound-sigma"):
        assert np.array_equal(plain[key], known[key])
    assert not np.array_equal(plain["sfa"], known["sfa"])
    row = G.run_families(["jena-tram"], 1, max_duration_s=20.0, log=lambda m: None, known_gnss=True)[0]
    assert G.markdown_table([row]).splitlines()[-1].startswith("| jena-tram (GNSS model known) |")
