"""Robustness of the SFA filter on seeded synthetic data: GNSS jump and ramp, odometer slip, a
10-minute GNSS outage, invalid values, late data, time-outs, determinism."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers_filter import run_filter

from interface_modules.presets import GPS_PRESETS, IMU_PRESETS, ODOMETER_PRESETS
from sfa import batch
from sfa.filter import TrackFilter
from sfa.layout import FilterStatus, Outcome
from sfa.measurements import GpsMeas, ImuMeas, InitMeas, OdoMeas
from sfa.presets import GROUND_TRUTH_SIGMA_M, filter_config_for
from sfa.synthetic import Faults, Profile, build_track_db, generate
from track_db import TrackDatabase

IMU = IMU_PRESETS["mems-train"]
ODO = ODOMETER_PRESETS["wheel-odometer"]
GPS = GPS_PRESETS["standalone"]


@pytest.fixture(scope="module")
def db(tmp_path_factory):
    path = build_track_db(tmp_path_factory.mktemp("track") / "synthetic.db")
    with TrackDatabase.open(path) as database:
        yield database


@pytest.fixture(scope="module")
def cfg():
    return filter_config_for("mems-train", "wheel-odometer", "standalone")


def truth_at(run, t):
    i = np.clip(np.round((np.asarray(t) - run.t_s[0]) * IMU.rate_hz).astype(int), 0, run.t_s.size - 1)
    return run.s_m[i]


def errors_of(run, estimates):
    t = np.array([e.epoch_s for e in estimates])
    s = np.array([e.arc_length_m for e in estimates])
    return t, s - truth_at(run, t)


def test_50m_gnss_jump_rejected_at_first_epoch(db, cfg):
    jump = (200.0, 230.0, 30.0, 40.0)  # 50 m, mostly along the northbound track
    run = generate(db, 1, 300.0, IMU, ODO, GPS, seed=11, faults=Faults(gps_jumps=(jump,)))
    updates, estimates, f = run_filter(db, cfg, run.measurements)
    t0 = run.t_s[0] + jump[0]
    gps = [(m, u) for m, u in zip(run.measurements, updates, strict=True) if isinstance(m, GpsMeas)]
    in_jump = [(m, u) for m, u in gps if t0 <= m.t_s < run.t_s[0] + jump[1]]
    assert in_jump[0][1].outcome == Outcome.GATED  # first epoch of the jump
    assert all(u.outcome == Outcome.GATED for _, u in in_jump)
    before = [u for m, u in gps if m.t_s < t0]
    assert sum(u.outcome == Outcome.ACCEPTED for u in before) >= len(before) - 1
    counters = f.counters()
    assert counters["gnss_step_detections"] >= 1
    t, err = errors_of(run, estimates)
    assert np.max(np.abs(err[(t >= t0) & (t < t0 + 30.0)])) < 1.5
    # during the jump the status says why
    i = next(k for k, m in enumerate(run.measurements) if m.t_s >= t0 + 5.0)
    _, est, _ = run_filter(db, cfg, run.measurements[: i + 1])
    assert "gnss_step" in est[-1].reasons and est[-1].status == FilterStatus.DEGRADED


def test_20_percent_slip_for_5s_detected_and_bounded(db, cfg):
    slip = (130.0, 135.0, 1.2)  # cruising at ~12 m/s
    clean = generate(db, 1, 200.0, IMU, ODO, GPS, seed=12)
    slipped = generate(db, 1, 200.0, IMU, ODO, GPS, seed=12, faults=Faults(odo_slips=(slip,)))
    _, est_clean, _ = run_filter(db, cfg, clean.measurements)
    upd, est_slip, f = run_filter(db, cfg, slipped.measurements)
    assert f.counters()["slip_detections"] >= 1
    t0 = slipped.t_s[0] + slip[0]
    first_flag = next(e.epoch_s for e in est_slip if "odometer_slip" in e.reasons)
    assert t0 <= first_flag <= t0 + 0.5
    s_clean = np.array([e.arc_length_m for e in est_clean])
    s_slip = np.array([e.arc_length_m for e in est_slip])
    assert np.max(np.abs(s_slip - s_clean)) <= 1.0
    _, err = errors_of(slipped, est_slip)
    assert np.max(np.abs(err)) < 2.0
    assert f.estimate().status == FilterStatus.NOMINAL or "odometer_slip" not in f.estimate().reasons


def test_10_minute_gnss_outage_degrades_honestly_and_recovers(db, cfg):
    outage = (100.0, 700.0)
    run = generate(db, 1, 760.0, IMU, ODO, GPS, seed=13, faults=Faults(gps_outages=(outage,)))
    res = batch.replay(db, cfg, run.measurements)
    t = res.epoch_s
    err = res.arc_length_m - truth_at(run, t)
    t_out0, t_back = run.t_s[0] + outage[0], run.t_s[0] + outage[1]
    during = (t > t_out0 + cfg.gps_timeout_s + 0.1) & (t < t_back)
    assert np.all(res.status[during] == FilterStatus.DEGRADED)
    assert np.all(res.reason_bits[during] & 8)  # R_GPS_TIMEOUT
    # honest interval: wider at the end of the outage than when GNSS was lost, and the truth stays
    # inside it. Not monotonic in between: the gyro's map matching locates the train in the synthetic
    # line's curve (measured: sigma_s 0.82 m when GNSS is lost, 1.63 m at 200 s, 0.15 m after the
    # curve at 300 s, 0.87 m at the end of the 5 km outage; this run's IMU has no scale or misalignment
    # error). The end value is not compared with the largest sigma_s of the 10 s before the outage,
    # when GNSS was still shrinking it: that passed by 0.015 m with GROUND TRUTH's sigma 0.1 m and
    # failed by 1.3e-5 m with 0.01 m (sfa.presets.GROUND_TRUTH_SIGMA_M), a coincidence of two
    # unrelated values rather than a property.
    sig = res.sigma_s_m
    assert sig[during][-1] > sig[t < t_out0][-1]
    z = cfg.replace().interval_z()
    assert np.mean(np.abs(err[during]) <= z * sig[during]) >= 0.95
    assert np.all(np.abs(err[during]) <= 3.5 * sig[during])
    # recovery within 10 s of the first fix back
    after = (t >= t_back + 10.0)
    assert np.all(res.status[after] == FilterStatus.NOMINAL)
    assert np.max(np.abs(err[after])) < 1.5
    assert sig[after].max() < 1.5
    assert int(res.counters[18]) >= 1  # gps_timeouts


def test_gnss_ramp_detected(db, cfg):
    ramp = (150.0, 250.0, 0.0, 0.3)  # 0.3 m/s along the northbound track
    run = generate(db, 1, 260.0, IMU, ODO, GPS, seed=14, faults=Faults(gps_ramps=(ramp,)))
    _, estimates, f = run_filter(db, cfg, run.measurements)
    assert f.counters()["gnss_ramp_detections"] >= 1
    first = next(e.epoch_s for e in estimates if "gnss_ramp" in e.reasons or "gnss_rejected" in e.reasons)
    assert first - (run.t_s[0] + ramp[0]) < 40.0
    t, err = errors_of(run, estimates)
    assert np.max(np.abs(err)) < 3.0  # a ramp reaching 30 m moves the estimate by far less


def test_invalid_values_rejected_counted_never_nan(db, cfg):
    run = generate(db, 1, 20.0, IMU, ODO, GPS, seed=15)
    f = TrackFilter(db, cfg)
    for m in run.measurements[:500]:
        f.process(m)
    t = run.measurements[499].t_s + 0.001
    bad = [
        ImuMeas(t, (math.nan, 0.0, -9.8), (0.0, 0.0, 0.0)),
        ImuMeas(t, (0.0, math.inf, -9.8), (0.0, 0.0, 0.0)),
        ImuMeas(math.nan, (0.0, 0.0, -9.8), (0.0, 0.0, 0.0)),
        OdoMeas(t, math.nan, 0.05),
        OdoMeas(t, 5.0, math.inf),
        OdoMeas(t, 5.0, -1.0),
        GpsMeas(t, math.nan, 11.58, 0.0, 1.5, 1, 10),
        GpsMeas(t, 50.93, math.inf, 0.0, 1.5, 1, 10),
        GpsMeas(t, 95.0, 11.58, 0.0, 1.5, 1, 10),
        GpsMeas(t, 50.93, 11.58, 0.0, math.inf, 1, 10),
        InitMeas(t, math.nan, 1.0, 1),
        InitMeas(t, 10.0, 1.0, 999),
    ]
    before = f.counters()
    for m in bad:
        assert f.process(m).outcome == Outcome.INVALID, m
    after = f.counters()
    assert after["imu_invalid"] - before["imu_invalid"] == 3
    assert after["odo_invalid"] - before["odo_invalid"] == 3
    assert after["gps_invalid"] - before["gps_invalid"] == 4
    no_fix = f.process(GpsMeas(t, 0.0, 0.0, 0.0, 1e4, 0, 0))
    assert no_fix.outcome == Outcome.NO_FIX and f.counters()["gps_no_fix"] == 1
    for m in run.measurements[500:]:
        f.process(m)
    e = f.estimate()
    assert all(math.isfinite(v) for v in (e.arc_length_m, e.speed_mps, e.sigma_s_m, e.lat_deg, e.lon_deg))
    assert abs(e.arc_length_m - run.s_m[-1]) < 1.0
    x, P = f.state()
    np.linalg.cholesky(P)
    assert np.array_equal(P, P.T)


def test_declared_fault_widens_the_reported_interval_only(db, cfg):
    """While a sensor is declared faulty or missing the reported sigma is the filter's own times
    z(fault_confidence) / z(confidence); the estimate itself is the same, and otherwise the sigma is
    unchanged (the same run with fault_confidence = confidence as reference). The ramp run's GNSS
    hold-off also times GNSS out."""
    ramp = (150.0, 250.0, 0.0, 0.3)
    run = generate(db, 1, 260.0, IMU, ODO, GPS, seed=14, faults=Faults(gps_ramps=(ramp,)))
    _, wide, _ = run_filter(db, cfg, run.measurements)
    _, plain, _ = run_filter(db, cfg.replace(fault_confidence=cfg.confidence), run.measurements)
    assert len(wide) == len(plain)
    scale = cfg.interval_z(cfg.fault_confidence) / cfg.interval_z()
    fault = {"gnss_ramp", "gnss_step", "odometer_slip", "imu_fault", "imu_stuck", "gnss_timeout",
             "odometer_timeout", "imu_timeout"}
    n_fault = 0
    for w, p in zip(wide, plain, strict=True):
        assert w.arc_length_m == p.arc_length_m and w.reasons == p.reasons
        if w.hypotheses > 1:  # the mixture of several hypotheses' intervals: not a scale of one
            continue
        if fault & set(w.reasons):
            n_fault += 1
            assert w.sigma_s_m == pytest.approx(scale * p.sigma_s_m, rel=1e-12)
            assert w.interval_high_m - w.interval_low_m > 1.3 * (p.interval_high_m - p.interval_low_m)
        else:
            assert w.sigma_s_m == p.sigma_s_m
    assert n_fault > 100  # the ramp is declared for a while


def test_late_data_policy(db, cfg):
    run = generate(db, 1, 30.0, IMU, ODO, GPS, seed=16)
    f = TrackFilter(db, cfg)
    ms = run.measurements
    for m in ms[:2000]:
        f.process(m)
    t_state = f.estimate().epoch_s
    assert f.process(ImuMeas(t_state - 0.05, (0.0, 0.0, -9.8), (0.0, 0.0, 0.0))).outcome == Outcome.LATE
    assert f.process(OdoMeas(t_state - 0.05, 5.0, 0.05)).outcome == Outcome.LATE
    lat, lon = db.line(1).latlon_at(float(truth_at(run, t_state - 0.3)))
    late_ok = f.process(GpsMeas(t_state - 0.3, float(lat), float(lon), 0.0, 1.5, 1, 12))
    assert late_ok.outcome == Outcome.ACCEPTED
    too_late = f.process(GpsMeas(t_state - 2.0, float(lat), float(lon), 0.0, 1.5, 1, 12))
    assert too_late.outcome == Outcome.LATE
    c = f.counters()
    assert (c["imu_late"], c["odo_late"], c["gps_late"], c["gps_late_applied"]) == (1, 1, 1, 1)
    # equal timestamps are not late
    assert f.process(OdoMeas(t_state, f.estimate().speed_mps, 0.05)).outcome == Outcome.ACCEPTED


def test_timeouts_and_status(db, cfg):
    f = TrackFilter(db, cfg)
    assert f.estimate().status == FilterStatus.INITIALISING
    assert f.process(OdoMeas(1.0, 1.0, 0.05)).outcome == Outcome.NOT_INITIALISED
    run = generate(db, 1, 40.0, IMU, ODO, GPS, seed=17)
    # drop every odometer sample between 20 and 25 s
    t0 = run.t_s[0]
    ms = [m for m in run.measurements if not (isinstance(m, OdoMeas) and t0 + 20 <= m.t_s < t0 + 25)]
    statuses = []
    for m in ms:
        f.process(m)
        statuses.append((m.t_s, f.estimate()))
    during = [e for t, e in statuses if t0 + 22 <= t < t0 + 25]
    assert all("odometer_timeout" in e.reasons and e.status == FilterStatus.DEGRADED for e in during)
    assert f.counters()["odo_timeouts"] == 1
    assert f.estimate().status == FilterStatus.NOMINAL
    # no motion sensor at all for long: LOST, judged at a later time
    later = f.estimate(at_s=f.estimate().epoch_s + 5.0)
    assert later.status == FilterStatus.LOST and "no_motion_sensor" in later.reasons


def test_deterministic_and_batch_identical(db, cfg):
    run = generate(db, 1, 120.0, IMU, ODO, GPS, seed=18,
                   faults=Faults(gps_jumps=((60.0, 65.0, 50.0, 0.0),), odo_slips=((30.0, 35.0, 1.2),)))
    _, est_a, fa = run_filter(db, cfg, run.measurements)
    _, est_b, fb = run_filter(db, cfg, run.measurements)
    a = np.array([(e.epoch_s, e.arc_length_m, e.speed_mps, e.sigma_s_m) for e in est_a])
    b = np.array([(e.epoch_s, e.arc_length_m, e.speed_mps, e.sigma_s_m) for e in est_b])
    assert a.tobytes() == b.tobytes()
    res = batch.replay(db, cfg, run.measurements)
    res2 = batch.replay(db, cfg, run.measurements)
    c = np.column_stack((res.epoch_s, res.arc_length_m, res.speed_mps, res.sigma_s_m))
    c2 = np.column_stack((res2.epoch_s, res2.arc_length_m, res2.speed_mps, res2.sigma_s_m))
    assert c.tobytes() == c2.tobytes()
    # the batch loop runs the same kernels, compiled inside another function: LLVM may round a few
    # operations differently (1e-17 relative), so across the two paths the agreement is numerical
    # the batch loop keeps one hypothesis: where the filter keeps others on the line (the reversal at a
    # stop) its interval holds their mixture, never narrower than the one hypothesis's
    one = np.array([e.hypotheses == 1 for e in est_a])
    assert 0 < one.sum() < one.size
    np.testing.assert_allclose(c[:, :3], a[:, :3], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(c[one, 3], a[one, 3], rtol=1e-9, atol=1e-9)
    assert np.all(a[~one, 3] >= c[~one, 3] * (1.0 - 1e-9))
    status = np.array([FilterStatus(int(s)) for s in res.status])
    assert [e.status for e, o in zip(est_a, one, strict=True) if o] == list(status[one])
    assert fa.counters() == fb.counters()


def test_single_corrupted_future_epoch_is_rejected_a_real_gap_is_not(db, cfg):
    run = generate(db, 1, 60.0, IMU, ODO, GPS, seed=19)
    f = TrackFilter(db, cfg)
    ms = run.measurements
    for m in ms[:3000]:
        f.process(m)
    t_state = f.estimate().epoch_s
    # one IMU datagram whose epoch is 1e5 s ahead (a flipped bit): rejected, nothing stalls
    bad = ImuMeas(t_state + 1e5, (0.0, 0.0, -9.8), (0.0, 0.0, 0.0))
    assert f.process(bad).outcome == Outcome.INVALID
    assert f.counters()["time_jumps_rejected"] == 1
    for m in ms[3000:]:
        f.process(m)
    e = f.estimate()
    assert e.epoch_s == ms[-1].t_s and e.status == FilterStatus.NOMINAL
    assert abs(e.arc_length_m - run.s_m[-1]) < 1.0
    # a real 30 s gap of every sensor: the second sample confirms it and the filter carries on
    t1 = ms[-1].t_s + 30.0
    assert f.process(OdoMeas(t1, 0.0, 0.03)).outcome == Outcome.INVALID
    assert f.process(OdoMeas(t1 + 0.05, 0.0, 0.03)).outcome != Outcome.INVALID
    assert f.estimate().epoch_s == t1 + 0.05 and f.counters()["time_jumps_rejected"] == 2


def _imu_modified(run, fn):
    """The run's measurements with each IMU sample passed through fn(i, t_from_start, sample)."""
    t0 = run.t_s[0]
    out = []
    for i, m in enumerate(run.measurements):
        out.append(fn(i, m.t_s - t0, m) if isinstance(m, ImuMeas) else m)
    return out


