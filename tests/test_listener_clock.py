"""STROBE clock model: rejects positive delay jitter, follows skew, resets on steps."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from listener.clock import StrobeClock
from listener.config import ClockConfig


def test_unsynced_before_first_strobe():
    clock = StrobeClock()
    assert not clock.synced
    assert clock.to_sensor_time(5.0) is None


def test_jitter_is_rejected_by_the_lower_delay_envelope():
    rng = np.random.default_rng(7)
    clock = StrobeClock(ClockConfig())
    offset = 1.7e9 - 100.0  # sensor time = listener time + offset
    d_min = 0.0002
    errors = []
    for k in range(240):
        sensor_t = 1.7e9 + k
        arrival = sensor_t - offset + d_min + rng.exponential(0.005)  # 5 ms mean jitter
        clock.on_strobe(sensor_t, arrival)
        if k >= 10:
            probe = 100.0 + k + 0.5
            errors.append(clock.to_sensor_time(probe) - (probe + offset))
    errors = np.abs(np.array(errors))
    # the estimate sits at the minimum delay, far below the 5 ms mean jitter
    assert errors.max() < 0.0015
    assert np.median(errors) < 0.0006


def test_skew_is_followed():
    clock = StrobeClock(ClockConfig())
    skew = 50e-6  # sensor clock runs 50 ppm fast
    for k in range(60):
        arrival = float(k)
        clock.on_strobe(1000.0 + k * (1 + skew), arrival + 0.0001)
    probe = 59.5
    expected = 1000.0 + (probe - 0.0001) * (1 + skew)
    assert abs(clock.to_sensor_time(probe) - expected) < 1e-4


def test_step_resets_the_model_once_it_persisted():
    clock = StrobeClock(ClockConfig(max_step_s=1.0, confirm_s=5.0))
    for k in range(5):
        clock.on_strobe(500.0 + k, float(k))
    clock.on_strobe(9000.0, 5.0)  # sensor set restarted its clock ...
    assert clock.resets == 0 and clock.unconfirmed == 1 and clock.rejected == 1
    assert abs(clock.to_sensor_time(5.0) - 505.0) < 1e-9  # not believed from one STROBE
    for k in range(1, 5):  # ... agreeing STROBEs, none with the old model, but not yet for 5 s
        clock.on_strobe(9000.0 + k, 5.0 + k)
        assert clock.resets == 0
    assert clock.rejected == 5 and clock.trouble_at == 9.0
    clock.on_strobe(9005.0, 10.0)  # 5 s of it: adopted
    assert clock.resets == 1 and clock.unconfirmed == 1
    assert abs(clock.to_sensor_time(10.0) - 9005.0) < 1e-9


def test_step_confirmed_by_the_next_strobe_without_persistence():
    clock = StrobeClock(ClockConfig(max_step_s=1.0, confirm_s=0.0))
    for k in range(5):
        clock.on_strobe(500.0 + k, float(k))
    clock.on_strobe(9000.0, 5.0)
    assert clock.resets == 0 and clock.unconfirmed == 1
    clock.on_strobe(9001.0, 6.0)
    assert clock.resets == 1
    assert abs(clock.to_sensor_time(6.0) - 9001.0) < 1e-9


@pytest.mark.parametrize("shift", [100.0, -100.0, 0.5, 0.2])
def test_a_forged_strobe_stream_beside_the_real_one_never_moves_the_timebase(shift):
    """STROBE at 2 Hz shifted by ``shift`` from another sender, interleaved with the real 1 Hz stream
    for 60 s: each real STROBE agrees with the model, so the forger's candidate never persists; every
    forged one is rejected and counted."""
    clock = StrobeClock(ClockConfig())
    offset = 1.7e9
    for k in range(20):
        clock.on_strobe(offset + k, k + 0.001)
    for k in range(20, 80):
        clock.on_strobe(offset + k + 0.25 + shift, k + 0.25)  # the forger's: real time + shift
        clock.on_strobe(offset + k, k + 0.001)
        clock.on_strobe(offset + k + 0.75 + shift, k + 0.75)
        probe = k + 0.9
        assert abs(clock.to_sensor_time(probe) - (offset + probe - 0.001)) < 0.01
    assert clock.resets == 0 and clock.rejected == 120 and clock.trouble_at == 79.75


@given(st.floats(min_value=1e-5, max_value=0.5), st.integers(min_value=0, max_value=2**31))
@settings(max_examples=40, deadline=None)
def test_a_ramp_cannot_drag_the_timebase_beyond_the_drift_bound(step_s, seed):
    """A forger beside the real 1 Hz stream moving its STROBEs ahead a little more each time (each
    within the jitter allowance of the last, so that a plain envelope would follow it): the timebase
    never runs ahead of the real one by more than drift x time + jitter. (A lone source that keeps
    its new offset for confirm_s is adopted: that is a sensor-set clock reset.)"""
    rng = np.random.default_rng(seed)
    cfg = ClockConfig()
    clock = StrobeClock(cfg)
    for k in range(10):
        clock.on_strobe(1000.0 + k, float(k))
    ahead = 0.0
    worst = 0.0
    for k in range(10, 130):
        ahead += step_s * rng.uniform(0.5, 1.0)
        clock.on_strobe(1000.0 + k + 0.5 + ahead, k + 0.5)
        clock.on_strobe(1000.0 + k + 1.0, k + 1.0)
        worst = max(worst, clock.to_sensor_time(k + 1.0) - (1000.0 + k + 1.0))
    assert worst <= cfg.max_drift * 130.0 + cfg.max_jitter_s + 1e-9


def test_one_corrupted_strobe_does_not_move_the_timebase():
    clock = StrobeClock(ClockConfig(max_step_s=1.0))
    for k in range(10):
        clock.on_strobe(500.0 + k, float(k))
    clock.on_strobe(5.0e8, 10.0)  # a flipped exponent bit
    clock.on_strobe(511.0, 11.0)
    assert clock.resets == 0 and clock.unconfirmed == 1
    assert abs(clock.to_sensor_time(11.5) - 511.5) < 1e-9


def test_non_finite_strobes_are_ignored():
    clock = StrobeClock()
    clock.on_strobe(float("nan"), 1.0)
    clock.on_strobe(1.0, float("inf"))
    assert not clock.synced


def test_skew_and_jitter_together():
    rng = np.random.default_rng(11)
    clock = StrobeClock(ClockConfig())
    skew = 80e-6
    errs = []
    for k in range(300):
        arrival = float(k) + 0.0002 + rng.exponential(0.005)
        sensor_t = 2000.0 + k * (1 + skew)
        clock.on_strobe(sensor_t, arrival)
        if k >= 60:
            probe = k + 0.5  # a measurement sent at listener time k + 0.5 - d_min
            truth = 2000.0 + (probe - 0.0002) * (1 + skew)
            errs.append(abs(clock.to_sensor_time(probe) - truth))
    assert max(errs) < 0.0015, max(errs)


def test_accelerated_sensor_clock_with_lost_strobes():
    """A live run at 10x (the simulator's --speed 10): STROBEs every 0.1 listener s, 20 % of them lost
    (seeded). With clock.rate = 10 the model extrapolates at the right rate from the first STROBE on,
    never resets, and dates a measurement within a few ms of sensor time; at the nominal rate the
    same stream resets the model again and again (what the live campaign's loss row measured)."""
    rng = np.random.default_rng(3)
    arrivals = np.arange(600) * 0.1
    kept = rng.random(600) >= 0.2
    for rate, expect_resets in ((10.0, False), (1.0, True)):
        clock = StrobeClock(ClockConfig(rate=rate))
        worst = 0.0
        for k in np.flatnonzero(kept):
            now = float(arrivals[k]) + 0.0002
            clock.on_strobe(5000.0 + 10.0 * float(arrivals[k]), now)
            probe = now + 0.25  # a measurement 0.25 listener s (2.5 sensor s) after the STROBE
            worst = max(worst, abs(clock.to_sensor_time(probe) - (5000.0 + 10.0 * (probe - 0.0002))))
        if expect_resets:
            assert clock.resets + clock.unconfirmed > 10
        else:
            assert clock.resets == 0 and clock.unconfirmed == 0
            assert worst < 0.005


def test_a_lone_source_off_the_configured_rate_is_judged_at_its_own_rate():
    """The only STROBE source runs 10 % fast (a sender at 1.1x with clock.rate = 1): the rate it shows
    while the model settles is the one the drift bound is judged at, so it is followed without a
    rejection and nothing it dates looks like the future."""
    clock = StrobeClock(ClockConfig())
    worst = 0.0
    for k in range(120):
        now = float(k)
        clock.on_strobe(1000.0 + 1.1 * now, now)
        probe = now + 0.5
        worst = max(worst, abs((1000.0 + 1.1 * probe) - clock.to_sensor_time(probe)))
    assert clock.settled_rate == pytest.approx(1.1)
    assert clock.rejected == 0 and clock.resets == 0
    assert worst < 0.2, worst


def test_an_accelerated_source_without_clock_rate_is_judged_at_its_own_rate():
    """sfa sim --live --speed 8 with the listener at clock.rate = 1 (a misconfiguration the live tests
    make): the rate shown while settling (8) is the one the drift bound uses, so the STROBEs are taken
    and the timebase follows them, as the envelope did before the drift bound."""
    clock = StrobeClock(ClockConfig())
    worst = 0.0
    for k in range(480):
        now = k * 0.125 + 0.0002 * (k % 3)
        clock.on_strobe(1.7e9 + k, now)
        probe = now + 0.06
        worst = max(worst, abs(clock.to_sensor_time(probe) - (1.7e9 + k + 0.48)))
    assert clock.settled_rate == pytest.approx(8.0, rel=0.01)
    assert clock.rejected == 0 and clock.resets == 0
    assert worst < 1.0
