"""Solution separation (sfa.separation): sub-filters without one aid, the separation test, GNSS
exclusion with re-anchoring, detection without exclusion, and that a run without a detection is the
run without sub-filters, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from helpers_filter import run_filter

from interface_modules.presets import GPS_PRESETS, IMU_PRESETS, ODOMETER_PRESETS
from sfa import batch
from sfa import separation as SEP
from sfa.config import FilterConfig
from sfa.filter import TrackFilter
from sfa.layout import K_USE_GYRO, Outcome
from sfa.presets import filter_config_for
from sfa.synthetic import Faults, generate

IMU = IMU_PRESETS["mems-train"]
ODO = ODOMETER_PRESETS["wheel-odometer"]
GPS = GPS_PRESETS["standalone"]
RAMP = (150.0, 250.0, 0.0, 0.3)  #: 0.3 m/s along the northbound track, reaching 30 m


@pytest.fixture(scope="module")
def db(track):  # conftest's synthetic track database
    return track


@pytest.fixture(scope="module")
def cfg():
    # the CUSUM ramp detector off: the separation test alone must find the ramp
    return filter_config_for("mems-train", "wheel-odometer", "standalone").replace(cusum_h_sigma=1e9)


@pytest.fixture(scope="module")
def ramp_run(db):
    return generate(db, 1, 260.0, IMU, ODO, GPS, seed=14, faults=Faults(gps_ramps=(RAMP,)))


def ramp_figures(run, estimates):
    """Largest |error| and the interval's coverage of the truth from the ramp's start on."""
    err, covered = [], []
    for e in estimates:
        if not e.epoch_s - run.t_s[0] > RAMP[0]:
            continue
        i = int(np.clip(round((e.epoch_s - run.t_s[0]) * IMU.rate_hz), 0, run.t_s.size - 1))
        err.append(e.arc_length_m - run.s_m[i])
        covered.append(e.interval_low_m <= run.s_m[i] <= e.interval_high_m)
    return float(np.max(np.abs(err))), float(np.mean(covered))


def test_off_by_default():
    assert FilterConfig().separation_window_s == 0.0


def test_sub_configs_switch_only_the_gyro_off():
    cfg = FilterConfig(use_gyro=True).to_array()
    scfg = SEP.sub_configs(cfg)
    assert scfg.shape == (SEP.NSUB, cfg.size)
    for k in range(SEP.NSUB):
        want = cfg.copy()
        if k // SEP.COPIES == SEP.AID_GYRO:
            want[K_USE_GYRO] = 0.0
        assert np.array_equal(scfg[k], want)


def test_ramp_is_excluded_and_the_estimate_re_anchored(db, cfg, ramp_run):
    _, plain, _ = run_filter(db, cfg, ramp_run.measurements)
    plain_err, plain_cov = ramp_figures(ramp_run, plain)
    assert plain_err > 8.0 and plain_cov < 0.2  # without a ramp detector the fixes drag the estimate
    upd, est, f = run_filter(db, cfg.replace(separation_window_s=60.0), ramp_run.measurements)
    err, cov = ramp_figures(ramp_run, est)
    counters = f.counters()
    assert counters["separation_detections"] >= 1
    assert counters["separation_excluded"] >= 10
    assert sum(u.outcome == Outcome.HELD_OFF for u in upd) == counters["separation_excluded"]
    held = [e for e in est if "gnss_excluded" in e.reasons]
    assert held and all(e.status != 1 for e in held)  # a fault reason: never NOMINAL
    assert held[0].epoch_s - ramp_run.t_s[0] < RAMP[0] + 40.0
    assert err < 3.5 and cov >= 0.9


def test_fault_free_run_is_the_run_without_sub_filters(db, cfg):
    """No detection: the sub-filters only watch, and every estimate is bit-identical."""
    run = generate(db, 1, 200.0, IMU, ODO, GPS, seed=21)
    _, off, _ = run_filter(db, cfg, run.measurements)
    _, on, f = run_filter(db, cfg.replace(separation_window_s=60.0), run.measurements)
    assert f.counters()["separation_detections"] == 0
    a = np.array([(e.epoch_s, e.arc_length_m, e.sigma_s_m, e.interval_low_m, e.interval_high_m) for e in off])
    b = np.array([(e.epoch_s, e.arc_length_m, e.sigma_s_m, e.interval_low_m, e.interval_high_m) for e in on])
    assert a.tobytes() == b.tobytes()


def test_compiled_run_equals_per_message_with_separation(db, cfg, ramp_run):
    """TrackFilter.run (the replay's and the listener's compiled loop over many rows) and process (one
    row at a time) give the same state, outcomes and counters through a detection, bit for bit."""
    from sfa.bank import NEF, NEI, NOST, RunOutput

    c = cfg.replace(separation_window_s=60.0)
    meas = ramp_run.measurements
    upd, _, f1 = run_filter(db, c, meas)
    packed = batch.pack(meas, db)
    n = packed.kind.shape[0]
    out = RunOutput(np.full(n, -1, dtype=np.int64), np.zeros(n), np.zeros((NEF, 0)),
                    np.zeros((NEI, 0), dtype=np.int64), np.zeros(n), np.zeros(n), np.zeros(2),
                    np.zeros(NOST, dtype=np.int64), 0)
    f2 = TrackFilter(db, c)
    i, calls = 0, 0
    while i < n and calls < n:  # bounded: each call takes at least one row
        calls += 1
        j, _ = f2.run(packed.kind, packed.t_s, packed.values, i, out)
        if j < n:
            out.u_out[j] = int(f2.process(meas[j]).outcome)
        i = j + 1
    assert i >= n
    assert calls < n / 100  # the rows ran compiled, not one call each
    assert out.u_out.tolist() == [int(u.outcome) for u in upd]
    x1, P1 = f1.state()
    x2, P2 = f2.state()
    assert x1.tobytes() == x2.tobytes() and P1.tobytes() == P2.tobytes()
    assert f1.counters() == f2.counters()
    assert f1.counters()["separation_detections"] >= 1


def test_invalid_fix_during_exclusion_is_counted_invalid(db, cfg, ramp_run):
    from sfa.measurements import GpsMeas

    f = TrackFilter(db, cfg.replace(separation_window_s=60.0))
    for m in ramp_run.measurements:
        f.process(m)
        if f.counters()["separation_excluded"] >= 1:
            break
    else:
        pytest.fail("no exclusion")
    t = m.t_s + 0.001
    before = f.counters()
    assert f.process(GpsMeas(t, float("nan"), 11.58, 0.0, 1.5, 1, 10)).outcome == Outcome.INVALID
    after = f.counters()
    assert after["gps_invalid"] == before["gps_invalid"] + 1
    assert after["separation_excluded"] == before["separation_excluded"]