def _bias_step(_i, t, m):
    """+0.3 m/s^2 on the forward accelerometer from 60 to 120 s."""
    if 60.0 <= t < 120.0:
        return ImuMeas(m.t_s, (m.f_mps2[0] + 0.3, m.f_mps2[1], m.f_mps2[2]), m.w_radps)
    return m


def _coverage(run, est, cfg, lo_s, hi_s):
    """Fraction of the estimates in [lo_s, hi_s) from the start whose interval holds the truth."""
    t, err = errors_of(run, est)
    rel = t - run.t_s[0]
    sig = np.array([e.sigma_s_m for e in est])
    w = (rel >= lo_s) & (rel < hi_s)
    return float(np.mean(np.abs(err[w]) <= cfg.interval_z() * sig[w]))


def test_accelerometer_bias_step_declared_by_gnss_and_covered(db, cfg):
    """A 0.3 m/s^2 step of the along-track accelerometer bias for 60 s. The odometer/IMU disagreement
    is first declared a slip (IMU bridging alone); until GNSS tells the two apart the interval also
    covers the odometer's position. The fixes agree with the odometer, so the accelerometer is
    declared faulty within seconds (not after slip_max_s), the estimate moves to the odometer's
    position and the truth stays inside the interval throughout (measured: declared 5.05 s after the
    step, coverage 1.0, error < 0.8 m from 1 s after the declaration)."""
    run = generate(db, 1, 200.0, IMU, ODO, GPS, seed=20)
    _, est, f = run_filter(db, cfg, _imu_modified(run, _bias_step))
    t, err = errors_of(run, est)
    rel = t - run.t_s[0]
    assert f.counters()["imu_faults"] >= 1 and f.counters()["odo_reanchors"] >= 1
    declared = min(e.epoch_s - run.t_s[0] for e in est if "imu_fault" in e.reasons)
    assert 60.0 < declared <= 60.0 + 10.0 < 60.0 + cfg.slip_max_s
    assert _coverage(run, est, cfg, 60.0, 120.0) >= 0.99
    after = (rel >= declared + 1.0) & (rel < 120.0)
    assert after.any() and np.max(np.abs(err[after])) < 1.0
    assert np.all(np.isfinite(err))
    clean = run_filter(db, cfg, run.measurements)[2]
    assert clean.counters()["imu_faults"] == 0  # no fault declared on the clean run


