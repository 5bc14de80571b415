"""tools.fast_clock: the compiled STROBE clock equals listener.clock.StrobeClock, STROBE by STROBE.

Seeded sequences with arrival jitter, clock skew, a confirmed step (reset), a lone corrupted timestamp
(unconfirmed), non-finite values, and a window that overflows; compared after every STROBE (the state
the fast replay uses for the sensor-set "now") and at the end (every field of the clock object).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from listener.clock import StrobeClock
from listener.config import ClockConfig
from tools.fast_clock import replay_strobes, sensor_now


def _strobes(seed: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    now = 1000.0 + np.arange(n) * 1.0 + rng.uniform(0.0, 0.02, n)  # 1 Hz, up to 20 ms delay jitter
    skew = rng.uniform(-2e-4, 2e-4)
    ts = 1.7e9 + (now - 1000.0) * (1.0 + skew) - rng.uniform(0.0, 0.004, n)
    ts[n // 3 :] += 5.0  # a clock step, confirmed by the next STROBE: a reset
    ts[n // 2] += 40.0  # one corrupted timestamp: unconfirmed, not believed
    ts[n // 2 + 7] = math.nan
    now[n // 2 + 9] = math.inf
    return ts, now


def _state(clock: StrobeClock) -> tuple:
    """Everything the clock holds: its public reading and its whole state array, bit for bit."""
    return (clock.samples(), clock.model(), clock.resets, clock.strobes, clock.unconfirmed, clock.synced,
            clock.rejected, clock.trouble_at, clock.state().tobytes())


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_compiled_clock_equals_the_listener_clock(seed):
    ts, now = _strobes(seed, 400)  # more than the 120-STROBE window
    cfg = ClockConfig()
    ref = StrobeClock(cfg)
    fast = StrobeClock(cfg)
    head = 25  # the fast path starts from a clock the exact prefix has already fed
    for k in range(head):
        ref.on_strobe(float(ts[k]), float(now[k]))
        fast.on_strobe(float(ts[k]), float(now[k]))
    params = replay_strobes(fast, ts[head:], now[head:])
    probe = now[head:] + 0.37  # a datagram arriving between this STROBE and the next
    expected = []
    for k in range(head, ts.size):
        ref.on_strobe(float(ts[k]), float(now[k]))
        got = ref.to_sensor_time(float(probe[k - head]))
        expected.append(math.nan if got is None else got)
    got = sensor_now(params[1:], probe)
    np.testing.assert_array_equal(got, np.array(expected))  # bit for bit, NaN where not synced
    assert _state(fast) == _state(ref)
    assert ref.resets >= 1 and ref.unconfirmed >= 1  # the sequence exercised both rules


def test_from_a_fresh_clock_and_nothing_to_do():
    cfg = ClockConfig(window_strobes=16)
    ts, now = _strobes(7, 60)
    ref, fast = StrobeClock(cfg), StrobeClock(cfg)
    empty = replay_strobes(fast, np.zeros(0), np.zeros(0))
    assert empty.shape == (1, 4) and empty[0, 0] == 0.0
    params = replay_strobes(fast, ts, now)
    for k in range(ts.size):
        ref.on_strobe(float(ts[k]), float(now[k]))
        assert (params[k + 1, 1], params[k + 1, 2], params[k + 1, 3]) == ref.model()[1:]
    assert _state(fast) == _state(ref)
    assert fast.to_sensor_time(now[-1] + 0.5) == ref.to_sensor_time(now[-1] + 0.5)


@pytest.mark.parametrize("shift", [100.0, -100.0, 0.3])
def test_compiled_clock_equals_the_listener_clock_under_a_forged_stream(shift):
    """A forger's STROBE stream beside the real one (2 Hz, shifted) and then a real clock step that
    persists: the rejections, the trouble time, the candidate and its adoption agree bit for bit."""
    rng = np.random.default_rng(4)
    rows = []
    for k in range(300):
        now = 1000.0 + k + rng.uniform(0.0, 0.01)
        real = 1.7e9 + (now - 1000.0) + (50.0 if k >= 200 else 0.0)  # a real step at k = 200
        rows.append((real, now))
        if 50 <= k < 120:
            for half in (0.25, 0.75):
                rows.append((1.7e9 + (now + half - 1000.0) + shift, now + half))
    ts = np.array([r[0] for r in rows])
    now = np.array([r[1] for r in rows])
    ref, fast = StrobeClock(ClockConfig()), StrobeClock(ClockConfig())
    for k in range(5):
        ref.on_strobe(float(ts[k]), float(now[k]))
        fast.on_strobe(float(ts[k]), float(now[k]))
    params = replay_strobes(fast, ts[5:], now[5:])
    expected = []
    for k in range(5, ts.size):
        ref.on_strobe(float(ts[k]), float(now[k]))
        got = ref.to_sensor_time(float(now[k]) + 0.1)
        expected.append(math.nan if got is None else got)
    np.testing.assert_array_equal(sensor_now(params[1:], now[5:] + 0.1), np.array(expected))
    assert _state(fast) == _state(ref)
    assert ref.rejected >= 140 and ref.resets == 1  # every forged one rejected; the real step adopted
