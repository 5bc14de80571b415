"""SFA filter: configuration, presets, public API, nominal accuracy and consistency, lines and junctions,
sense of travel, covariance hygiene."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from interface_modules.presets import GPS_PRESETS, IMU_PRESETS, ODOMETER_PRESETS
from sfa import batch
from sfa import layout as L
from sfa.config import FilterConfig
from sfa.errors import FilterConfigError, FilterStateError, MeasurementTypeError
from sfa.filter import TrackFilter
from sfa.layout import COUNTER_NAMES, FilterStatus, Outcome
from sfa.measurements import InitMeas, OdoMeas
from sfa.presets import filter_config_for
from sfa.synthetic import Profile, build_track_db, generate
from track_db import TrackDatabase

IMU = IMU_PRESETS["mems-train"]
ODO = ODOMETER_PRESETS["wheel-odometer"]
GPS = GPS_PRESETS["standalone"]


@pytest.fixture(scope="module")
def db(tmp_path_factory):
    path = build_track_db(tmp_path_factory.mktemp("track") / "core.db")
    with TrackDatabase.open(path) as database:
        yield database


def test_config_validation_and_gate_units():
    cfg = FilterConfig()
    assert cfg.gate_nis(0.9999, 2) == pytest.approx(-2.0 * math.log(1e-4))  # chi2(2) quantile in closed form
    assert cfg.gate_nis(0.9973, 1) == pytest.approx(9.0, abs=0.01)  # 3 sigma, 1 dof
    assert cfg.interval_z() == pytest.approx(1.959964, abs=1e-6)
    with pytest.raises(FilterConfigError, match="gate_prob_gps"):
        FilterConfig(gate_prob_gps=1.0)
    # the fault interval: z(0.99) / z(0.95) in the compiled config; never narrower than the nominal one
    assert FilterConfig().to_array()[L.K_FAULT_SIGMA_SCALE] == pytest.approx(2.575829 / 1.959964, abs=1e-6)
    assert FilterConfig(fault_confidence=0.95).to_array()[L.K_FAULT_SIGMA_SCALE] == 1.0
    with pytest.raises(FilterConfigError, match="fault_confidence"):
        FilterConfig(fault_confidence=0.9)
    with pytest.raises(FilterConfigError, match="fault_confidence"):
        FilterConfig(fault_confidence=1.0)
    with pytest.raises(FilterConfigError, match="gps_white_sigma_m"):
        FilterConfig(gps_white_sigma_m=-1.0)
    with pytest.raises(FilterConfigError, match="finite"):
        FilterConfig(gps_gm_tau_s=math.nan)
    with pytest.raises(FilterConfigError, match="unknown FilterConfig"):
        cfg.replace(no_such_field=1.0)
    with pytest.raises(FilterConfigError, match="use_gyro"):
        FilterConfig(use_gyro=1)
    for bad in (0, 2.5):
        with pytest.raises(FilterConfigError, match="gyro_average_samples"):
            FilterConfig(gyro_average_samples=bad)


def test_presets_follow_the_simulator_specs():
    cfg = filter_config_for("mems-train", "wheel-odometer", "rtk")
    assert cfg.gps_white_sigma_m == GPS_PRESETS["rtk"].white_sigma_m
    assert cfg.gps_gm_tau_s == GPS_PRESETS["rtk"].gm_tau_s
    assert cfg.gps_nominal_sigma_h_m == GPS_PRESETS["rtk"].reported_sigma_h_m
    assert cfg.init_sigma_odo_scale == ODO.scale_sigma
    assert cfg.accel_bias_rw_mps2_rts == IMU.accel_bias_rw
    assert cfg.init_sigma_accel_bias_mps2 > IMU.accel_bias_sigma  # pitch misalignment folded in
    radar = filter_config_for(odometer="doppler-radar")
    assert radar.init_sigma_odo_scale == ODOMETER_PRESETS["doppler-radar"].scale_sigma
    with pytest.raises(FilterConfigError, match="unknown sensor preset"):
        filter_config_for(gps="galileo-hp")
    assert filter_config_for(confidence=0.99).confidence == 0.99


def test_import_is_light():
    code = ("import sys, sfa, sfa.cli; "
            "print('numba' in sys.modules, 'sfa.kernels' in sys.modules, 'scipy' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.split() == ["False", "False", "False"]


def test_api_before_and_after_initialisation(db):
    f = TrackFilter(db, filter_config_for())
    e = f.estimate()
    assert e.status == FilterStatus.INITIALISING and e.reasons == ("not_initialised",) and e.line_id is None
    assert set(f.counters()) == set(COUNTER_NAMES) and not any(f.counters().values())
    with pytest.raises(FilterStateError):
        f.state()
    with pytest.raises(MeasurementTypeError):
        f.process("IMU 1 2 3")
    with pytest.raises(FilterStateError):
        TrackFilter(db, {"gate_prob_gps": 0.99})
    u = f.process(InitMeas(10.0, 100.0, 0.0, None, direction=1))
    assert u.outcome == Outcome.INITIALISED
    e = f.estimate()
    assert e.line_id == db.default_line_id and e.status == FilterStatus.NOMINAL and e.direction == 1
    assert e.interval_low_m < 100.0 < e.interval_high_m
    assert e.interval_high_m - 100.0 == pytest.approx(1.959964 * e.sigma_s_m, rel=1e-6)
    lat, lon = db.line(db.default_line_id).latlon_at(100.0)
    assert (e.lat_deg, e.lon_deg) == pytest.approx((float(lat), float(lon)), abs=1e-9)


def test_nominal_accuracy_and_consistency(db):
    """Monte Carlo over 8 seeds on the synthetic network: along-track error and interval coverage."""
    cfg = filter_config_for()
    errs, inside = [], []
    for seed in range(8):
        run = generate(db, 1, 400.0, IMU, ODO, GPS, seed=100 + seed)
        res = batch.replay(db, cfg, run.measurements)
        idx = np.clip(np.round((res.epoch_s - run.t_s[0]) * IMU.rate_hz).astype(int), 0, run.t_s.size - 1)
        e = res.arc_length_m - run.s_m[idx]
        errs.append(np.abs(e))
        inside.append(np.abs(e) <= 1.96 * res.sigma_s_m)
        assert np.all(res.status[1:] != FilterStatus.LOST)
        x, P = res.x, res.P
        np.linalg.cholesky(P)
        assert np.all(np.isfinite(x))
        assert abs(x[3] - run.odo_scale) < 3e-3  # odometer scale calibrated
    a = np.concatenate(errs)
    coverage = float(np.mean(np.concatenate(inside)))
    assert np.percentile(a, 95) < 1.5
    # never over-confident; the synthetic generator has no misalignment or scale errors while the
    # preset models them, so the interval may be wider than needed here (the 93-98 % calibration is
    # measured on the simulator, whose error model is complete: benchmarks/bench_filter_accuracy.py)
    assert coverage >= 0.90


def test_junction_keeps_the_right_line(db):
    """Train on the branch (line 2), initialised on the default line 1 before the junction."""
    cfg = filter_config_for()
    prof = Profile(segments=((15.0, 0.8), (200.0, 0.0)), v0_mps=0.0, s0_m=600.0)
    run = generate(db, 2, 160.0, IMU, ODO, GPS, seed=31, profile=prof)
    ms = [InitMeas(run.measurements[0].t_s, run.measurements[0].arc_length_m, 0.0, 1)] + run.measurements[1:]
    f = TrackFilter(db, cfg)
    lines = []
    for m in ms:
        f.process(m)
        if isinstance(m, OdoMeas):
            lines.append((m.t_s, f.estimate()))
    junction_s = db.junctions()[0].s_b_m
    after = [(t, e) for t, e in lines if e.epoch_s > run.t_s[0] + 10 and
             run.s_m[int(round((t - run.t_s[0]) * 100))] > junction_s + 60.0]
    assert after and all(e.line_id == 2 for _, e in after)
    for t, e in after:
        s_true = run.s_m[int(round((t - run.t_s[0]) * 100))]
        assert abs(e.arc_length_m - s_true) < 3.0
    # the same start on the main line stays on the main line
    run1 = generate(db, 1, 160.0, IMU, ODO, GPS, seed=31, profile=prof)
    f1 = TrackFilter(db, cfg)
    for m in run1.measurements:
        f1.process(m)
    assert f1.estimate().line_id == 1 and abs(f1.estimate().arc_length_m - run1.s_m[-1]) < 3.0


def test_unknown_direction_is_resolved_by_gnss(db):
    cfg = filter_config_for()
    run = generate(db, 1, 60.0, IMU, ODO, GPS, seed=32)
    first = run.measurements[0]
    ms = [InitMeas(first.t_s, first.arc_length_m, first.speed_mps, first.line_id, direction=None)]
    f = TrackFilter(db, cfg)
    assert f.process(ms[0]).outcome == Outcome.INITIALISED
    assert f.estimate().hypotheses == 2 and f.estimate().direction == 0
    for m in run.measurements[1:]:
        f.process(m)
    e = f.estimate()
    assert e.direction == 1 and e.hypotheses == 1 and abs(e.arc_length_m - run.s_m[-1]) < 2.0


def test_reinitialisation_keeps_calibration(db):
    cfg = filter_config_for()
    run = generate(db, 1, 200.0, IMU, ODO, GPS, seed=33)
    f = TrackFilter(db, cfg)
    for m in run.measurements:
        f.process(m)
    x0, P0 = f.state()
    t = run.measurements[-1].t_s
    assert f.process(InitMeas(t, 5000.0, 3.0, 1, direction=1)).outcome == Outcome.INITIALISED
    x1, P1 = f.state()
    assert x1[0] == 5000.0 and x1[1] == 3.0
    assert x1[3] == x0[3] and P1[3, 3] == P0[3, 3]  # odometer scale kept
    assert f.counters()["initialisations"] == 2


def test_gnss_projection_baseline_keeps_to_the_pass_it_is_on(tmp_path):
    """An out-and-back line passes every place twice: the baseline must stay on the current pass."""
    import math

    from sfa.baselines import gnss_projection
    from sfa.measurements import GpsMeas, InitMeas
    from track_db import TrackDatabase
    from track_db.build import LineGeometry, create_database

    lat0, lon0 = 50.93, 11.58
    east = np.concatenate([np.arange(0.0, 1000.0, 10.0), np.arange(1000.0, -1.0, -10.0)])
    north = np.concatenate([np.zeros(100), np.full(101, 30.0)])  # back along a parallel 30 m away
    lat = lat0 + np.degrees(north / 6378137.0)
    lon = lon0 + np.degrees(east / (6378137.0 * math.cos(math.radians(lat0))))
    db = TrackDatabase.open(create_database(tmp_path / "ob.db", [LineGeometry("out and back", lat, lon)]))
    line = db.line(1)
    # a train on the way back at s ~ 1500 m (east ~ 470 m), its fixes 20 m off towards the outward leg
    s_true = np.arange(1500.0, 1600.0, 10.0)
    meas = [InitMeas(0.0, 1500.0, 10.0, 1)]
    for k, s in enumerate(s_true):
        la, lo = line.latlon_at(float(s))
        meas.append(GpsMeas(1.0 + k, la - np.degrees(20.0 / 6378137.0), lo, 0.0, 1.5, 1, 10))
    res = gnss_projection(db, meas)
    got = res.arc_length_m[1:]
    assert np.all(np.abs(got - s_true) < 2.0), got  # the nearest point overall would be s ~ 500 m


def test_reading_the_estimate_never_changes_the_arithmetic(db):
    """The covariance is propagated in blocks and synced only by the kernels' own steps: a filter read
    after every message (the listener) and one read only at the end (the batch replay) are bit-identical,
    and the pending-block sigma the estimate reports equals the synced covariance's."""
    from sfa import kernels as K
    from sfa import layout as L

    cfg = filter_config_for()
    run = generate(db, 1, 120.0, IMU, ODO, GPS, seed=7)
    read, quiet = TrackFilter(db, cfg), TrackFilter(db, cfg)
    pending_seen = 0
    for m in run.measurements:
        read.process(m)
        quiet.process(m)
        if not read.initialised:
            continue
        est = read.estimate()
        _, P, aux, _ = read.hypotheses()[0]  # the reported one (copies)
        x_now, p_now = read.state()  # a synced copy
        if aux[L.A_PB_H] > 0.0:
            pending_seen += 1
            pss, pvv = K.pending_var_s(P, aux), K.pending_var_v(P, aux)
            assert pss == pytest.approx(p_now[0, 0], rel=1e-12)
            assert pvv == pytest.approx(p_now[1, 1], rel=1e-12)
        own = math.sqrt(p_now[0, 0])
        if est.hypotheses == 1:
            assert est.sigma_s_m == pytest.approx(own, rel=1e-12)
        else:  # the interval holds the mixture of the line's hypotheses: never below the reported one's
            assert est.sigma_s_m >= own * (1.0 - 1e-12)
    assert pending_seen > 1000  # most IMU samples leave a pending block
    xa, pa = read.state()
    xb, pb = quiet.state()
    assert np.array_equal(xa, xb) and np.array_equal(pa, pb)
    res = batch.replay(db, cfg, run.measurements)
    # the batch path: the same kernels and block boundaries (compiled inside its loop: 1e-9, as documented)
    assert res.arc_length_m[-1] == pytest.approx(xa[0], abs=1e-9)
    np.testing.assert_allclose(res.P, pa, rtol=1e-9, atol=1e-15)