def test_accelerometer_bias_step_without_gnss_declared_after_slip_max_and_covered(db, cfg):
    """The same bias step inside a GNSS outage: nothing can arbitrate, so the slip lasts slip_max_s
    before the accelerometer is declared faulty, and the interval covers the odometer's position all
    along (measured: declared at 81.75 s, coverage 1.0 over the step; the error reaches 72 m and the
    reported sigma_s 72 m)."""
    run = generate(db, 1, 200.0, IMU, ODO, GPS, seed=20, faults=Faults(gps_outages=((55.0, 130.0),)))
    _, est, f = run_filter(db, cfg, _imu_modified(run, _bias_step))
    declared = min(e.epoch_s - run.t_s[0] for e in est if "imu_fault" in e.reasons)
    assert 60.0 + cfg.slip_max_s <= declared <= 60.0 + cfg.slip_max_s + 5.0
    assert _coverage(run, est, cfg, 60.0, 120.0) >= 0.99


def test_slip_confirmed_by_gnss_is_not_an_accelerometer_fault(db, cfg):
    """A 20 % slip for 5 s with GNSS: the fixes agree with the IMU-bridged estimate, so the slip is
    confirmed (no imu_fault) and the interval, widened at the declaration to cover the odometer's
    position, returns to its own width before the slip ends: the filter's sigma widened by the
    fault_confidence factor while the slip is declared (measured: sigma_s 0.82 m before, 2.9 m at most,
    1.11 m = 1.31 x 0.85 m from 2.5 s into the slip)."""
    slip = (130.0, 135.0, 1.2)
    run = generate(db, 1, 200.0, IMU, ODO, GPS, seed=12, faults=Faults(odo_slips=(slip,)))
    _, est, f = run_filter(db, cfg, run.measurements)
    assert f.counters()["slip_detections"] >= 1 and f.counters()["imu_faults"] == 0
    assert not any("imu_fault" in e.reasons for e in est)
    rel = np.array([e.epoch_s for e in est]) - run.t_s[0]
    sig = np.array([e.sigma_s_m for e in est])
    before = sig[(rel >= 125.0) & (rel < 130.0)].max()
    assert sig[(rel >= 130.0) & (rel < 135.0)].max() > 2.0 * before
    fault_scale = cfg.interval_z(cfg.fault_confidence) / cfg.interval_z()  # 2.576 / 1.960
    late = (rel >= 134.0) & (rel < 135.0)
    assert all("odometer_slip" in est[i].reasons for i in np.flatnonzero(late))  # still declared
    assert sig[late].max() < 1.2 * fault_scale * before
    assert _coverage(run, est, cfg, 125.0, 140.0) >= 0.99


