"""Sensor models: the sample statistics of every error source match its configuration."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from interface_modules.faults import Fault
from interface_modules.motion import Trajectory
from interface_modules.presets import G_MPS2, GPS_PRESETS, IMU_PRESETS, ODOMETER_PRESETS
from interface_modules.sensors.gps import NO_FIX_SIGMA_H_M, gauss_markov, simulate_gps
from interface_modules.sensors.imu import simulate_imu
from interface_modules.sensors.odometer import simulate_odometer
from interface_modules.synthetic import Segment, SyntheticTrack

IDEAL_IMU = IMU_PRESETS["ideal"]
IDEAL_ODO = ODOMETER_PRESETS["ideal"]
TRACK = SyntheticTrack([Segment(5000.0), Segment(1000.0, 1 / 200.0)])


def trajectory(n: int, *, s0: float = 100.0, v: float = 0.0, dt: float = 0.01, a: float = 0.0) -> Trajectory:
    """Constant-speed (or standstill) truth on the straight part of TRACK."""
    t = np.arange(n) * dt
    return Trajectory(
        dt_s=dt,
        t_s=t,
        s_m=s0 + v * t,
        v_mps=np.full(n, v),
        a_mps2=np.full(n, a),
        direction=np.ones(n, dtype=np.int8),
        events=[],
    )


def rng(seed: int = 0) -> np.random.Generator:
    return np.random.default_rng(seed)


def rel(a: float, b: float) -> float:
    return abs(a - b) / b


# ------------------------------------------------------------------------------------------- IMU


def test_imu_white_noise_matches_the_noise_density():
    spec = dataclasses.replace(IDEAL_IMU, accel_noise_density=60e-6 * G_MPS2, gyro_noise_density=8.7e-5)
    s = simulate_imu(trajectory(60_000), TRACK, spec, 100.0, [], rng(1), 100.0)
    for axis in ("ax", "ay", "az"):
        assert rel(np.std(s.values[axis]), spec.accel_noise_density * 10.0) < 0.02
    for axis in ("gx", "gy", "gz"):
        assert rel(np.std(s.values[axis]), spec.gyro_noise_density * 10.0) < 0.02
    # level IMU at rest reads -g (5 standard errors of the mean)
    assert np.mean(s.values["az"]) == pytest.approx(
        -G_MPS2, abs=5 * spec.accel_noise_density * 10 / math.sqrt(60_000)
    )


def test_imu_noise_is_scaled_for_the_output_rate():
    spec = dataclasses.replace(IDEAL_IMU, accel_noise_density=1e-3)
    s = simulate_imu(trajectory(40_000), TRACK, spec, 25.0, [], rng(2), 100.0)
    assert s.t_s.size == 10_000 and s.t_s[1] == pytest.approx(0.04)
    assert rel(np.std(s.values["ax"]), 1e-3 * 5.0) < 0.03


def test_imu_bias_random_walk_increments():
    spec = dataclasses.replace(IDEAL_IMU, accel_bias_rw=2e-4, gyro_bias_rw=2e-5)
    s = simulate_imu(trajectory(50_000), TRACK, spec, 100.0, [], rng(3), 100.0)
    assert rel(np.std(np.diff(s.values["ax"])), 2e-4 * math.sqrt(0.01)) < 0.02
    assert rel(np.std(np.diff(s.values["gz"])), 2e-5 * math.sqrt(0.01)) < 0.02


def test_imu_turn_on_bias_scale_and_misalignment_across_seeds():
    bias = dataclasses.replace(IDEAL_IMU, accel_bias_sigma=0.02, gyro_bias_sigma=0.01)
    scale = dataclasses.replace(IDEAL_IMU, gyro_scale_sigma=0.003)
    mis = dataclasses.replace(IDEAL_IMU, misalignment_sigma=0.01)
    at_rest = trajectory(5)
    curving = trajectory(5, s0=5200.0, v=10.0)
    b_ax, b_gx, ratio, pitch = [], [], [], []
    for seed in range(500):
        b = simulate_imu(at_rest, TRACK, bias, 100.0, [], rng(seed), 100.0)
        b_ax.append(b.values["ax"][0])
        b_gx.append(b.values["gx"][0])
        c = simulate_imu(curving, TRACK, scale, 100.0, [], rng(seed), 100.0)
        ratio.append(c.values["gz"][0] / c.truth["gz"][0])
        m = simulate_imu(at_rest, TRACK, mis, 100.0, [], rng(seed), 100.0)
        pitch.append(math.asin(m.values["ax"][0] / G_MPS2))
    # 500 draws: the sample std is within ~3.2 % (1 sigma) of the true one
    assert rel(np.std(b_ax), 0.02) < 0.12
    assert rel(np.std(b_gx), 0.01) < 0.12
    assert rel(np.std(np.array(ratio) - 1.0), 0.003) < 0.12
    assert rel(np.std(pitch), 0.01) < 0.12


def test_imu_quantisation_bias_step_and_stuck():
    spec = dataclasses.replace(
        IDEAL_IMU, accel_noise_density=1e-3, accel_lsb=1e-3, gyro_noise_density=1e-4, gyro_lsb=1e-4
    )
    faults = [
        Fault(kind="imu_bias_step", sensor="imu", start_s=5.0, axis="ax", value=0.2),
        Fault(kind="stuck", sensor="imu", start_s=8.0, end_s=9.0),
    ]
    s = simulate_imu(trajectory(1_000), TRACK, spec, 100.0, faults, rng(4), 100.0)
    for axis, lsb in (("ax", 1e-3), ("gz", 1e-4)):
        q = s.values[axis] / lsb
        np.testing.assert_allclose(q, np.round(q), atol=1e-6)
    t = s.t_s
    step = np.mean(s.values["ax"][(t >= 5.0) & (t < 8.0)]) - np.mean(s.values["ax"][t < 5.0])
    assert step == pytest.approx(0.2, abs=0.002)
    stuck = s.values["ay"][(t >= 8.0) & (t < 9.0)]
    assert np.all(stuck == s.values["ay"][int(np.searchsorted(t, 8.0)) - 1])
    assert [e[1] for e in s.events] == ["imu_bias_step"]


# -------------------------------------------------------------------------------------- odometer


def test_odometer_noise_and_reported_sigma():
    spec = dataclasses.replace(
        ODOMETER_PRESETS["wheel-odometer"],
        scale_sigma=0.0,
        slip_rate_per_h=0.0,
        dropout_prob=0.0,
        lsb_mps=0.0,
    )
    s = simulate_odometer(trajectory(500_000, v=10.0), spec, 20.0, [], rng(5), 100.0)
    expected = math.hypot(spec.sigma_floor_mps, spec.sigma_fraction * 10.0)
    assert rel(np.std(s.values["speed"]), expected) < 0.02
    assert np.mean(s.values["speed"]) == pytest.approx(10.0, abs=0.003)
    assert rel(float(np.median(s.values["sigma"])), expected) < 0.01


def test_odometer_scale_across_seeds_and_zero_at_standstill():
    spec = dataclasses.replace(IDEAL_ODO, scale_sigma=0.01)
    scales = [
        simulate_odometer(trajectory(10, v=10.0), spec, 20.0, [], rng(seed), 100.0).values["speed"][0] / 10
        - 1
        for seed in range(500)
    ]
    assert rel(np.std(scales), 0.01) < 0.12
    wheel = ODOMETER_PRESETS["wheel-odometer"]
    rest = simulate_odometer(trajectory(2_000), wheel, 20.0, [], rng(6), 100.0)
    assert np.all(rest.values["speed"] == 0.0)  # no tachometer pulses at standstill
    radar = simulate_odometer(trajectory(2_000), ODOMETER_PRESETS["doppler-radar"], 20.0, [], rng(6), 100.0)
    assert np.std(radar.values["speed"]) > 0.0  # a radar is noisy at rest


def test_odometer_configured_slip_and_slide_episodes():
    faults = [
        Fault(kind="odo_slip", sensor="odometer", start_s=10.0, end_s=15.0, value=0.2),
        Fault(kind="odo_slip", sensor="odometer", start_s=20.0, end_s=24.0, value=-0.15),
    ]
    s = simulate_odometer(trajectory(3_000, v=10.0), IDEAL_ODO, 20.0, faults, rng(7), 100.0)
    t, v = s.t_s, s.values["speed"]
    np.testing.assert_allclose(v[(t >= 10.5) & (t <= 14.5)], 12.0)
    np.testing.assert_allclose(v[(t >= 20.5) & (t <= 23.5)], 8.5)
    np.testing.assert_allclose(v[(t < 10.0) | ((t > 15.0) & (t < 20.0)) | (t > 24.0)], 10.0)
    assert [e[1] for e in s.events] == ["odo_slip", "odo_slide"]


def test_odometer_spontaneous_slips_only_under_traction_or_braking():
    spec = dataclasses.replace(ODOMETER_PRESETS["wheel-odometer"], slip_rate_per_h=3600.0)
    n = 100 * 600
    a = np.where(np.arange(n) < n // 2, 0.8, 0.0)  # traction, then cruising
    tr = Trajectory(
        dt_s=0.01,
        t_s=np.arange(n) * 0.01,
        s_m=np.zeros(n),
        v_mps=np.full(n, 10.0),
        a_mps2=a,
        direction=np.ones(n, dtype=np.int8),
        events=[],
    )
    s = simulate_odometer(tr, spec, 20.0, [], rng(8), 100.0)
    starts = [e[0] for e in s.events if e[1] == "odo_slip"]
    assert len(starts) > 200  # ~300 expected in the 300 s of traction
    assert max(starts) < 300.0 and not [e for e in s.events if e[1] == "odo_slide"]


def test_odometer_dropouts_match_probability():
    spec = dataclasses.replace(IDEAL_ODO, dropout_prob=0.01)
    s = simulate_odometer(trajectory(1_000_000, v=5.0), spec, 20.0, [], rng(9), 100.0)
    n = s.t_s.size
    dropped = n - int(s.send.sum())
    assert abs(dropped - 0.01 * n) < 5 * math.sqrt(0.01 * 0.99 * n)


# ------------------------------------------------------------------------------------------- GPS


def test_gauss_markov_variance_and_correlation():
    x = gauss_markov(200_000, 1.0, 1.5, 30.0, rng(10))
    assert rel(np.std(x), 1.5) < 0.05
    lag1 = np.corrcoef(x[:-1], x[1:])[0, 1]
    assert lag1 == pytest.approx(math.exp(-1.0 / 30.0), abs=0.005)


def test_gps_errors_match_the_preset():
    spec = GPS_PRESETS["standalone"]
    s = simulate_gps(trajectory(100 * 40_000, dt=0.01), TRACK, spec, 1.0, [], rng(11), 100.0)
    err = s.truth["east_err"]
    assert rel(np.std(err), math.hypot(spec.gm_sigma_m, spec.white_sigma_m)) < 0.12
    white = np.diff(err) / math.sqrt(2)  # consecutive differences: mostly the white part at tau = 30 s
    expected = math.sqrt(spec.white_sigma_m**2 + spec.gm_sigma_m**2 * (1 - math.exp(-1 / spec.gm_tau_s)))
    assert rel(np.std(white), expected) < 0.03
    # the datagram's position is the truth moved by the error (north error through the meridian radius)
    dn = np.radians(s.values["lat"] - s.truth["lat"]) * 6_371_000.0
    assert np.corrcoef(dn, s.truth["north_err"])[0, 1] > 0.999
    assert np.all(s.values["fix_quality"] == 1)
    assert 5 <= s.values["num_sv"].min() and s.values["num_sv"].max() <= 32


def test_gps_tunnel_outage_reacquisition_and_multipath():
    n = 100 * 300
    t = np.arange(n) * 0.01
    tr = Trajectory(
        dt_s=0.01,
        t_s=t,
        s_m=100.0 + 10.0 * t,
        v_mps=np.full(n, 10.0),
        a_mps2=np.zeros(n),
        direction=np.ones(n, dtype=np.int8),
        events=[],
    )
    faults = [
        Fault(kind="gnss_outage", sensor="gps", from_m=1100.0, to_m=1600.0, mode="no_fix"),
        Fault(kind="gnss_outage", sensor="gps", from_m=2100.0, to_m=2300.0, mode="silent"),
        Fault(kind="multipath_step", sensor="gps", start_s=250.0, end_s=260.0, east_m=30.0),
    ]
    spec = GPS_PRESETS["ideal"]
    s = simulate_gps(tr, TRACK, spec, 1.0, faults, rng(12), 100.0)
    ts, fq = s.t_s, s.values["fix_quality"]
    s_fix = 100.0 + 10.0 * ts
    tunnel = (s_fix >= 1100.0) & (s_fix <= 1600.0)
    assert np.all(fq[tunnel] == 0) and np.all(s.values["sigma_h"][tunnel] == NO_FIX_SIGMA_H_M)
    assert np.all(s.values["lat"][tunnel] == 0.0) and np.all(s.values["num_sv"][tunnel] == 0)
    first_after = ts[(s_fix > 1600.0) & (fq > 0)][0]
    last_in = ts[tunnel][-1]
    assert first_after - last_in >= spec.reacquire_s  # hot start after the tunnel
    silent = (s_fix >= 2100.0) & (s_fix <= 2300.0)
    assert not s.send[silent].any() and s.send[~silent].all()
    mp = (ts >= 250.0) & (ts < 260.0)
    assert np.all(np.abs(s.truth["east_err"][mp] - 30.0) < 1e-9)
    kinds = [e[1] for e in s.events]
    assert kinds.count("gnss_lost") == 2 and "multipath_step" in kinds
