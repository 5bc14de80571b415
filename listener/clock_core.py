"""The STROBE clock's arithmetic, once: compiled kernels over one explicit state array (sans-I/O).

:class:`listener.clock.StrobeClock` (the listener, per STROBE) and the fast replay (every STROBE of a
capture in one compiled loop, :func:`run_strobes` / :func:`sensor_times`) run these same functions on
the same state, so the two cannot drift apart. The rules (lower-delay envelope, the skew by the
linear-programming method of Moon, Skelly and Towsley, the drift bound, candidates and resets) are
described in :mod:`listener.clock`.

The kernels are decorated with :func:`sfa.engine.njit`: ``sfa listen`` runs the copies compiled ahead
of time into the engine extension (:data:`sfa.engine_build.ENTRY_POINTS`: :func:`on_strobe`,
:func:`offset_at`, :func:`sensor_time`), every other process numba's JIT of the same source, which
computes the same bits.

State layout (float64, :func:`new_state`): the scalar slots ``C_*``, the configuration ``P_*``, then
four regions of ``W`` = ``clock.window_strobes``: the window's arrival times and offsets, each kept in
a mirrored buffer of ``2 W`` (sample slot ``p`` also at ``p + W``, so the window is always one
contiguous stretch from ``C_HEAD`` and dropping the oldest sample moves nothing), and two hull
scratch regions of ``W``. Sums and maxima run oldest sample first with the float operations of the
original Python (``sum`` is a plain left-to-right sum, ``max``/``min`` keep the first of equals), so
the model is the one the listener has always computed.
"""

from __future__ import annotations

import math

import numpy as np

from sfa.engine import njit

# scalar slots
C_SLOPE = 0  #: skew of the model [s/s]
C_REF = 1  #: listener time the model's intercept refers to [s]
C_INTERCEPT = 2  #: model offset (sensor time - listener time) at C_REF [s]
C_RESETS = 3  #: times the model was restarted by a confirmed step
C_STROBES = 4  #: STROBEs used
C_UNCONFIRMED = 5  #: STROBEs that disagreed with the model and became a (new) candidate
C_CAND = 6  #: candidate offset [s] (meaningful when C_HAS_CAND != 0)
C_HAS_CAND = 7
C_N = 8  #: samples in the window
C_HEAD = 9  #: slot of the oldest sample in the mirrored buffers
C_REJECTED = 10  #: STROBEs not taken
C_TROUBLE = 11  #: listener time of the last STROBE not taken (NaN: none)
C_CAND_SINCE = 12  #: listener time the candidate was first seen [s]
C_ANCHOR_T = 13  #: start of the model t_0 [s]
C_ANCHOR_O = 14  #: settled offset o_0 at t_0 [s]
C_ANCHOR_R = 15  #: settled rate (NaN while settling) [sensor s per listener s]
# configuration slots (listener.config.ClockConfig)
P_WINDOW = 16  #: window_strobes [count]
P_MAX_STEP = 17  #: max_step_s [s]
P_CONFIRM = 18  #: confirm_s [s]
P_DRIFT = 19  #: max_drift [-]
P_JITTER = 20  #: max_jitter_s [s]
P_RATE = 21  #: rate [sensor s per listener s]
HEADER = 22  #: the sample regions start here


def new_state(cfg) -> np.ndarray:
    """A clock that has seen no STROBE, configured by ``cfg`` (a ClockConfig)."""
    window = int(cfg.window_strobes)
    if window < 1:
        raise ValueError(f"clock.window_strobes = {window}: must be >= 1")
    s = np.zeros(HEADER + 6 * window)
    s[C_TROUBLE] = math.nan
    s[C_ANCHOR_R] = math.nan
    s[P_WINDOW] = window
    s[P_MAX_STEP] = cfg.max_step_s
    s[P_CONFIRM] = cfg.confirm_s
    s[P_DRIFT] = cfg.max_drift
    s[P_JITTER] = cfg.max_jitter_s
    s[P_RATE] = cfg.rate
    return s