def test_standstill_after_ground_truth_keeps_its_accuracy(db, cfg):
    """60 s standing after GROUND TRUTH: nothing observes the arc length better than GROUND TRUTH did
    (GNSS is metre class), and the train does not move, so the interval stays at GROUND TRUTH's own
    accuracy and the estimate stays put. With the former 0.1 m prior (ten times the error of the
    simulated GROUND TRUTH) sigma_s stayed at 0.1 m for the whole standstill while the error was
    0.008-0.018 m: the standstill-creep scenario's over-wide interval (coverage 98.5 %, NEES 0.51).
    Measured here: sigma_s 0.010 -> 0.013 m, error < 0.001 m."""
    assert cfg.init_sigma_s_m == GROUND_TRUTH_SIGMA_M
    profile = Profile(segments=((60.0, 0.0), (15.0, 0.8), (60.0, 0.0), (15.0, -0.8), (30.0, 0.0)))
    run = generate(db, 1, 180.0, IMU, ODO, GPS, seed=15, profile=profile)
    _, est, _ = run_filter(db, cfg, run.measurements)
    t, err = errors_of(run, est)
    rel = t - run.t_s[0]
    sig = np.array([e.sigma_s_m for e in est])
    standing = (rel >= 1.0) & (rel < 59.0)
    assert all("standstill" in e.reasons for e, w in zip(est, standing, strict=True) if w)
    assert np.all(sig[standing] <= 2.0 * GROUND_TRUTH_SIGMA_M)
    assert np.all(np.abs(err[standing]) <= cfg.interval_z() * sig[standing])
    assert _coverage(run, est, cfg, 0.0, 180.0) >= 0.95


