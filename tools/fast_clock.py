"""The listener's STROBE clock (:class:`listener.clock.StrobeClock`) over many STROBEs in compiled code.

The fast replay needs the clock state after every STROBE of a capture: for the counters the exact
replay reports (STROBEs used, resets, unconfirmed steps) and for the sensor-set "now" at each
datagram's arrival, which the pipeline compares epochs against (``epoch_future`` rejection, stale
estimates not sent). ``StrobeClock.on_strobe`` refits an upper convex hull over its 120-STROBE window
in Python on every STROBE (about 0.15 ms each: 0.9 s on a 92 min capture); :func:`run_strobes` is a
line-by-line transliteration of ``on_strobe``, ``_fit`` and ``_upper_hull`` with the same float
operations in the same order (Python's ``sum`` of floats is a plain left-to-right sum up to Python 3.11;
3.12 compensates it, so :func:`clock_supported` sends those interpreters to the Python clock).
tests/test_fast_clock.py checks the two against each other STROBE by STROBE, steps and jitter included.
The window is kept in mirrored buffers (each sample twice, ``window`` apart), so it is always one
contiguous stretch and dropping the oldest sample moves nothing; the sums still run oldest first.
:func:`run_clock` applies the STROBEs of a capture stretch and dates its measurements in one pass (the
fast replay's clock stage); :func:`replay_strobes` returns the state after every STROBE instead.
"""

from __future__ import annotations

import math
import sys
from collections import deque

import numpy as np
from numba import njit

# slots of the scalar state array
C_SLOPE = 0
C_REF = 1
C_INTERCEPT = 2
C_RESETS = 3
C_STROBES = 4
C_UNCONFIRMED = 5
C_CAND = 6  #: candidate offset (meaningful when C_HAS_CAND != 0)
C_HAS_CAND = 7
C_N = 8  #: samples in the window
C_HEAD = 9  #: slot of the oldest sample in the mirrored sample buffers
C_REJECTED = 10  #: StrobeClock.rejected
C_TROUBLE = 11  #: StrobeClock.trouble_at (NaN: None)
C_CAND_SINCE = 12
C_ANCHOR_T = 13
C_ANCHOR_O = 14
C_ANCHOR_R = 15  #: StrobeClock._anchor_r (NaN while settling)
NSTATE = 16
# slots of the parameter array (ClockConfig)
P_MAX_STEP = 0
P_CONFIRM = 1
P_DRIFT = 2
P_JITTER = 3
P_RATE = 4
NPARAM = 5


def clock_supported() -> bool:
    """True where :func:`run_strobes` is bit-identical to StrobeClock (float ``sum`` not compensated)."""
    return sys.version_info < (3, 12)


@njit(cache=True, _nrt=False)
def _fit(st, smp_t, smp_o, h0, n, hx, hy):
    """StrobeClock._fit over the n samples smp_*[h0:h0 + n] (oldest first); hx, hy: hull scratch."""
    ref = smp_t[h0 + n - 1]
    slope = 0.0
    intercept = smp_o[h0]
    for i in range(1, n):
        if smp_o[h0 + i] > intercept:
            intercept = smp_o[h0 + i]
    if n >= 10 and smp_t[h0 + n - 1] - smp_t[h0] >= 20.0:
        m = 0
        for i in range(n):
            px = smp_t[h0 + i]
            py = smp_o[h0 + i]
            while m >= 2:
                x1 = hx[m - 2]
                y1 = hy[m - 2]
                x2 = hx[m - 1]
                y2 = hy[m - 1]
                if (x2 - x1) * (py - y1) - (y2 - y1) * (px - x1) >= 0:
                    m -= 1
                else:
                    break
            hx[m] = px
            hy[m] = py
            m += 1
        acc = 0.0
        for i in range(n):
            acc = acc + smp_t[h0 + i]
        t_mean = acc / n
        for j in range(m - 1):
            ta = hx[j]
            oa = hy[j]
            tb = hx[j + 1]
            ob = hy[j + 1]
            if ta <= t_mean <= tb and tb > ta:
                slope = (ob - oa) / (tb - ta)
                break
        # max(-1e-3, min(1e-3, slope)) with Python's semantics (the first argument unless the second wins)
        lo = slope if slope < 1e-3 else 1e-3
        slope = lo if lo > -1e-3 else -1e-3
        intercept = smp_o[h0] - slope * (smp_t[h0] - ref)
        for i in range(1, n):
            v = smp_o[h0 + i] - slope * (smp_t[h0 + i] - ref)
            if v > intercept:
                intercept = v
    st[C_INTERCEPT] = intercept
    st[C_SLOPE] = slope
    st[C_REF] = ref


