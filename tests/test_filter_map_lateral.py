"""The centre line's lateral error in a GNSS fix's R (sfa.kernels.lateral_variance): correlated along the
track over ``track_lateral_corr_length_m``, so the fixes inside one correlation length share one draw of
it and a map offset is not learnt as the receiver's error."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sfa import kernels as K
from sfa import layout as L
from sfa.config import FilterConfig
from sfa.filter import TrackFilter
from sfa.layout import Outcome
from sfa.measurements import GpsMeas, InitMeas, OdoMeas
from sfa.synthetic import build_track_db
from track_db import TrackDatabase


def _variance(speed_mps: float, since_fix_s: float, corr_m: float, sigma_m: float = 1.0) -> float:
    cfg = FilterConfig(track_lateral_sigma_m=sigma_m, track_lateral_corr_length_m=corr_m).to_array()
    x, aux = np.zeros(L.NX), np.zeros(L.NAUX)
    x[L.V] = speed_mps
    aux[L.A_T_GPS] = 100.0
    return K.lateral_variance(x, aux, cfg, 100.0 + since_fix_s)


def test_each_fix_counts_the_share_of_one_draw_it_sees():
    assert _variance(10.0, 0.1, 0.0) == 1.0  # off: independent per fix
    assert _variance(10.0, 0.1, 40.0) == pytest.approx(40.0)  # 40 fixes, 1 m apart, in 40 m
    assert _variance(-10.0, 0.1, 40.0) == pytest.approx(40.0)  # either sense of travel
    assert _variance(2.0, 0.1, 40.0, sigma_m=0.5) == pytest.approx(0.25 * 200.0)
    assert _variance(10.0, 5.0, 40.0) == 1.0  # 50 m since the last fix: a new draw, n_c = 1
    assert _variance(0.0, 0.1, 40.0) == K.LAT_NC_MAX  # a standstill: every fix sees the same offset
    assert _variance(10.0, -0.5, 40.0) == K.LAT_NC_MAX  # an older fix than the last in use: no travel


def test_n_fixes_in_one_length_tell_what_their_mean_does():
    """n_c fixes of white sigma sw inside one length carry 1 / (sw^2 / n_c + sigma_lat^2) of information
    about the receiver's cross-track error: that of their mean, whose map term does not average out."""
    sw, sl, corr, speed, dt = 0.3, 1.0, 40.0, 4.0, 0.1
    n_c = corr / (speed * dt)
    r = sw * sw + _variance(speed, dt, corr, sl)
    assert n_c / r == pytest.approx(1.0 / (sw * sw / n_c + sl * sl))


@pytest.fixture(scope="module")
def db(tmp_path_factory):
    path = build_track_db(tmp_path_factory.mktemp("track") / "lateral.db")
    with TrackDatabase.open(path) as database:
        yield database


def _offset_fix(line, t: float, s: float, offset_m: float) -> GpsMeas:
    """An RTK fix offset_m to the left of the centre line at arc length s (the track as built is there)."""
    te, tn = line.tangent_at(s)
    e, n = line.point_at(s)
    lat, lon = line.frame.to_geodetic(e - tn * offset_m, n + te * offset_m)
    return GpsMeas(t, float(lat), float(lon), 0.0, sigma_h_m=0.02, fix_quality=4)


@pytest.mark.parametrize("corr_m, learnt_at_most, learnt_at_least", [(0.0, None, 0.5), (40.0, 0.05, None)])
def test_a_map_offset_is_not_learnt_as_the_receivers_error(db, corr_m, learnt_at_most, learnt_at_least):
    """A train standing 0.8 m beside the digitised line, RTK fixes at 10 Hz for 60 s: counted as
    independent, the offset goes into the GNSS error state (which turns it along the track in the next
    curve); shared by every fix at the standstill it stays in the map's term."""
    cfg = FilterConfig(gps_gm_sigma_m=0.1, gps_gm_tau_s=600.0, gps_white_sigma_m=0.01,
                       gps_nominal_sigma_h_m=0.02, track_lateral_sigma_m=1.0,
                       track_lateral_corr_length_m=corr_m, use_gyro=False)
    f = TrackFilter(db, cfg)
    line = db.line()
    s0 = 300.0
    assert f.process(InitMeas(0.0, s0, 0.0, line.line_id, direction=1)).outcome == Outcome.INITIALISED
    for k in range(1, 1201):  # 60 s: odometer at 20 Hz, a fix every other sample
        t = k * 0.05
        f.process(OdoMeas(t, 0.0, 0.02))
        if k % 2 == 0:
            f.process(_offset_fix(line, t, s0, 0.8))
    x, _ = f.state()
    learnt = math.hypot(x[L.GE], x[L.GN])
    if learnt_at_most is not None:
        assert learnt <= learnt_at_most, learnt
    if learnt_at_least is not None:
        assert learnt >= learnt_at_least, learnt
    assert abs(f.estimate().arc_length_m - s0) < 0.05