def test_stuck_imu_detected_reported_and_bridged(db, cfg):
    """The IMU repeats one sample for 10 s: declared stuck after 10 identical samples, its samples are
    not used (reason imu_stuck, then imu_timeout), the filter bridges on the odometer and recovers."""
    run = generate(db, 1, 120.0, IMU, ODO, GPS, seed=21)
    frozen = {}

    def stuck(i, t, m):
        if 50.0 <= t < 60.0:
            frozen.setdefault("m", m)
            return ImuMeas(m.t_s, frozen["m"].f_mps2, frozen["m"].w_radps)
        return m

    updates, est, f = run_filter(db, cfg, _imu_modified(run, stuck))
    assert f.counters()["imu_stuck_samples"] >= 980
    during = [e for e in est if 52.0 <= e.epoch_s - run.t_s[0] < 59.0]
    assert during and all("imu_stuck" in e.reasons and e.status == FilterStatus.DEGRADED for e in during)
    t, err = errors_of(run, est)
    assert np.max(np.abs(err)) < 1.0
    after = [e for e in est if e.epoch_s - run.t_s[0] > 61.0]
    assert after and "imu_stuck" not in after[-1].reasons
    assert run_filter(db, cfg, run.measurements)[2].counters()["imu_stuck_samples"] == 0


