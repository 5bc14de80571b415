"""The fast replay's clock stage: many STROBEs through the listener's own clock in one compiled loop.

The fast replay needs the clock after every STROBE of a capture: for the counters the exact replay
reports (STROBEs used, resets, unconfirmed steps) and for the sensor-set "now" at each datagram's
arrival, which the pipeline compares epochs against (``epoch_future`` rejection, stale estimates not
sent). There is one clock implementation, :mod:`listener.clock_core` (compiled kernels over the state
:class:`listener.clock.StrobeClock` holds); this module only drives it through the clock's public
batch calls (:meth:`~listener.clock.StrobeClock.take_strobes`,
:meth:`~listener.clock.StrobeClock.sensor_times`) and applies the pipeline's two clock rules to the
answers. tests/test_fast_clock.py checks the batch calls against the per-STROBE calls.
"""

from __future__ import annotations

import numpy as np

from listener import clock_core


def replay_strobes(clock, timestamp: np.ndarray, now: np.ndarray) -> np.ndarray:
    """Advance ``clock`` (a StrobeClock) by the STROBEs, as ``on_strobe`` does, in one compiled loop.

    Returns (k + 1, 4): row 0 the model before the first STROBE, row j + 1 after STROBE j, each as
    (synced, intercept, slope, ref)."""
    out = np.zeros((np.shape(timestamp)[0] + 1, 4))
    out[0] = clock.model()
    out[1:] = clock.take_strobes(timestamp, now)
    return out


def replay_clock(clock, strobes, meas, max_future: float, stale_before: float, m_now=None):
    """Advance ``clock`` (a StrobeClock) by the STROBEs ``strobes`` = (datagram index, timestamp, arrival)
    and date the measurements ``meas`` = (datagram index, arrival, epoch) against it on the way, in datagram
    order (one compiled pass).

    Per measurement, with the clock as the STROBEs before it left it (``to_sensor_time`` of its arrival:
    sensor_now, NaN before any STROBE): one without its epoch (``epoch[j]`` NaN) is dated
    ``epoch[j] = sensor_now`` in place (``Pipeline._date``; the caller makes sure the clock has a STROBE by
    then, else the listener would queue it undated); ``future[j]``: the listener rejects a carried epoch
    as epoch_future (epoch > sensor_now + max_future); ``fresh_min[j]``: the clock's sensor time at
    ``m_now[j]`` (its release: the arrival, default, or the end of a sequence buffer's hold) minus
    ``stale_before`` (estimates with an older epoch are stale, not sent). Every STROBE is applied.
    Returns (fresh_min, future, number of future epochs)."""
    m_row, m_time, t_s = meas
    sn, sn_release = clock.sensor_times(strobes, (m_row, m_time, m_time if m_now is None else m_now))
    undated = np.isnan(t_s)
    with np.errstate(invalid="ignore"):
        future = ~undated & (t_s > sn + float(max_future))
    t_s[undated] = sn[undated]
    fresh_min = sn_release - float(stale_before)
    return fresh_min, future, int(np.count_nonzero(future))


def sensor_now(params: np.ndarray, now: np.ndarray) -> np.ndarray:
    """``StrobeClock.to_sensor_time(now)`` per element with the model ``params`` (rows as returned by
    :func:`replay_strobes`, one per element); NaN where the clock has no STROBE yet (None)."""
    out = np.empty(np.shape(now)[0])
    clock_core.model_sensor_times(np.ascontiguousarray(params, dtype=np.float64),
                                  np.ascontiguousarray(now, dtype=np.float64), out)
    return out


__all__ = ["replay_clock", "replay_strobes", "sensor_now"]
