"""tools.info_bound: the covariance is the error the relaxed model really makes, and the p95 of a
sigma mixture is the pooled p95 of draws from it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tools.info_bound import GnssErrorModel, OdometerNoise, along_track_sigma, expected_p95


def _world(step_s=0.5, duration_s=150.0):
    """A run with two stops and a 90 degree curve: sample times, held speeds, tangents, fix times."""
    t = np.arange(0.0, duration_s + 1e-9, step_s)
    speed = np.where((t % 60.0) < 45.0, 9.0, 0.0)  # 45 s running, 15 s stopped
    heading = np.clip((t - 40.0) / 30.0, 0.0, 1.0) * (math.pi / 2)  # the curve from 40 s to 70 s
    tangent = np.column_stack([np.sin(heading), np.cos(heading)])
    fixes = np.arange(1.0, duration_s + 1e-9, 1.0)
    return t, speed, tangent, fixes


def _draw(rng, t, speed, tangent, fixes, model, k_sigma, odo_psd=0.0):
    """The relaxed world, drawn independently of the module: ds(t) = k D(t) plus (``odo_psd``, one
    value per sample) the odometer's integrated white noise, exact GM per axis."""
    distance = np.concatenate([[0.0], np.cumsum(speed[:-1] * np.diff(t))])  # held speed per segment
    k = rng.normal(0.0, k_sigma)
    walk = rng.normal(0.0, 1.0, t.size - 1) * np.sqrt(np.broadcast_to(odo_psd, t.shape)[:-1] * np.diff(t))
    ds = k * distance + np.concatenate([[0.0], np.cumsum(walk)])
    g = rng.normal(0.0, model.gm_sigma_m, 2)
    z = np.empty((fixes.size, 2))
    t_prev = 0.0
    for j, tf in enumerate(fixes):
        phi = math.exp(-(tf - t_prev) / model.gm_tau_s)
        g = phi * g + rng.normal(0.0, model.gm_sigma_m * math.sqrt(1 - phi * phi), 2)
        t_prev = tf
        i = int(np.searchsorted(t, tf))  # fixes fall on sample times
        z[j] = tangent[i - 1] * ds[i] + g + rng.normal(0.0, model.white_sigma_m, 2)
    return ds, z


@pytest.mark.parametrize("model", [GnssErrorModel(1.2, 20.0, 0.5), GnssErrorModel(0.8, 90.0, 0.9)])
def test_the_sigma_is_the_error_the_model_makes(model):
    t, speed, tangent, fixes = _world()
    rng = np.random.default_rng(20261203)
    errors, sigmas = [], []
    for _ in range(400):  # bounded: 400 draws, about 4 s
        ds, z = _draw(rng, t, speed, tangent, fixes, model, 0.005)
        sig, ds_hat = along_track_sigma(t, speed, tangent, fixes, model, 0.005, fix_z_en=z)
        errors.append(ds_hat - ds)
        sigmas.append(sig)
    e, s = np.concatenate(errors), np.concatenate(sigmas)
    ok = s > 0
    nees = float(np.mean((e[ok] / s[ok]) ** 2))
    assert 0.85 < nees < 1.15, nees  # the covariance is neither optimistic nor pessimistic
    # the sigma without data is the same as with (the covariance does not depend on the data)
    assert np.array_equal(along_track_sigma(t, speed, tangent, fixes, model, 0.005), sigmas[-1])
    realised = float(np.percentile(np.abs(e), 95))
    assert realised == pytest.approx(expected_p95(s), rel=0.08)  # seeds 1-3: within 6 %


def test_no_fix_no_information():
    t, speed, tangent, _ = _world()
    sig = along_track_sigma(t, speed, tangent, np.array([]), GnssErrorModel(1.0, 30.0, 0.5), 0.01)
    distance = np.concatenate([[0.0], np.cumsum(speed[:-1] * np.diff(t))])
    np.testing.assert_allclose(sig, 0.01 * distance, rtol=1e-9, atol=1e-12)  # the scale error alone


def test_better_gnss_lowers_the_bound():
    t, speed, tangent, fixes = _world()
    worse = along_track_sigma(t, speed, tangent, fixes, GnssErrorModel(1.5, 60.0, 1.0), 0.005)
    better = along_track_sigma(t, speed, tangent, fixes, GnssErrorModel(0.5, 60.0, 0.3), 0.005)
    assert np.all(better <= worse + 1e-12) and better[-1] < 0.6 * worse[-1]


def test_expected_p95():
    assert expected_p95(np.full(10, 2.0)) == pytest.approx(2.0 * 1.959964, rel=1e-5)
    assert expected_p95(np.zeros(4)) == 0.0
    assert math.isnan(expected_p95(np.array([])))
    rng = np.random.default_rng(7)
    sig = np.repeat([0.2, 1.0, 3.0], 20000)
    draws = np.abs(rng.normal(0.0, sig))
    assert expected_p95(sig) == pytest.approx(float(np.percentile(draws, 95)), rel=0.02)


def test_the_odometer_s_white_noise_is_the_error_the_model_makes():
    """With the odometer's white noise (here a poor one: 5 % of speed at 20 Hz, so that it matters beside
    the scale error) the drawn world's position also random-walks; the covariance with that noise is
    still the error the filter makes (without it, NEES 1.25), and is larger than the noise-free one,
    most where the fixes are furthest apart."""
    t, speed, tangent, fixes = _world()
    fixes = fixes[(fixes < 60.0) | (fixes > 100.0)]  # a 40 s outage
    noise = OdometerNoise(0.05, 0.05, 0.01, 20.0)
    psd = noise.psd_m2ps(speed)
    assert psd[0] == pytest.approx((0.05 ** 2 + (0.05 * 9.0) ** 2 + 0.01 ** 2 / 12) / 20.0)
    model = GnssErrorModel(1.0, 30.0, 0.5)
    rng = np.random.default_rng(20261206)
    errors, sigmas = [], []
    for _ in range(400):  # bounded: 400 draws, about 4 s
        ds, z = _draw(rng, t, speed, tangent, fixes, model, 0.005, psd)
        sig, ds_hat = along_track_sigma(t, speed, tangent, fixes, model, 0.005, fix_z_en=z, odo_psd_m2ps=psd)
        errors.append(ds_hat - ds)
        sigmas.append(sig)
    e, s = np.concatenate(errors), np.concatenate(sigmas)
    ok = s > 0
    nees = float(np.mean((e[ok] / s[ok]) ** 2))
    assert 0.85 < nees < 1.15, nees
    quiet = along_track_sigma(t, speed, tangent, fixes, model, 0.005)
    assert np.all(sigmas[-1] >= quiet - 1e-12)
    gap = (t > 60.0) & (t < 100.0)
    assert np.max(sigmas[-1][gap] - quiet[gap]) > np.max((sigmas[-1] - quiet)[t < 40.0])
