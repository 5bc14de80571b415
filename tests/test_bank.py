"""sfa.bank: the hypothesis bank's compiled loop is TrackFilter's, over one measurement or a run of them."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from interface_modules.presets import GPS_PRESETS, IMU_PRESETS, ODOMETER_PRESETS
from sfa import batch
from sfa import layout as L
from sfa.bank import (
    I_JHI,
    I_JLO,
    NEF,
    NEI,
    NOST,
    O_LAST,
    O_ROW,
    HypothesisBank,
    RunOutput,
    score,
    score_log_s,
)
from sfa.filter import TrackFilter
from sfa.measurements import InitMeas
from sfa.presets import filter_config_for
from sfa.synthetic import build_track_db, generate
from sfa.track_arrays import TrackArrays
from track_db import TrackDatabase

IMU = IMU_PRESETS["mems-train"]
ODO = ODOMETER_PRESETS["wheel-odometer"]
GPS = GPS_PRESETS["standalone"]


@pytest.fixture(scope="module")
def db(tmp_path_factory):
    path = build_track_db(tmp_path_factory.mktemp("track") / "bank.db")
    with TrackDatabase.open(path) as database:
        yield database


def _output_rule(estimates):
    """(epoch, s, sigma_s) of the estimates the listener sends: finite, not older than the last sent, not
    the same epoch and arc length (no clock here: nothing is stale)."""
    sent = []
    last = (-math.inf, math.nan)
    for e in estimates:
        if not (math.isfinite(e.epoch_s) and math.isfinite(e.arc_length_m)):
            continue
        if e.epoch_s >= last[0] and not (e.epoch_s == last[0] and e.arc_length_m == last[1]):
            last = (e.epoch_s, e.arc_length_m)
            sent.append((*last, e.sigma_s_m))
    return np.array(sent)


def _both_paths(db, cfg, meas, monkeypatch):
    """TrackFilter.process per measurement, and TrackFilter.run (the replay's path) over the packed
    measurements, checked equal bit for bit: outcomes, NIS, sent estimates, final hypotheses and
    counters. Returns (the per-message filter, the most lines with hypotheses at once, the rows after
    which the compiled loop stopped for a spawn)."""
    one = TrackFilter(db, cfg)
    upd = [one.process(m) for m in [meas[0]]]
    ests = [one.estimate()]
    most = 1
    for m in meas[1:]:
        upd.append(one.process(m))
        ests.append(one.estimate())
        most = max(most, len({h[3] for h in one.hypotheses()}))

    packed = batch.pack(meas, db)
    n = len(meas)
    out = RunOutput(np.zeros(n, dtype=np.int64), np.zeros(n), np.zeros((NEF, n)),
                    np.zeros((NEI, n), dtype=np.int64), np.full(n, -math.inf), packed.t_s.copy(),
                    np.array([-math.inf, math.nan]), np.zeros(NOST, dtype=np.int64), 0)
    out.ost[O_LAST] = -1
    monkeypatch.setattr(HypothesisBank, "MAX_SPAWN_SETS", 0)  # compact after every spawn: only indices change
    two = TrackFilter(db, cfg)
    i = 0
    handed = branched = 0
    while i < n:  # bounded: every pass moves i on by at least one row
        j, b = two.run(packed.kind, packed.t_s, packed.values, i, out)
        branched += b
        if j >= n:
            break
        u = two.process(meas[j])
        handed += 1
        out.u_out[j] = int(u.outcome)
        out.u_nis[j] = math.nan if u.nis is None else u.nis
        two.emit(j, out)
        i = j + 1
    assert handed < 10  # the GROUND TRUTH goes through process(), the rest ran compiled
    assert out.u_out.tolist() == [int(u.outcome) for u in upd]
    want_nis = np.array([math.nan if u.nis is None else u.nis for u in upd])
    np.testing.assert_array_equal(out.u_nis, want_nis)
    sent = _output_rule(ests)
    rows = int(out.ost[O_ROW])
    assert rows == sent.shape[0] > 1000
    np.testing.assert_array_equal(out.e_f[0, :rows], sent[:, 0])
    np.testing.assert_array_equal(out.e_f[1, :rows], sent[:, 1])
    np.testing.assert_array_equal(out.e_f[4, :rows], sent[:, 2])  # the interval, hypotheses spanned
    for (xa, pa, aa, la), (xb, pb, ab, lb) in zip(one.hypotheses(), two.hypotheses(), strict=True):
        assert la == lb
        np.testing.assert_array_equal(xa, xb)
        np.testing.assert_array_equal(pa, pb)
        np.testing.assert_array_equal(aa, ab)
    assert one.counters() == two.counters()
    return one, most, branched


def test_run_over_packed_measurements_equals_process_one_by_one(db, monkeypatch):
    """TrackFilter.run and TrackFilter.process give the same, bit for bit, through the junction where
    line 2 leaves line 1 (branches spawned, hypotheses on two lines, standstill reversals)."""
    run = generate(db, 1, 240.0, IMU, ODO, GPS, seed=11)
    _, most, branched = _both_paths(db, filter_config_for(), run.measurements, monkeypatch)
    assert most == 2  # the run did keep hypotheses on both lines at some time
    assert branched >= 1


def test_a_filter_on_the_wrong_branch_is_relocalised_the_same_on_both_paths(db, monkeypatch):
    """The train runs on line 1; the GROUND TRUTH puts the filter on line 2, which shares line 1's
    first kilometre, and no branch is spawned where they part (junction window 0): the lone line-2
    hypothesis rejects every fix once the lines have parted. After reacquire_s of rejections that
    disagree along line 2 it is relocalised onto line 1 (TrackFilter._relocalise), where the train
    is; the compiled loop stops at the same measurement and both paths give the same, bit for bit."""
    run = generate(db, 1, 240.0, IMU, ODO, GPS, seed=11)
    meas = list(run.measurements)
    assert isinstance(meas[0], InitMeas) and meas[0].line_id == 1
    meas[0] = dataclasses.replace(meas[0], line_id=2)
    cfg = filter_config_for().replace(junction_window_m=0.0)
    one, _, stops = _both_paths(db, cfg, meas, monkeypatch)
    assert stops >= 1
    assert one.counters()["relocalisations"] == 1
    est = one.estimate()
    assert est.line_id == 1
    truth = float(np.interp(est.epoch_s, run.t_s, run.s_m))
    assert abs(est.arc_length_m - truth) < 5.0, (est.arc_length_m, truth)
    # the same run without relocalisation stays on line 2
    alone = TrackFilter(db, cfg.replace(relocalise=False))
    for m in meas:  # bounded: one 240 s run
        alone.process(m)
    assert alone.estimate().line_id == 2
    assert alone.counters()["relocalisations"] == 0


def test_a_nis_that_is_not_a_number_scores_as_the_cap():
    bank = HypothesisBank(2)
    bank.set_live([0, 1], 0)
    bank.AUX[0, L.A_LAST_NIS_ODO] = math.nan
    bank.AUX[1, L.A_LAST_NIS_ODO] = 3.0
    bank.AUX[:2, L.A_LOGLIK] = -1.0
    score(bank.order, 2, bank.AUX, L.A_LAST_NIS_ODO, 50.0, 1.0, 0.0, 1.0)
    assert bank.AUX[0, L.A_LOGLIK] == -1.0 - 25.0
    assert bank.AUX[1, L.A_LOGLIK] == -1.0 - 1.5
    score(bank.order, 2, bank.AUX, L.A_LAST_NIS_ODO, 50.0, 0.1, 0.0, 1.0)  # a tenth of an independent fix
    assert bank.AUX[0, L.A_LOGLIK] == -1.0 - 25.0 - 2.5
    assert bank.AUX[1, L.A_LOGLIK] == -1.0 - 1.5 - 0.15


def test_a_gyro_window_scores_by_its_normal_log_density():
    """NIS and log S together move the score by the normal's log-density: the hypothesis that predicts
    the wider spread gains nothing by it (scipy's norm.logpdf). A window that shares its curvature error
    with n_c others (share s0 / S = 1 / n_c) counts its log S once in n_c, as its NIS already does."""
    from scipy.stats import norm

    bank = HypothesisBank(2)
    bank.set_live([0, 1], 0)
    y, s_narrow, s_wide = 0.02, 0.02 ** 2, 0.05 ** 2  # the residual [rad/s], each hypothesis's S
    for h, sm in ((0, s_narrow), (1, s_wide)):
        bank.AUX[h, L.A_LAST_NIS_GYRO] = y * y / sm
        bank.AUX[h, L.A_LAST_S_GYRO] = sm
    score(bank.order, 2, bank.AUX, L.A_LAST_NIS_GYRO, 50.0, 1.0, 0.0, 1.0)
    assert bank.AUX[1, L.A_LOGLIK] > bank.AUX[0, L.A_LOGLIK]  # NIS alone: the wide one leads
    score_log_s(bank.order, 2, bank.AUX, L.A_LAST_S_GYRO, 1.0)
    lead = bank.AUX[0, L.A_LOGLIK] - bank.AUX[1, L.A_LOGLIK]
    want = norm.logpdf(y, 0.0, math.sqrt(s_narrow)) - norm.logpdf(y, 0.0, math.sqrt(s_wide))
    assert lead == pytest.approx(want, rel=1e-12)
    assert lead > 0.0
    bank.AUX[:2, L.A_LOGLIK] = 0.0
    score_log_s(bank.order, 2, bank.AUX, L.A_LAST_S_GYRO, 0.25)  # one of n_c = 4 windows
    lead = bank.AUX[0, L.A_LOGLIK] - bank.AUX[1, L.A_LOGLIK]
    assert lead == pytest.approx(0.25 * math.log(s_wide / s_narrow) / 2.0)


def _slot(bank, slot, line, s, sigma, t, loglik=0.0):
    """Slot ``slot`` initialised on ``line`` at arc length s with 1-sigma ``sigma`` and score
    ``loglik``, every sensor fresh at t."""
    bank.place(slot, line, frozenset())
    bank.X[slot, L.S] = s
    bank.PP[slot, L.S, L.S] = sigma * sigma
    bank.AUX[slot, L.A_INIT] = 1.0
    bank.AUX[slot, L.A_LOGLIK] = loglik
    for a in (L.A_T_STATE, L.A_T_IMU, L.A_T_ODO, L.A_T_GPS):
        bank.AUX[slot, a] = t
    bank.AUX[slot, L.A_IMU_FAULT_T] = -math.inf


def _mixture_mass(half_width, s_r, hyps):
    """scipy's mass of the mixture ((s, sigma, loglik), ...) within s_r +- half_width."""
    from scipy.stats import norm

    w = np.exp(np.array([h[2] for h in hyps]) - max(h[2] for h in hyps))
    w /= w.sum()
    return sum(wi * (norm.cdf(s_r + half_width, s, sg) - norm.cdf(s_r - half_width, s, sg))
               for wi, (s, sg, _) in zip(w, hyps, strict=True))


def test_the_interval_holds_the_confidence_of_the_reported_line_s_hypotheses():
    """The reported interval s_r +- z sigma is the smallest that holds 95 % of the mixture of the live
    hypotheses on the reported line (each N(s_h, sigma_h^2), weighted by exp(score)): it spans a
    hypothesis that holds a share, barely widens for one at the reversal prior's 1 %, ignores another
    line's, and the status follows the widened sigma."""
    cfg = filter_config_for().to_array()
    z = cfg[L.K_Z_INTERVAL]
    a = TrackArrays(1, 1000.0, np.array([0.0, 1000.0]), np.array([0.0, 1000.0]), np.zeros(2), np.zeros(2),
                    np.zeros(2))
    b = TrackArrays(2, 1000.0, np.array([0.0, 1000.0]), np.zeros(2), np.array([0.0, 1000.0]), np.zeros(2),
                    np.zeros(2))
    bank = HypothesisBank(4)
    t = 1000.0
    _slot(bank, 0, a, 100.0, 0.1, t)
    bank.set_live([0], 0)
    assert bank.status(cfg, t) == (1, 0, pytest.approx(0.1, rel=1e-12))  # alone: its own
    for ll, share in ((0.0, "equal"), (-2.0, "12 %"), (4.0, "98 %: the report's hysteresis")):
        _slot(bank, 1, a, 106.0, 0.2, t, ll)  # the mirrored sense of travel, 6 m on
        bank.set_live([0, 1], 0)
        code, bits, sigma = bank.status(cfg, t)
        hyps = ((100.0, 0.1, 0.0), (106.0, 0.2, ll))
        assert _mixture_mass(z * sigma, 100.0, hyps) == pytest.approx(0.95, abs=1e-6), share
        assert _mixture_mass(0.999 * z * sigma, 100.0, hyps) < 0.95, share  # the smallest
        assert 6.0 < z * sigma < 6.0 + z * 0.2 and (code, bits) == (1, 0), share
    _slot(bank, 1, a, 106.0, 0.2, t, -4.6)  # a reversal at its prior, 1 %: the reported one's 96 %
    inside = 0.95 * (1.0 + math.exp(-4.6))  # the mass the reported one must hold within its interval
    assert bank.status(cfg, t)[2] == pytest.approx(0.1 * norm_ppf(0.5 + 0.5 * inside) / z, rel=1e-6)
    _slot(bank, 1, a, 80.0, 0.2, t)  # 20 m behind, an equal share: sigma above degraded_sigma_m (5 m)
    _slot(bank, 2, b, 900.0, 0.1, t, 50.0)  # another line (other arc lengths), however likely: not counted
    bank.set_live([0, 1, 2], 0)
    code, bits, sigma = bank.status(cfg, t)
    hyps = ((100.0, 0.1, 0.0), (80.0, 0.2, 0.0))
    assert _mixture_mass(z * sigma, 100.0, hyps) == pytest.approx(0.95, abs=1e-6)
    assert sigma > 5.0 and (code, bits) == (2, L.R_SIGMA_HIGH)
    bank.set_live([0, 2], 0)  # pruned: the interval is the reported one's own again
    assert bank.status(cfg, t) == (1, 0, pytest.approx(0.1, rel=1e-12))


def norm_ppf(p: float) -> float:
    from scipy.stats import norm

    return float(norm.ppf(p))


def test_a_reversal_kept_through_a_gnss_outage_does_not_blow_the_interval_up():
    """Long-outage seed 4: the tram stops inside the 700 m outage, the mirrored sense of travel is kept
    at its prior (1:100) with nothing to tell it apart, and the two part at twice the speed. Spanning
    every live hypothesis made the half-width 755 m (status LOST) by the end of the run; weighted, the
    interval stays the reported one's within its share and still holds the truth."""
    from interface_modules.tracks import database_path
    from tools.bench_generalisation import family_world

    sc, run, meas, cfg = family_world("long-outage", 4, 300.0)
    te, ts = run.truth["epoch"], run.truth["arc_length"]
    z = cfg.interval_z()
    widest, worst, both = 0.0, 0.0, 0
    with TrackDatabase.open(database_path(sc)) as track:
        f = TrackFilter(track, cfg)
        for m in meas:  # bounded: the world's 300 s of measurements
            f.process(m)
            if m.t_s - te[0] < 240.0:
                continue
            e = f.estimate()
            lines = [h[3] for h in f.hypotheses()]
            both += lines.count(e.line_id) > 1
            err = abs(e.arc_length_m - float(np.interp(e.epoch_s, te, ts)))
            widest = max(widest, z * e.sigma_s_m)
            worst = max(worst, err / (z * e.sigma_s_m))
    assert both > 1000  # the reversal was kept on the line through the outage
    assert widest < 20.0, widest
    assert worst <= 1.0, worst


def test_the_bank_grows_when_spawning_needs_room():
    bank = HypothesisBank(1)
    cap = bank.cap
    bank.X[0, L.S] = 42.0
    bank.set_live([0], 0)
    taken: list[int] = []
    for _ in range(cap + 3):
        taken.append(bank.new_slot(taken))
    assert len(set(taken)) == cap + 3 and 0 not in taken
    assert bank.cap > cap and bank.X[0, L.S] == 42.0 and bank.slots() == [0]


def test_compact_keeps_only_the_junction_sets_of_live_slots():
    """A lineage that passes junction after junction interns a new set each time; compact() forgets the
    sets no live slot has, and a live slot keeps its junctions still to branch at."""
    bank = HypothesisBank(2)
    line = TrackArrays(7, 100.0, np.array([0.0, 100.0]), np.array([0.0, 100.0]), np.zeros(2), np.zeros(2),
                       np.zeros(2))
    bank.junction_s = lambda line_id: [(k, 10.0 * k) for k in range(8)]
    bank.place(0, line, frozenset())
    bank.set_live([0], 0)
    for k in range(1, 6):
        bank.set_spawned(0, frozenset(range(k)))  # branched at junctions 0 .. k - 1
    assert len(bank.spawn_sets) == 6 and bank.JS.size > 3
    bank.MAX_SPAWN_SETS = 2
    bank.compact()
    assert bank.spawn_sets == [frozenset(), frozenset(range(5))] and bank.spawned(0) == frozenset(range(5))
    lo, hi = int(bank.IDX[I_JLO, 0]), int(bank.IDX[I_JHI, 0])
    assert bank.JS.tolist() == bank.JS[lo:hi].tolist() == [50.0, 60.0, 70.0]


def _reversal_run():
    """The Jena tram (as-built path, actual sensor errors of the shipped scenario) from Lobeda-Ost to
    Schlegelstraße, a cab change there, and back to 300 m."""
    import dataclasses

    from interface_modules.offline import generate as sim_generate
    from interface_modules.scenario import JourneyPoint, load_scenario
    from tools.bench_replay import load_benchmark_module

    sc = load_scenario("tram-urban")
    points = (JourneyPoint(153.0, name="A", departure_s=10.0),
              JourneyPoint(535.4, name="B", arrival_s=70.0, departure_s=90.0, dwell_s=20.0),
              JourneyPoint(300.0, name="C", arrival_s=130.0, departure_s=140.0, dwell_s=5.0))
    sc = dataclasses.replace(sc.with_overrides(journey=points), max_duration_s=150.0)
    run = sim_generate(sc, 3)
    acc = load_benchmark_module("bench_filter_accuracy")
    return sc, run, acc.to_measurements(run.messages())


@pytest.mark.parametrize("prior", [0.0, 4.6])
def test_a_real_reversal_is_reported_at_the_first_fix_whatever_the_reversal_prior(prior):
    """The mirrored copy spawned at the stop starts ``reversal_log_prior`` behind (4.6, the default):
    once the train moves the other way the first GNSS fix puts it far ahead, so the report turns at
    that fix with or without the prior."""
    from interface_modules.tracks import database_path
    from sfa.presets import datasheet_config_for

    sc, run, meas = _reversal_run()
    te, ts, td = run.truth["epoch"], run.truth["arc_length"], run.truth["direction"]
    back = te[np.argmax(td != td[0])]  # the truth turns at the cab change
    cfg = datasheet_config_for(sc.imu.preset, sc.odometer.preset, sc.gps.preset)
    cfg = cfg.replace(reversal_log_prior=prior)
    with TrackDatabase.open(database_path(sc)) as track:
        f = TrackFilter(track, cfg)
        turned, worst = None, 0.0
        for m in meas:
            f.process(m)
            e = f.estimate()
            if turned is None and m.t_s > back and e.direction == -1:
                turned = m.t_s
            if m.t_s > back + 5.0:
                worst = max(worst, abs(e.arc_length_m - float(np.interp(m.t_s, te, ts))))
    assert turned is not None and turned - back < 6.0, (turned, back)
    assert worst < 3.0


def test_a_fix_scores_by_the_student_t_of_its_nis():
    """With dof > 0 a 2-d fix scores -(dof + 2) / 2 log(1 + NIS / dof): scipy's log-density of the NIS
    of a 2-d t (NIS / 2 is F(2, dof)) up to a constant. Session 27's departure fix, NIS 12.31 against
    0.12, moves the score by 6.1 under the normal, by 4.1 (below switch_log_ratio, 4.6) with 4 dof."""
    from scipy.stats import f as fdist

    bank = HypothesisBank(2)
    bank.set_live([0, 1], 0)
    bank.AUX[0, L.A_LAST_NIS_GPS] = 12.31
    bank.AUX[1, L.A_LAST_NIS_GPS] = 0.12
    score(bank.order, 2, bank.AUX, L.A_LAST_NIS_GPS, 50.0, 1.0, 0.0, 2.0)
    assert bank.AUX[1, L.A_LOGLIK] - bank.AUX[0, L.A_LOGLIK] == pytest.approx((12.31 - 0.12) / 2.0)
    bank.AUX[:2, L.A_LOGLIK] = 0.0
    score(bank.order, 2, bank.AUX, L.A_LAST_NIS_GPS, 50.0, 1.0, 4.0, 2.0)
    lead = bank.AUX[1, L.A_LOGLIK] - bank.AUX[0, L.A_LOGLIK]
    want = fdist.logpdf(0.12 / 2.0, 2, 4) - fdist.logpdf(12.31 / 2.0, 2, 4)
    assert lead == pytest.approx(want, rel=1e-12)
    assert 4.0 < lead < filter_config_for().switch_log_ratio
    # the cap bounds a fix's weight under the t as under the normal, and the evidence weight scales it
    bank.AUX[:2, L.A_LOGLIK] = 0.0
    bank.AUX[0, L.A_LAST_NIS_GPS] = 1e6
    score(bank.order, 2, bank.AUX, L.A_LAST_NIS_GPS, 50.0, 0.5, 4.0, 2.0)
    assert bank.AUX[0, L.A_LOGLIK] == pytest.approx(-0.5 * 3.0 * math.log1p(50.0 / 4.0), rel=1e-12)