@njit(cache=True, _nrt=False)
def _settle(st, smp_t, smp_o, h0, n, rate):
    """StrobeClock._settle over the n samples smp_*[h0:h0 + n]."""
    t0 = smp_t[h0]
    o0 = smp_o[h0]
    t1 = smp_t[h0 + n - 1]
    o1 = smp_o[h0 + n - 1]
    r = rate
    if t1 > t0:
        raw = 1.0 + (o1 - o0) / (t1 - t0)
        if abs(raw - rate) > 0.02 * rate:
            r = raw
    st[C_ANCHOR_R] = r
    ta = st[C_ANCHOR_T]
    best = o0 - (r - 1.0) * (t0 - ta)
    for i in range(1, n):
        v = smp_o[h0 + i] - (r - 1.0) * (smp_t[h0 + i] - ta)
        if v > best:
            best = v
    st[C_ANCHOR_O] = best


@njit(cache=True, _nrt=False)
def _on_strobe(ts, t, n, window, prm, st, smp_t, smp_o, hx, hy):
    """``StrobeClock.on_strobe(ts, t)`` on the state: st, and the n samples from slot st[C_HEAD] of the
    mirrored buffers smp_t, smp_o (2 * window: sample slot p is also kept at p + window, so the window
    is always one contiguous stretch and dropping the oldest moves nothing). Returns n."""
    if math.isfinite(ts) and math.isfinite(t):
        offset = ts - t
        max_step = prm[P_MAX_STEP]
        confirm = prm[P_CONFIRM]
        rate = prm[P_RATE]
        accept = True
        if n > 0:
            predicted = st[C_INTERCEPT] + st[C_SLOPE] * (t - st[C_REF])
            since = t - st[C_ANCHOR_T]
            bad = abs(offset - predicted) > max_step
            if not bad and since >= confirm:
                if math.isnan(st[C_ANCHOR_R]):
                    _settle(st, smp_t, smp_o, int(st[C_HEAD]), n, rate)
                r = st[C_ANCHOR_R]
                bad = offset > st[C_ANCHOR_O] + (r - 1.0 + prm[P_DRIFT] * r) * since + prm[P_JITTER]
            if bad:
                agree = False
                if st[C_HAS_CAND] != 0.0:
                    age = t - st[C_CAND_SINCE]
                    rc = rate if math.isnan(st[C_ANCHOR_R]) else st[C_ANCHOR_R]
                    agree = not abs(offset - (rc - 1.0) * age - st[C_CAND]) > max_step
                if not agree:
                    st[C_CAND] = offset
                    st[C_HAS_CAND] = 1.0
                    st[C_CAND_SINCE] = t
                    st[C_UNCONFIRMED] += 1.0
                    st[C_REJECTED] += 1.0
                    st[C_TROUBLE] = t
                    accept = False
                elif t - st[C_CAND_SINCE] < confirm:
                    st[C_REJECTED] += 1.0
                    st[C_TROUBLE] = t
                    accept = False
                else:
                    n = 0
                    st[C_RESETS] += 1.0
        if accept:
            st[C_HAS_CAND] = 0.0
            if n == 0:
                st[C_ANCHOR_T] = t
                st[C_ANCHOR_O] = offset
                st[C_ANCHOR_R] = math.nan
            head = int(st[C_HEAD])
            if n == window:  # deque(maxlen=window).append drops the oldest
                head += 1
                if head == window:
                    head = 0
                n -= 1
            p = head + n
            if p >= window:
                p -= window
            smp_t[p] = t
            smp_o[p] = offset
            smp_t[p + window] = t
            smp_o[p + window] = offset
            n += 1
            st[C_HEAD] = head
            st[C_STROBES] += 1.0
            _fit(st, smp_t, smp_o, head, n, hx, hy)
    return n


@njit(cache=True, _nrt=False)
def run_strobes(timestamp, now, window, prm, st, smp_t, smp_o, hx, hy, out):
    """Apply STROBEs (sensor-set ``timestamp[k]`` received at ``now[k]``) to the clock state.

    ``st``: scalar state (slots C_*); ``smp_t``/``smp_o``: the window's samples, oldest first from slot
    ``st[C_HEAD]``, ``st[C_N]`` of them (mirrored buffers of 2 * ``window``); hx, hy: scratch (window).
    ``out[k]``: (synced, intercept, slope, ref) after STROBE k."""
    n = int(st[C_N])
    for k in range(timestamp.shape[0]):
        n = _on_strobe(timestamp[k], now[k], n, window, prm, st, smp_t, smp_o, hx, hy)
        out[k, 0] = 1.0 if n > 0 else 0.0
        out[k, 1] = st[C_INTERCEPT]
        out[k, 2] = st[C_SLOPE]
        out[k, 3] = st[C_REF]
    st[C_N] = n