def test_covariance_stays_exactly_symmetric_through_faults(db, cfg):
    """sync_block averages only the (S, V, GE, GN) pairs (the others are equal by construction when P is
    symmetric): that holds only if every path leaves P exactly symmetric. Slip (rewind, re-anchor),
    GNSS jump and ramp, outage, standstills (reversal hypotheses): checked after every measurement."""
    faults = Faults(
        gps_outages=((60.0, 90.0),),
        gps_jumps=((110.0, 125.0, 40.0, -25.0),),
        gps_ramps=((150.0, 170.0, 0.8, 0.4),),
        odo_slips=((30.0, 36.0, 1.25),),
    )
    run = generate(db, 1, 200.0, IMU, ODO, GPS, seed=31, faults=faults)
    f = TrackFilter(db, cfg)
    checked = 0
    worst = 0.0
    for m in run.measurements[:30000]:
        f.process(m)
        for _, P, _, _ in f.hypotheses():
            worst = max(worst, float(np.max(np.abs(P - P.T))))
            checked += 1
    c = f.counters()
    assert c["slip_detections"] >= 1 and c["gnss_step_detections"] + c["gps_gated"] >= 1
    assert c["zupt_updates"] > 0 and checked > 20000
    assert worst == 0.0


def test_a_fix_past_a_bend_re_anchors_a_widened_estimate(db, cfg):
    """The GNSS update is iterated in the arc length (docs/filter.md, Updates): with the arc length known
    only to 300 m, a fix on the far leg of line 1's 90 degree curve (the estimate 1.9 km up the northern
    leg, the fix 600 m further on, past the bend) is accepted and moves the estimate to within metres
    of the fix's place. Linearised once at the estimate, the tangent points north while the fix lies
    ~130 m east of that tangent's line: NIS in the thousands, gated, and the estimate never came back
    (the real Dresden drive, session 9)."""
    f = TrackFilter(db, cfg.replace(use_gyro=False))
    assert f.seed(100.0, 1, 1900.0, 0.0, 1, 300.0, 0.1).outcome == Outcome.INITIALISED
    lat, lon = db.line(1).latlon_at(2500.0)
    upd = f.process(GpsMeas(100.0, float(lat), float(lon), 0.0, 1.0, 1, 12))
    assert upd.outcome == Outcome.ACCEPTED, upd
    est = f.estimate()
    assert abs(est.arc_length_m - 2500.0) < 5.0, est
    assert est.sigma_s_m < 10.0, est