def test_hypotheses_on_routes_sharing_one_track_are_duplicates():
    """On the Jena network several routes share a track with the same arc length: hypotheses on them
    cannot be told apart (their likelihoods stay equal), so the prune (sfa.bank.same_track) keeps one;
    a branch that parts within two junction windows is not a duplicate (the geometry below is the
    bundled OSM data)."""
    from interface_modules.scenario import load_scenario
    from interface_modules.tracks import database_path
    from sfa import layout as L
    from sfa.bank import HypothesisBank

    with TrackDatabase.open(database_path(load_scenario("tram-urban"))) as jena:
        f = TrackFilter(jena, filter_config_for())
        bank = HypothesisBank(f.config.max_hypotheses)
        cfg = f.config.to_array()
        used: list[int] = []

        def hyp(line_id, s_m, direction=1.0):
            h = bank.new_slot(used)
            used.append(h)
            bank.place(h, f.line_arrays(line_id), frozenset())
            bank.X[h, L.S] = s_m
            bank.AUX[h, L.A_DIR] = direction
            return h

        def same(g, h):
            return bank.same_track(g, h, cfg)

        shared = (hyp(2, 2418.0), hyp(10, 2418.0), hyp(17, 2418.0))  # one track, measured 2026-11-22
        assert same(shared[0], shared[1]) and same(shared[0], shared[2])
        assert not same(shared[0], hyp(10, 2418.0, -1.0))  # the other way along it
        assert not same(hyp(2, 2351.4), hyp(1, 2350.8))  # line 1 parts from line 2 ahead
        assert not same(shared[0], hyp(2, 2420.0))  # same line: 2 m apart
        assert same(shared[0], hyp(2, 2418.5))  # same line, within 1 m