@njit(cache=True, _nrt=False)
def run_clock(
    s_row, s_ts, s_time, m_row, m_time, t_s, m_now, window, prm, max_future, stale_before, st, smp_t,
    smp_o, hx, hy, fresh_min, future,
):  # fmt: skip
    """The STROBEs (datagram ``s_row``, timestamp ``s_ts``, arrival ``s_time``) and the measurements
    (datagram ``m_row``, arrival ``m_time``, epoch ``t_s``) of one capture stretch, in datagram order.

    Per measurement, with the clock as the STROBEs before it left it (``StrobeClock.to_sensor_time`` of its
    arrival: sensor_now; NaN before any STROBE): a measurement without its epoch (``t_s[j]`` NaN) is
    dated ``t_s[j] = sensor_now`` (``Pipeline._date``: the STROBE clock at arrival; the caller makes sure
    the clock has a STROBE by then, else the listener would queue it undated); ``future[j]``: the
    listener rejects a carried epoch as epoch_future (t_s > sensor_now + max_future); ``fresh_min[j]``:
    the clock's sensor time at ``m_now[j]`` (the measurement's release: its arrival, or the end of a
    sequence buffer's hold) - stale_before (estimates with an older epoch are stale, not sent). Every
    STROBE is applied (those after the last measurement too).
    Returns the number of future epochs."""
    n = int(st[C_N])
    si = 0
    n_s = s_row.shape[0]
    n_future = 0
    for j in range(m_row.shape[0]):
        r = m_row[j]
        while si < n_s and s_row[si] < r:
            n = _on_strobe(s_ts[si], s_time[si], n, window, prm, st, smp_t, smp_o, hx, hy)
            si += 1
        now = m_time[j]
        if n > 0:
            sn = now + (st[C_INTERCEPT] + st[C_SLOPE] * (now - st[C_REF]))  # as sensor_now
        else:
            sn = math.nan
        if math.isnan(t_s[j]):  # no epoch: dated by the clock at its arrival (Pipeline._date), never future
            t_s[j] = sn
            future[j] = False
        else:
            fut = t_s[j] > sn + max_future
            future[j] = fut
            if fut:
                n_future += 1
        if m_now[j] != now:
            later = m_now[j]
            sn = later + (st[C_INTERCEPT] + st[C_SLOPE] * (later - st[C_REF])) if n > 0 else math.nan
        fresh_min[j] = sn - stale_before
    while si < n_s:
        n = _on_strobe(s_ts[si], s_time[si], n, window, prm, st, smp_t, smp_o, hx, hy)
        si += 1
    st[C_N] = n
    return n_future


def _state_of(clock):
    """(window, st, smp_t, smp_o, hx, hy): a StrobeClock's state as run_strobes / run_clock read it."""
    window = int(clock._cfg.window_strobes)
    samples = list(clock._samples)
    st = np.zeros(NSTATE)
    st[C_SLOPE] = clock._slope
    st[C_REF] = clock._ref_now
    st[C_INTERCEPT] = clock._intercept
    st[C_RESETS] = clock.resets
    st[C_STROBES] = clock.strobes
    st[C_UNCONFIRMED] = clock.unconfirmed
    if clock._candidate is not None:
        st[C_CAND] = clock._candidate
        st[C_HAS_CAND] = 1.0
    st[C_REJECTED] = clock.rejected
    st[C_TROUBLE] = math.nan if clock.trouble_at is None else clock.trouble_at
    st[C_CAND_SINCE] = clock._cand_since
    st[C_ANCHOR_T] = clock._anchor_t
    st[C_ANCHOR_O] = clock._anchor_o
    st[C_ANCHOR_R] = clock._anchor_r
    st[C_N] = len(samples)
    st[C_HEAD] = 0
    size = max(window, 1)
    smp_t = np.zeros(2 * size)
    smp_o = np.zeros(2 * size)
    for i, (t, o) in enumerate(samples):
        smp_t[i] = smp_t[i + size] = t
        smp_o[i] = smp_o[i + size] = o
    return window, st, smp_t, smp_o, np.zeros(size), np.zeros(size)