def window_of(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(arrival times, offsets) of the samples in the window, oldest first (copies)."""
    w, n, h = int(s[P_WINDOW]), int(s[C_N]), int(s[C_HEAD])
    t0 = HEADER + h
    o0 = HEADER + 2 * w + h
    return s[t0 : t0 + n].copy(), s[o0 : o0 + n].copy()


@njit(cache=True, _nrt=False)
def _fit(s, w, h0, n):
    """The model over the n samples from slot h0 (the upper envelope, and the skew once the window
    spans 10 samples and 20 s)."""
    ts = HEADER + h0  # arrival times of the window, oldest first
    os_ = HEADER + 2 * w + h0  # their offsets
    hx = HEADER + 4 * w  # hull scratch
    hy = HEADER + 5 * w
    rate = s[P_RATE]
    ref = s[ts + n - 1]
    slope = 0.0
    intercept = s[os_]
    for i in range(1, n):
        if s[os_ + i] > intercept:
            intercept = s[os_ + i]
    if rate != 1.0:
        # an accelerated sensor clock: the offset grows by (rate - 1) s per second, from the start
        slope = rate - 1.0
        intercept = s[os_] - slope * (s[ts] - ref)
        for i in range(1, n):
            v = s[os_ + i] - slope * (s[ts + i] - ref)
            if v > intercept:
                intercept = v
    if n >= 10 and s[ts + n - 1] - s[ts] >= 20.0:
        # Linear-programming skew estimate (Moon, Skelly & Towsley, 1999): the line above every point
        # that minimises the summed vertical distance is the upper-hull edge spanning the mean time.
        # Delay jitter only pushes points down, so it never moves that line.
        m = 0  # upper convex hull (Andrew's monotone chain)
        for i in range(n):
            px = s[ts + i]
            py = s[os_ + i]
            while m >= 2:
                x1 = s[hx + m - 2]
                y1 = s[hy + m - 2]
                x2 = s[hx + m - 1]
                y2 = s[hy + m - 1]
                # drop the middle point if it lies on or below the segment from hull[-2] to p
                if (x2 - x1) * (py - y1) - (y2 - y1) * (px - x1) >= 0:
                    m -= 1
                else:
                    break
            s[hx + m] = px
            s[hy + m] = py
            m += 1
        acc = 0.0
        for i in range(n):
            acc = acc + s[ts + i]
        t_mean = acc / n
        for j in range(m - 1):
            ta = s[hx + j]
            oa = s[hy + j]
            tb = s[hx + j + 1]
            ob = s[hy + j + 1]
            if ta <= t_mean <= tb and tb > ta:
                slope = (ob - oa) / (tb - ta)
                break
        # |skew| <= 1000 ppm around the nominal rate: anything larger is not a clock
        # (max(lo, min(hi, slope)): the first argument unless the second wins, as Python's min/max)
        if rate == 1.0:
            lo, hi = -1e-3, 1e-3
        else:
            lo, hi = rate - 1.0 - 1e-3 * rate, rate - 1.0 + 1e-3 * rate
        c = slope if slope < hi else hi
        slope = c if c > lo else lo
        intercept = s[os_] - slope * (s[ts] - ref)
        for i in range(1, n):
            v = s[os_ + i] - slope * (s[ts + i] - ref)
            if v > intercept:
                intercept = v
    s[C_INTERCEPT] = intercept
    s[C_SLOPE] = slope
    s[C_REF] = ref


@njit(cache=True, _nrt=False)
def _settle(s, w, h0, n):
    """End of the settling period: the rate the source has shown (``clock.rate`` unless it is more
    than 2 % off) and the least delayed offset at the model's start, o_0, on that rate."""
    ts = HEADER + h0
    os_ = HEADER + 2 * w + h0
    rate = s[P_RATE]
    t0 = s[ts]
    o0 = s[os_]
    t1 = s[ts + n - 1]
    o1 = s[os_ + n - 1]
    r = rate
    if t1 > t0:
        raw = 1.0 + (o1 - o0) / (t1 - t0)
        if abs(raw - rate) > 0.02 * rate:
            r = raw
    s[C_ANCHOR_R] = r
    ta = s[C_ANCHOR_T]
    best = o0 - (r - 1.0) * (t0 - ta)
    for i in range(1, n):
        v = s[os_ + i] - (r - 1.0) * (s[ts + i] - ta)
        if v > best:
            best = v
    s[C_ANCHOR_O] = best


@njit(cache=True, _nrt=False)
def on_strobe(s, timestamp_s, now):
    """Take one STROBE: sensor-set ``timestamp_s`` received at listener time ``now`` (non-finite
    values are ignored). Returns 1 if it was taken into the model, else 0."""
    if not (math.isfinite(timestamp_s) and math.isfinite(now)):
        return 0
    w = int(s[P_WINDOW])
    n = int(s[C_N])
    offset = timestamp_s - now
    max_step = s[P_MAX_STEP]
    confirm = s[P_CONFIRM]
    if n > 0:
        predicted = _offset(s[C_INTERCEPT], s[C_SLOPE], s[C_REF], now)
        since = now - s[C_ANCHOR_T]
        bad = abs(offset - predicted) > max_step
        if not bad and since >= confirm:
            if math.isnan(s[C_ANCHOR_R]):
                _settle(s, w, int(s[C_HEAD]), n)
            r = s[C_ANCHOR_R]
            bad = offset > s[C_ANCHOR_O] + (r - 1.0 + s[P_DRIFT] * r) * since + s[P_JITTER]
        if bad:
            # a step, or faster than the drift bound: believed only once STROBEs agreeing with it persist
            # for confirm_s with none agreeing with the model (one corrupted timestamp, or a forger's
            # stream beside the real one, must not move the timebase); agreeing with the candidate:
            # within max_step_s of it, carried at the rate, so a lone source off the bound is followed
            agree = False
            if s[C_HAS_CAND] != 0.0:
                age = now - s[C_CAND_SINCE]
                rc = s[P_RATE] if math.isnan(s[C_ANCHOR_R]) else s[C_ANCHOR_R]
                agree = not abs(offset - (rc - 1.0) * age - s[C_CAND]) > max_step
            if not agree:
                s[C_CAND] = offset
                s[C_HAS_CAND] = 1.0
                s[C_CAND_SINCE] = now
                s[C_UNCONFIRMED] += 1.0
                s[C_REJECTED] += 1.0
                s[C_TROUBLE] = now
                return 0
            if now - s[C_CAND_SINCE] < confirm:
                s[C_REJECTED] += 1.0
                s[C_TROUBLE] = now
                return 0
            n = 0  # the candidate persisted: a reset, the window restarts with this STROBE
            s[C_RESETS] += 1.0
    s[C_HAS_CAND] = 0.0
    if n == 0:
        s[C_ANCHOR_T] = now
        s[C_ANCHOR_O] = offset
        s[C_ANCHOR_R] = math.nan
    head = int(s[C_HEAD])
    if n == w:  # a full window drops its oldest sample
        head += 1
        if head == w:
            head = 0
        n -= 1
    p = head + n
    if p >= w:
        p -= w
    s[HEADER + p] = now
    s[HEADER + p + w] = now
    s[HEADER + 2 * w + p] = offset
    s[HEADER + 3 * w + p] = offset
    n += 1
    s[C_N] = n
    s[C_HEAD] = head
    s[C_STROBES] += 1.0
    _fit(s, w, head, n)
    return 1


@njit(cache=True, _nrt=False)
def _offset(intercept, slope, ref, now):
    return intercept + slope * (now - ref)


@njit(cache=True, _nrt=False)
def offset_at(s, now):
    """Estimated ``sensor_time - now`` at listener time ``now`` [s]."""
    return _offset(s[C_INTERCEPT], s[C_SLOPE], s[C_REF], now)


@njit(cache=True, _nrt=False)
def sensor_time(s, now):
    """Sensor-set time of a measurement that arrived at ``now``; NaN before the first STROBE."""
    if s[C_N] == 0.0:
        return math.nan
    return now + _offset(s[C_INTERCEPT], s[C_SLOPE], s[C_REF], now)


@njit(cache=True, _nrt=False)
def run_strobes(s, timestamp, now, out):
    """:func:`on_strobe` for every STROBE (sensor-set ``timestamp[k]`` received at ``now[k]``), in order;
    ``out[k]`` = (synced, intercept, slope, ref) after STROBE k."""
    for k in range(timestamp.shape[0]):
        on_strobe(s, timestamp[k], now[k])
        out[k, 0] = 1.0 if s[C_N] > 0.0 else 0.0
        out[k, 1] = s[C_INTERCEPT]
        out[k, 2] = s[C_SLOPE]
        out[k, 3] = s[C_REF]


@njit(cache=True, _nrt=False)
def sensor_times(s, s_pos, s_ts, s_time, q_pos, q_a, q_b, out_a, out_b):
    """The STROBEs (position ``s_pos``, timestamp ``s_ts``, arrival ``s_time``) and the queries (position
    ``q_pos``, two listener times ``q_a``, ``q_b`` each) of a stretch, in position order (both ascend):
    ``out_a[j]``, ``out_b[j]`` = :func:`sensor_time` at ``q_a[j]``, ``q_b[j]`` with the clock as the
    STROBEs before position ``q_pos[j]`` left it. Every STROBE is applied (those after the last query
    too)."""
    si = 0
    n_s = s_pos.shape[0]
    for j in range(q_pos.shape[0]):
        while si < n_s and s_pos[si] < q_pos[j]:
            on_strobe(s, s_ts[si], s_time[si])
            si += 1
        out_a[j] = sensor_time(s, q_a[j])
        out_b[j] = sensor_time(s, q_b[j])
    while si < n_s:
        on_strobe(s, s_ts[si], s_time[si])
        si += 1


@njit(cache=True, _nrt=False)
def model_sensor_times(rows, now, out):
    """``out[k]`` = :func:`sensor_time` at ``now[k]`` for the model ``rows[k]`` = (synced, intercept,
    slope, ref) as :func:`run_strobes` records it."""
    for k in range(now.shape[0]):
        if rows[k, 0] == 0.0:
            out[k] = math.nan
        else:
            out[k] = now[k] + _offset(rows[k, 1], rows[k, 2], rows[k, 3], now[k])
