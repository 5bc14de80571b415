"""Robust single-point solution: exact on noise-free ranges, robust to NLOS biases, height aiding
geometry against pyproj, its error on the real smartLoc pseudoranges, and SFA end to end with it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from listener.config import ListenerConfig
from tools.adapters.evaluate import read_truth, run_pipeline, truth_figures
from tools.adapters.smartloc import SmartLocConfig, convert_smartloc, default_source_dir
from tools.adapters.spp import (
    C_MPS,
    OMEGA_E_RADPS,
    SppConfig,
    enu_rotation,
    radius_at_height_m,
    read_pseudoranges,
    solve_epoch,
)
from tools.errors import ToolError

RX = np.array([3785108.1107158, 899901.49390314, 5037234.4571748])  # smartLoc start (ECEF) [m]


def _geometry(az_el_deg, rx=RX, dist_m=2.2e7):
    rot = enu_rotation(rx)
    sats = []
    for az, el in az_el_deg:
        a, e = math.radians(az), math.radians(el)
        enu = np.array([math.cos(e) * math.sin(a), math.cos(e) * math.cos(a), math.sin(e)])
        sats.append(rx + dist_m * (rot.T @ enu))
    return np.array(sats)


SKY = [(10, 60), (80, 35), (140, 50), (200, 25), (250, 70), (300, 40), (330, 20), (30, 15), (170, 80),
       (280, 18)]
SYSTEM = np.array([1, 1, 1, 1, 1, 4, 4, 4, 4, 4])


def _ranges(sats, rx=RX, clocks=(1234.5, -987.0)):
    geo = np.linalg.norm(sats - rx, axis=1)
    sagnac = OMEGA_E_RADPS * (sats[:, 0] * rx[1] - sats[:, 1] * rx[0]) / C_MPS  # independent of the module
    clk = np.where(SYSTEM == 1, clocks[0], clocks[1])
    return geo + sagnac + clk


def test_noise_free_ranges_give_the_position_exactly():
    sats = _geometry(SKY)
    rho = _ranges(sats)
    cfg = SppConfig(height_aiding_m=None)
    x, w, cov = solve_epoch(rho, np.full(10, 5.0), sats, SYSTEM, np.zeros(3), cfg, robust=False)
    assert np.linalg.norm(x - RX) < 1e-3
    x2, w2, _ = solve_epoch(rho, np.full(10, 5.0), sats, SYSTEM, RX + 50.0, cfg)
    assert np.linalg.norm(x2 - RX) < 1e-3 and np.all(w2 > 0.99)


def test_cauchy_weights_reject_nlos_biases_that_pull_least_squares():
    rng = np.random.default_rng(11)
    sats = _geometry(SKY)
    rho = _ranges(sats) + rng.normal(0.0, 1.0, 10)
    rho[[3, 7]] += 60.0  # two reflected signals, 60 m long
    sigma = np.full(10, 3.0)
    cfg = SppConfig(height_aiding_m=None)
    ls = solve_epoch(rho, sigma, sats, SYSTEM, np.zeros(3), cfg, robust=False)[0]
    rob, w, _ = solve_epoch(rho, sigma, sats, SYSTEM, ls, cfg)
    assert np.linalg.norm(ls - RX) > 10.0
    assert np.linalg.norm(rob - RX) < 3.0
    assert w[3] < 0.1 and w[7] < 0.1 and np.all(np.delete(w, [3, 7]) > 0.5)


def test_height_aiding_radius_matches_pyproj():
    from pyproj import Transformer

    to_ecef = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    to_geo = Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
    for lat, lon, h in ((52.5, 13.37, 40.0), (-33.9, 151.2, 5.0), (0.0, 0.0, 0.0), (70.0, -20.0, 900.0)):
        x = np.array(to_ecef.transform(lon, lat, h + 30.0))  # a point 30 m above the aiding height
        lon2, lat2, _ = to_geo.transform(*x)
        want = np.linalg.norm(to_ecef.transform(lon2, lat2, h))
        assert radius_at_height_m(x, h) == pytest.approx(want, abs=1e-3)


def test_reduced_file_without_pseudoranges_is_a_clear_error(tmp_path):
    p = tmp_path / "in.txt"
    p.write_text("odom3 0 1 0 0 0 0 0 0.0025 0 0 0 0 0\n")
    with pytest.raises(ToolError, match="no pseudorange3 records"):
        read_pseudoranges(p)
    p.write_text("pseudorange3 0 2e7 25 1 2 3 5 1 40\n")
    with pytest.raises(ToolError, match=r"in.txt:1: pseudorange3 record has 9 fields, expected 10"):
        read_pseudoranges(p)


@pytest.fixture(scope="module")
def spp_capture(tmp_path_factory):
    return convert_smartloc(None, tmp_path_factory.mktemp("spp"), SmartLocConfig(gnss_source="spp"))


def test_real_single_point_fixes_have_the_documented_error(spp_capture):
    """Horizontal error of the 1 Hz solutions against the ground truth, measured when written: median
    14.37 m, p95 56.47 m, max 88.27 m over 283 fixes (all epochs solved); bounds ~5 % above."""
    import json

    err = json.loads(spp_capture.metadata.read_text())["gnss"]["error_vs_truth"]
    assert err["fixes"] == 283 and err["with_fix"] == 283
    assert err["horizontal_error_p50_m"] <= 15.1
    assert err["horizontal_error_p95_m"] <= 59.3
    assert err["horizontal_error_max_m"] <= 92.7


def test_bundled_input_is_the_published_file():
    import hashlib

    data = (default_source_dir() / "Berlin_Potsdamer_Platz_Input.txt").read_bytes()
    published = "a4ba29c7b8c8c8c991a9194b09ed21527bcffd8c736affeb7ac8d7cb0ba730ff"
    assert hashlib.sha256(data).hexdigest() == published


def test_pipeline_accuracy_with_real_gnss(spp_capture):
    """SFA on all-real sensors (odometer + single-point GNSS from the urban-canyon pseudoranges), with
    the moment fit of the GNSS error model (``gps_adaptive_ml = false``; the listener's default until
    session 35). Measured when written: rms 2.176 m, p95 3.632 m, max 4.284 m along track; most fixes
    are gated or held off (their errors are tens of metres). Bounds ~5 % above the measurement."""
    result = run_pipeline(spp_capture.capture, spp_capture.track,
                          filter_config=ListenerConfig().filter.filter_config(gps_adaptive_ml=False))
    fig = truth_figures(result["estimates"], read_truth(spp_capture.truth))
    assert fig["n"] > 1300
    assert fig["p95_m"] <= 3.81
    assert fig["max_m"] <= 4.50
    assert fig["rms_m"] <= 2.29
    out = result["metrics"]["filter"]["outcomes"]
    assert out["odo_accepted"] == 1372
    assert out["gps_accepted"] + out.get("gps_gated", 0) + out.get("gps_held_off", 0) == 283


def test_pipeline_accuracy_with_real_gnss_under_the_default_model(spp_capture):
    """The same with the listener's default filter (the maximum-likelihood GNSS model since session 35).
    On this log from its first second it misses the issue's 3 m: measured rms 3.307 m, p95 4.399 m, max
    5.633 m, coverage 100 %. Judged from 15 start times it is level with the moment fit (docs/filter.md,
    "Session 35": median window p95 3.19 m for both). Bounds ~5 % above the measurement."""
    result = run_pipeline(spp_capture.capture, spp_capture.track)
    fig = truth_figures(result["estimates"], read_truth(spp_capture.truth))
    assert fig["n"] > 1300
    assert fig["p95_m"] <= 4.62
    assert fig["max_m"] <= 5.91
    assert fig["rms_m"] <= 3.47
    assert fig["coverage"] >= 0.99
    out = result["metrics"]["filter"]["outcomes"]
    assert out["odo_accepted"] == 1372
    assert out["gps_accepted"] + out.get("gps_gated", 0) + out.get("gps_held_off", 0) == 283