def _spin_world():
    """gnss-10hz world 112 of the generalisation benchmark (as-built truth, 10 Hz GNSS whose correlated
    error is 1.1 m / 34 s): the simulated wheel odometer spins 0.7-1.1 m/s above the truth from 249 to
    253 s into the run, while the train accelerates from 7 to 9.5 m/s."""
    from interface_modules.tracks import database_path
    from tools.bench_generalisation import family_world

    sc, run, meas, cfg = family_world("gnss-10hz", 112, 300.0)
    return database_path(sc), meas, run.truth, cfg


def _through_spin(path, meas, truth, cfg):
    """imu_faults, and the largest |v - v_true| [m/s] from 249 to 253.5 s."""
    t0 = truth["epoch"][0]
    worst = 0.0
    with TrackDatabase.open(path) as track:
        f = TrackFilter(track, cfg)
        for m in meas:
            f.process(m)
            if 249.0 <= m.t_s - t0 <= 253.5:
                v = f.state()[0][1]  # x[V], the speed [m/s]
                worst = max(worst, abs(v - float(np.interp(m.t_s, truth["epoch"], truth["speed"]))))
        return f.counters()["imu_faults"], worst


def test_a_10hz_receiver_s_fixes_vote_on_a_slip_as_one_fix_a_second():
    """A declared slip is arbitrated by GNSS; fixes closer than cusum_min_interval_s share their
    correlated error, so each votes dt / 1 s of an independent fix (kernels.gps_evidence_weight). Counted
    one by one, this world's 10 Hz fixes, their correlated error along the track, declared the
    accelerometer faulty 1.5 s into a wheel spin; the estimate then took the spinning odometer's speed
    (1 m/s too fast) and ended 4.9 m off with sigma 0.7 m. That was under the moment fit of the GNSS error
    model, the default until session 35; under the maximum-likelihood one (the default since) the fixes
    counted one by one do not declare it here, so the counterfactual is run with the moment fit, and the
    spin is bridged under both."""
    path, meas, truth, cfg = _spin_world()
    t0 = truth["epoch"][0]
    odo = [(m.t_s - t0, m.speed_mps - float(np.interp(m.t_s, truth["epoch"], truth["speed"])))
           for m in meas if isinstance(m, OdoMeas)]
    assert min(d for t, d in odo if 249.2 <= t <= 253.0) > 0.5  # the premise: the wheels spin
    assert cfg.gps_adaptive_ml  # the benchmark's datasheet presets
    for ml in (True, False):
        faults, worst = _through_spin(path, meas, truth, cfg.replace(gps_adaptive_ml=ml))
        assert faults == 0 and worst < 0.1, ml  # the accelerometer bridges the spin
    moments = cfg.replace(gps_adaptive_ml=False, cusum_min_interval_s=0.0)  # one by one
    faults, worst = _through_spin(path, meas, truth, moments)
    assert faults >= 1 and worst > 0.5