def _set_state(clock, window, st, smp_t, smp_o) -> None:
    """Leave ``clock`` exactly as the compiled STROBEs left the state."""
    n = int(st[C_N])
    h = int(st[C_HEAD])
    samples = zip(smp_t[h : h + n].tolist(), smp_o[h : h + n].tolist(), strict=True)
    clock._samples = deque(samples, maxlen=window)
    clock._slope = float(st[C_SLOPE])
    clock._ref_now = float(st[C_REF])
    clock._intercept = float(st[C_INTERCEPT])
    clock.resets = int(st[C_RESETS])
    clock.strobes = int(st[C_STROBES])
    clock.unconfirmed = int(st[C_UNCONFIRMED])
    clock._candidate = float(st[C_CAND]) if st[C_HAS_CAND] != 0.0 else None
    clock.rejected = int(st[C_REJECTED])
    clock.trouble_at = None if math.isnan(st[C_TROUBLE]) else float(st[C_TROUBLE])
    clock._cand_since = float(st[C_CAND_SINCE])
    clock._anchor_t = float(st[C_ANCHOR_T])
    clock._anchor_o = float(st[C_ANCHOR_O])
    clock._anchor_r = float(st[C_ANCHOR_R])


def _params(clock) -> np.ndarray:
    """The clock's configuration as the compiled code reads it (slots P_*)."""
    c = clock._cfg
    prm = np.zeros(NPARAM)
    prm[P_MAX_STEP] = c.max_step_s
    prm[P_CONFIRM] = c.confirm_s
    prm[P_DRIFT] = c.max_drift
    prm[P_JITTER] = c.max_jitter_s
    prm[P_RATE] = c.rate
    return prm


def replay_strobes(clock, timestamp: np.ndarray, now: np.ndarray) -> np.ndarray:
    """Advance ``clock`` (a StrobeClock) by the STROBEs as ``on_strobe`` would, in compiled code.

    Returns (k + 1, 4): row 0 the state before the first STROBE, row j + 1 after STROBE j, each as
    (synced, intercept, slope, ref). The clock object is left exactly as the STROBEs would leave it."""
    window, st, smp_t, smp_o, hx, hy = _state_of(clock)
    out = np.zeros((timestamp.shape[0] + 1, 4))
    out[0] = (1.0 if st[C_N] > 0 else 0.0, clock._intercept, clock._slope, clock._ref_now)
    run_strobes(
        np.ascontiguousarray(timestamp, dtype=np.float64),
        np.ascontiguousarray(now, dtype=np.float64),
        window,
        _params(clock),
        st,
        smp_t,
        smp_o,
        hx,
        hy,
        out[1:],
    )
    _set_state(clock, window, st, smp_t, smp_o)
    return out


def replay_clock(clock, strobes, meas, max_future: float, stale_before: float, m_now=None):
    """Advance ``clock`` (a StrobeClock) by the STROBEs ``strobes`` = (datagram index, timestamp, arrival)
    and date the measurements ``meas`` = (datagram index, arrival, epoch) against it on the way, as
    :func:`replay_strobes` and :func:`sensor_now` would (one compiled pass, no per-measurement state rows).

    ``m_now``: the measurements' release times (default: their arrivals). Returns (fresh_min, future,
    number of future epochs): see :func:`run_clock`."""
    window, st, smp_t, smp_o, hx, hy = _state_of(clock)
    m_row = meas[0]
    fresh_min = np.empty(m_row.shape[0])
    future = np.empty(m_row.shape[0], dtype=np.bool_)
    n_future = run_clock(
        *strobes, *meas, meas[1] if m_now is None else m_now, window, _params(clock), float(max_future),
        float(stale_before),
        st, smp_t, smp_o, hx, hy, fresh_min, future,
    )  # fmt: skip
    _set_state(clock, window, st, smp_t, smp_o)
    return fresh_min, future, int(n_future)


def sensor_now(params: np.ndarray, now: np.ndarray) -> np.ndarray:
    """``StrobeClock.to_sensor_time(now)`` per element with the clock state ``params`` (rows as returned by
    :func:`replay_strobes`, one per element); NaN where the clock has no STROBE yet (None)."""
    ic, sl, ref = params[:, 1], params[:, 2], params[:, 3]
    with np.errstate(invalid="ignore", over="ignore"):
        out = now + (ic + sl * (now - ref))  # now + offset_at(now), the same operations in the same order
    return np.where(params[:, 0] != 0.0, out, math.nan)


__all__ = ["clock_supported", "replay_clock", "replay_strobes", "run_clock", "run_strobes", "sensor_now"]