def _roll_cos_by_angles(f_lat, f_up, fy, fz):
    """The roll compensation's definition: phi = atan2(f_up, f_lat) - atan2(fz, fy), used when the
    force is plausible and |phi| <= 0.35 rad (the kernel gets cos(phi) without the two atan2)."""
    nb, nl = math.hypot(fy, fz), math.hypot(f_lat, f_up)
    if not 0.8 * nl <= nb <= 1.25 * nl:
        return 1.0
    phi = math.atan2(f_up, f_lat) - math.atan2(fz, fy)
    return math.cos(phi) if abs(phi) <= 0.35 else 1.0


def test_roll_cos_equals_the_angle_difference_it_replaces():
    from sfa import kernels as K

    rng = np.random.default_rng(7)
    g = 9.80665
    compensated = 0
    for _ in range(20000):
        f_lat = rng.normal(0.0, 3.0)
        level = complex(f_lat, -g)
        roll = rng.uniform(-0.5, 0.5)  # inside and outside the 0.35 rad limit
        body = level * rng.uniform(0.7, 1.3) * complex(math.cos(-roll), math.sin(-roll))
        want = _roll_cos_by_angles(f_lat, -g, body.real, body.imag)
        got = K.roll_cos(f_lat, -g, body.real, body.imag)
        if abs(abs(roll) - 0.35) > 1e-9:  # the limit itself: rounding decides either way
            assert got == pytest.approx(want, abs=1e-14), (f_lat, roll, body)
        compensated += got != 1.0
    assert 5000 < compensated < 20000  # both branches taken
    # across atan2's branch cut (both vectors near the negative x axis, on either side of it) the angle
    # difference is near 2 pi: no compensation, as the definition says, though the roll is small
    assert _roll_cos_by_angles(-10.0, 0.01, -10.0, -0.01) == 1.0
    assert K.roll_cos(-10.0, 0.01, -10.0, -0.01) == 1.0
    same_side = _roll_cos_by_angles(-10.0, 0.01, -10.0, 0.02)
    assert same_side != 1.0 and K.roll_cos(-10.0, 0.01, -10.0, 0.02) == pytest.approx(same_side)
    # no force at all, NaN: no compensation
    assert K.roll_cos(0.0, 0.0, 0.0, 0.0) == 1.0
    assert K.roll_cos(1.0, -g, math.nan, -g) == 1.0


def test_preset_families_select_the_builders():
    """``[filter] presets`` picks the builder; an unknown family is one error naming the value."""
    from listener.config import ConfigError, config_from_dict
    from sfa.presets import config_for, datasheet_config_for

    assert config_for("model-matched", gps="rtk") == filter_config_for(gps="rtk")
    assert config_for("datasheet", gps="rtk", use_gyro=True) == datasheet_config_for(gps="rtk", use_gyro=True)
    with pytest.raises(FilterConfigError, match="unknown preset family 'simulator'"):
        config_for("simulator")
    assert config_from_dict({"filter": {"presets": "datasheet"}}).filter.presets == "datasheet"
    with pytest.raises(ConfigError, match="filter.presets: must be model-matched or datasheet, got 'x'"):
        config_from_dict({"filter": {"presets": "x"}})
