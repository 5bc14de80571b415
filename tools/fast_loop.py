"""The filter loop of the fast replay: ``sfa.filter.TrackFilter.process`` in compiled code, on one line.

:func:`run_segment` steps packed measurements (layout of ``sfa.batch.Packed``) through the same
``sfa.kernels`` functions, in the same order, as ``TrackFilter`` does with every hypothesis it keeps,
as long as all of them are on one line and share the junctions they have already branched at. It
carries out what ``TrackFilter`` does between the kernel calls, transliterated from sfa/filter.py:

- the reported hypothesis's outcome and NIS, and its estimate after every measurement,
- hypothesis scoring (``_score``: gyro, odometer and GNSS NIS) and pruning (``_prune``: likelihood
  ratio, off the end of the line, duplicates, ``max_hypotheses``, the switch of the reported one),
- the reversed sense of travel kept at standstill (``_spawn_reversals``),

and it stops, handing the measurement back to the caller (which runs ``TrackFilter.process`` on it),
where ``TrackFilter`` would do anything else:

- STOP_BEFORE: before a GROUND TRUTH (initialisation) or a measurement the time-jump rule looks at,
- STOP_AFTER: after a measurement that brings a hypothesis within the junction window of a junction
  it has not branched at (or to an arc length that is not finite): everything up to the last statement
  of ``TrackFilter.process`` is done, and the caller runs that statement, ``_spawn_branches``, itself,
- STOP_UNDONE: after restoring the state from before the measurement, when a hypothesis score would
  not be finite (snapshots are taken only while several hypotheses are kept).

After every processed measurement it also applies the listener's output rule (finite estimate, not
stale against the STROBE clock, epoch not older than the last output, not the same epoch and arc
length) as ``listener.pipeline.Pipeline._maybe_output`` does.
"""

from __future__ import annotations

import hashlib
import math
import os
from pathlib import Path

import numba
import numpy as np
from numba import njit

import sfa
from sfa import gnss_noise
from sfa import kernels as K
from sfa import layout as L


def source_key(paths) -> str:
    """A hash of numba's version and of the files' names and contents (20 hex digits)."""
    h = hashlib.sha256(numba.__version__.encode())
    for path in paths:
        h.update(Path(path).name.encode() + b"\0" + Path(path).read_bytes() + b"\0")
    return h.hexdigest()[:20]


def _keyed_cache_dir() -> str | None:
    """A numba disk-cache directory for this module's loops keyed on the sources they are built from.

    Numba keys a cached function on its own file only; these loops inline ``sfa.kernels`` and read
    ``sfa.layout``'s slots at compile time, so a cache keyed on this file alone would go stale when the
    filter changes. The directory's name is a hash of every ``sfa/*.py`` and of this file: any edit
    there selects a new, empty directory (the loops compile once, about 25 s, then load in well under
    a second). Under ``numba.config.CACHE_DIR`` (``NUMBA_CACHE_DIR``) if set, else beside this file in
    ``__pycache__``; None (no disk cache, compiled per process) where that cannot be written."""
    key = source_key([*sorted(Path(sfa.__file__).parent.glob("*.py")), Path(__file__)])
    base = numba.config.CACHE_DIR or str(Path(__file__).parent / "__pycache__")
    where = os.path.join(base, f"fast_loop-{key}")
    try:
        os.makedirs(where, exist_ok=True)
        probe = os.path.join(where, f".probe-{os.getpid()}")
        with open(probe, "w"):
            pass
        os.remove(probe)
    except OSError:
        return None
    return where


#: where the loops below are cached (numba reads config.CACHE_DIR when a function is decorated, so it is
#: set around their definitions and put back at the end of the module)
CACHE_DIR = _keyed_cache_dir()
_CACHE = CACHE_DIR is not None
_CACHE_DIR_BEFORE = numba.config.CACHE_DIR
if _CACHE:
    numba.config.CACHE_DIR = CACHE_DIR

#: slots of run_segment's ``ost`` (int64[NOST]): next estimate row, estimates not sent as stale, last
#: sent measurement (-1: none yet), its reason bits, smallest and largest line id sent
O_ROW, O_STALE, O_LAST, O_BITS, O_LINE_LO, O_LINE_HI = range(6)
NOST = 6
DONE = 0  #: every measurement processed
STOP_BEFORE = 1  #: stopped before measurement i (state untouched by it)
STOP_UNDONE = 2  #: measurement i was stepped, then undone (state as before it)
STOP_AFTER = 3  #: measurement i was processed up to TrackFilter._spawn_branches, which the caller runs


@njit(cache=_CACHE, _nrt=False)
def _copy1(dst, src):
    """dst[:] = src element by element (the compiled loop runs without numba's allocator, _nrt=False)."""
    for i in range(dst.shape[0]):
        dst[i] = src[i]


@njit(cache=_CACHE, _nrt=False)
def _copy2(dst, src):
    """dst[:, :] = src element by element."""
    for i in range(dst.shape[0]):
        for j in range(dst.shape[1]):
            dst[i, j] = src[i, j]


@njit(cache=_CACHE, _nrt=False, error_model="numpy")  # reads sfa.layout slots (keyed cache)
def _prune(order, ns, X, AUX, length_m, window, prune_ratio, switch_ratio, max_hyps, keep, key):
    """TrackFilter._prune over the hypotheses ``order[:ns[0]]``, reported ``order[ns[1]]`` (finite scores)."""
    nh = ns[0]
    rep = order[ns[1]]
    best = AUX[order[0], L.A_LOGLIK]
    for j in range(1, nh):
        v = AUX[order[j], L.A_LOGLIK]
        if v > best:
            best = v
    # sorted(hyps, key=(h is not reported, -loglik)): the reported one first, the others stably by
    # decreasing score
    m = 0
    keep[m] = rep
    m += 1
    for j in range(nh):
        h = order[j]
        if h == rep:
            continue
        kh = -AUX[h, L.A_LOGLIK]
        p = m
        while p > 1 and key[p - 1] > kh:
            keep[p] = keep[p - 1]
            key[p] = key[p - 1]
            p -= 1
        keep[p] = h
        key[p] = kh
        m += 1
    kept = 0
    for j in range(m):
        h = keep[j]
        if AUX[h, L.A_LOGLIK] < best - prune_ratio:
            continue
        s = X[h, L.S]
        if s > length_m + window or s < -window:
            if nh > 1:
                continue
        dup = False
        for q in range(kept):
            g = keep[q]
            if int(AUX[g, L.A_DIR]) == int(AUX[h, L.A_DIR]) and abs(X[g, L.S] - s) < 1.0:
                dup = True
                break
        if dup:
            continue
        keep[kept] = h  # kept <= j: in place
        kept += 1
    if kept == 0:
        keep[0] = rep
        kept = 1
    if kept > max_hyps:
        kept = max_hyps
    rep_in = False
    for q in range(kept):
        if keep[q] == rep:
            rep_in = True
    lead = keep[0]
    for q in range(1, kept):
        if AUX[keep[q], L.A_LOGLIK] > AUX[lead, L.A_LOGLIK]:
            lead = keep[q]
    if rep_in:
        chosen = lead if AUX[lead, L.A_LOGLIK] > AUX[rep, L.A_LOGLIK] + switch_ratio else rep
    else:
        chosen = lead
    if kept == 1:
        AUX[keep[0], L.A_LOGLIK] = 0.0
    for q in range(kept):
        order[q] = keep[q]
        if keep[q] == chosen:
            ns[1] = q
    ns[0] = kept


@njit(cache=_CACHE, _nrt=False, error_model="numpy")  # reads sfa.layout slots (keyed cache)
def _score(order, nh, AUX, slot, cap):
    """TrackFilter._score's update (before its prune); False when a score is no longer finite."""
    ok = True
    for j in range(nh):
        h = order[j]
        nis = AUX[h, slot]
        AUX[h, L.A_LOGLIK] -= 0.5 * (cap if cap < nis else nis)  # min(nis, cap) as Python evaluates it
        if not math.isfinite(AUX[h, L.A_LOGLIK]):
            ok = False
    return ok


@njit(cache=_CACHE, _nrt=False, error_model="numpy")  # reads sfa.layout slots (keyed cache)
def _spawn_reversals(order, ns, X, PP, AUX, CNT, MEM, cfg):
    """TrackFilter._spawn_reversals' additions (mirrored hypotheses); True when any was added."""
    nh = ns[0]
    cap = X.shape[0]
    total = nh
    for j in range(nh):
        h = order[j]
        if AUX[h, L.A_STILL] == 0.0:
            continue
        dh = int(AUX[h, L.A_DIR])
        twin = False
        for q in range(total):
            g = order[q]
            if int(AUX[g, L.A_DIR]) != dh and abs(X[g, L.S] - X[h, L.S]) < 1.0:
                twin = True
                break
        if twin:
            continue
        free = -1
        for c in range(cap):
            used = False
            for q in range(total):
                if order[q] == c:
                    used = True
                    break
            if not used:
                free = c
                break
        K.sync_block(X[h], PP[h], AUX[h], cfg, CNT[h])  # as TrackFilter's _Hypothesis.mirrored
        _copy1(X[free], X[h])
        _copy2(PP[free], PP[h])
        _copy1(AUX[free], AUX[h])
        _copy1(CNT[free], CNT[h])
        MEM[free, :] = 0.0
        K.mirror(X[free], PP[free], AUX[free])
        order[total] = free
        total += 1
    if total > nh:  # as TrackFilter._empty_gyro_windows: every window (the copies' too) starts empty
        for q in range(total):
            AUX[order[q], L.A_GY_N] = 0.0
    ns[0] = total
    return total > nh


@njit(cache=_CACHE, _nrt=False, error_model="numpy")  # reads sfa.layout slots (keyed cache)
def run_segment(
    kind,
    t,
    vals,
    i0,
    X,
    PP,
    AUX,
    CNT,
    MEM,
    SX,
    SP,
    SA,
    SC,
    SM,
    order,
    ns,
    cfg,
    ts,
    te,
    tn,
    tg,
    tk,
    length_m,
    junc_s,
    window,
    jump_limit,
    cap,
    prune_ratio,
    switch_ratio,
    max_hyps,
    reversal,
    fresh_min,
    last,
    u_out,
    u_nis,
    e_f,
    e_i,
    ost,
    m_time,
    line_id,
    seq0,
    z,
    work_i,
    work_f,
):
    """Step measurements i0, i0 + 1, ... of (kind, t, vals) with the hypotheses ``order[:ns[0]]``
    (slots of X, PP, AUX, CNT, MEM), reported ``order[ns[1]]``; S* are snapshot arrays of the same shapes.

    Per measurement i: its outcome ``u_out[i]`` and NIS ``u_nis[i]`` (NaN for IMU). Per output the listener
    sends (``last``: its last output (epoch, s), advanced), one row r = ost[O_ROW] (then advanced) of the
    replay's estimate columns: e_f[:, r] = epoch [s], s [m], arrival ``m_time[i]`` [s], speed [m/s],
    sigma_s [m], interval low and high (s -+ z sigma) [m]; e_i[:, r] = output SEQ (seq0 + r & 0xFFFF),
    status, ``line_id``. ``ost`` also counts estimates not sent as stale (O_STALE) and holds the last sent
    measurement, its reason bits and the smallest and largest line sent (O_LAST, O_BITS, O_LINE_LO,
    O_LINE_HI). ``work_i`` (2, cap) int64 and ``work_f`` (cap,) are scratch (the loop is compiled without
    numba's allocator and reference counting, ``_nrt=False``: it allocates nothing).
    Returns (i, why): DONE with i = n, STOP_BEFORE / STOP_UNDONE with i the first measurement not
    processed, STOP_AFTER with i the measurement whose branch spawning and output are the caller's.
    """
    n = kind.shape[0]
    nj = junc_s.shape[0]
    keep = work_i[0]
    key = work_f
    s_order = work_i[1]
    for i in range(i0, n):
        k = kind[i]
        ti = t[i]
        v = vals[i]
        if k != 1 and k != 2 and k != 3:
            return i, STOP_BEFORE
        nh = ns[0]
        rep = ns[1]
        if math.isfinite(ti) and ti - AUX[order[rep], L.A_T_STATE] > jump_limit:
            return i, STOP_BEFORE  # TrackFilter._is_time_jump
        if k == 3:  # one GNSS model, the reported hypothesis's (as TrackFilter._process_gps)
            for j in range(nh):
                gnss_noise.share(AUX[order[j]], AUX[order[rep]], j == rep)
        snap = k != 1 and nh > 1  # only a score can need undoing
        if snap:
            for j in range(nh):
                h = order[j]
                s_order[j] = h
                _copy1(SX[h], X[h])
                _copy2(SP[h], PP[h])
                _copy1(SA[h], AUX[h])
                _copy1(SC[h], CNT[h])
                if k == 2:  # step_gps does not take mem; step_odo leaves its IMU ring alone
                    _copy1(SM[h, : L.MEM_HN], MEM[h, : L.MEM_HN])
        code = K.O_INVALID
        accepted = False
        for j in range(nh):
            h = order[j]
            if k == 1:
                c = K.step_imu(
                    X[h],
                    PP[h],
                    AUX[h],
                    CNT[h],
                    MEM[h],
                    cfg,
                    ts,
                    tg,
                    tk,
                    ti,
                    v[0],
                    v[1],
                    v[2],
                    v[3],
                    v[4],
                    v[5],
                )
            elif k == 2:
                c = K.step_odo(X[h], PP[h], AUX[h], CNT[h], MEM[h], cfg, ts, tg, ti, v[0], v[1])
            else:
                fq = -1 if not math.isfinite(v[3]) else int(v[3])
                c = K.step_gps(X[h], PP[h], AUX[h], CNT[h], cfg, ts, te, tn, tg, ti, v[0], v[1], v[2], fq)
            if c == K.O_ACCEPTED:
                accepted = True
            if j == rep:
                code = c
        nis = math.nan
        if k == 2:
            nis = AUX[order[rep], L.A_LAST_NIS_ODO]
        elif k == 3:
            nis = AUX[order[rep], L.A_LAST_NIS_GPS]
        undo = False
        if nh > 1:
            if k == 1:
                all_ok = True
                any_on = False
                for j in range(nh):
                    h = order[j]
                    if not AUX[h, L.A_LAST_NIS_GYRO] >= 0.0:
                        all_ok = False
                    if AUX[h, L.A_GYRO_OK] != 0.0:
                        any_on = True
                if all_ok and any_on:
                    _score(order, nh, AUX, L.A_LAST_NIS_GYRO, cap)  # gyro NIS >= 0: finite scores
                    _prune(
                        order, ns, X, AUX, length_m, window, prune_ratio, switch_ratio, max_hyps, keep, key
                    )
            elif accepted:
                slot = L.A_LAST_NIS_ODO if k == 2 else L.A_LAST_NIS_GPS
                if _score(order, nh, AUX, slot, cap):
                    _prune(
                        order, ns, X, AUX, length_m, window, prune_ratio, switch_ratio, max_hyps, keep, key
                    )
                else:
                    undo = True
        if undo:  # a score that is not finite: sorting by it is Python's business
            for j in range(nh):
                h = s_order[j]
                order[j] = h
                _copy1(X[h], SX[h])
                _copy2(PP[h], SP[h])
                _copy1(AUX[h], SA[h])
                _copy1(CNT[h], SC[h])
                if k == 2:
                    _copy1(MEM[h, : L.MEM_HN], SM[h, : L.MEM_HN])
            ns[0] = nh
            ns[1] = rep
            return i, STOP_UNDONE
        if k == 2 and reversal and AUX[order[ns[1]], L.A_STILL] != 0.0:
            if _spawn_reversals(order, ns, X, PP, AUX, CNT, MEM, cfg):
                _prune(order, ns, X, AUX, length_m, window, prune_ratio, switch_ratio, max_hyps, keep, key)
        branch = False
        if nj > 0 and (k == 3 or (k == 2 and code == K.O_ACCEPTED)):
            # TrackFilter._spawn_branches comes last in process(): when a hypothesis is within the window
            # of a junction not yet branched at (or at a non-finite s: bisect on NaN), the caller runs it
            for j in range(ns[0]):
                s = X[order[j], L.S]
                if not math.isfinite(s):
                    branch = True
                    break
                lo = s - window
                hi = s + window
                for q in range(nj):
                    if lo <= junc_s[q] <= hi:
                        branch = True
                        break
                if branch:
                    break
        u_nis[i] = nis
        u_out[i] = code
        if branch:
            return i, STOP_AFTER
        r = order[ns[1]]
        epoch = AUX[r, L.A_T_STATE]
        s = X[r, L.S]
        if math.isfinite(epoch) and math.isfinite(s):
            if epoch < fresh_min[i]:
                ost[O_STALE] += 1
            elif epoch >= last[0] and not (epoch == last[0] and s == last[1]):
                last[0] = epoch
                last[1] = s
                st, bits, sig = K.status_of(X[r], PP[r], AUX[r], cfg, epoch)  # what the output carries
                put_row(e_f, e_i, ost, i, epoch, s, m_time[i], float(int(AUX[r, L.A_DIR])) * X[r, L.V], sig,
                        st, bits, line_id, seq0, z)  # fmt: skip
    return n, DONE


@njit(cache=_CACHE, _nrt=False)
def put_row(e_f, e_i, ost, i, epoch, s, arrival, speed, sig, status, bits, line_id, seq0, z):
    """One sent output, for measurement i, into the estimate columns at row ost[O_ROW] (see run_segment)."""
    k = ost[O_ROW]
    e_f[0, k] = epoch
    e_f[1, k] = s
    e_f[2, k] = arrival
    e_f[3, k] = speed
    e_f[4, k] = sig
    e_f[5, k] = s - z * sig
    e_f[6, k] = s + z * sig
    e_i[0, k] = (seq0 + k) & 0xFFFF
    e_i[1, k] = status
    e_i[2, k] = line_id
    e_i[3, k] = bits
    if ost[O_LAST] < 0 or line_id < ost[O_LINE_LO]:
        ost[O_LINE_LO] = line_id
    if ost[O_LAST] < 0 or line_id > ost[O_LINE_HI]:
        ost[O_LINE_HI] = line_id
    ost[O_LAST] = i
    ost[O_BITS] = bits
    ost[O_ROW] = k + 1


@njit(cache=_CACHE)  # calls sfa.kernels.interp_at (keyed cache)
def interp_many(ts, arr, s, valid):
    """``sfa.kernels.interp_at`` per element where ``valid`` and ts[0] <= s <= ts[-1]; NaN elsewhere.

    The segment search starts from the previous element's segment (``seg_hint``: the same segment as
    ``interp_at``'s binary search, found in O(1) along a trajectory)."""
    out = np.full(s.shape[0], np.nan)
    lo = ts[0]
    hi = ts[ts.shape[0] - 1]
    hint = np.zeros(L.NAUX)
    for i in range(s.shape[0]):
        if valid[i] and lo <= s[i] <= hi:
            out[i] = K.interp_seg(ts, arr, s[i], K.seg_hint(ts, s[i], hint))
    return out


@njit(cache=_CACHE)
def run_replay_loop(
    kind, t, vals, x, P, aux, cnt, mem, cfg, ts, te, tn, tg, tk, last_epoch, last_s, out_f, out_i
):
    """``sfa.batch.run_packed``'s loop with the NIS and the output rule (no hypotheses, no stale rule):
    the reference ``sfa bench`` checks ``run_packed``'s disk-cached compile against. Returns the outputs."""
    n = kind.shape[0]
    outputs = 0
    for i in range(n):
        k = kind[i]
        ti = t[i]
        v = vals[i]
        nis = math.nan
        if k == 1:
            o = K.step_imu(x, P, aux, cnt, mem, cfg, ts, tg, tk, ti, v[0], v[1], v[2], v[3], v[4], v[5])
        elif k == 2:
            o = K.step_odo(x, P, aux, cnt, mem, cfg, ts, tg, ti, v[0], v[1])
            nis = aux[L.A_LAST_NIS_ODO]
        elif k == 3:
            fq = -1 if not math.isfinite(v[3]) else int(v[3])
            o = K.step_gps(x, P, aux, cnt, cfg, ts, te, tn, tg, ti, v[0], v[1], v[2], fq)
            nis = aux[L.A_LAST_NIS_GPS]
        elif k == 8:
            o = K.step_init(x, P, aux, cnt, mem, cfg, ts, tg, ti, v[0], v[1], v[3])
        else:
            o = K.O_INVALID
        epoch = aux[L.A_T_STATE]
        st, bits, sig = K.status_of(x, P, aux, cfg, epoch)
        s = x[L.S]
        out_f[i, 0] = epoch
        out_f[i, 1] = s
        out_f[i, 2] = x[L.V]
        out_f[i, 3] = sig
        out_f[i, 4] = nis
        out_i[i, 0] = o
        out_i[i, 1] = st
        out_i[i, 2] = bits
        send = 0
        if math.isfinite(epoch) and math.isfinite(s) and epoch >= last_epoch:
            if not (epoch == last_epoch and s == last_s):
                send = 1
                last_epoch = epoch
                last_s = s
                outputs += 1
        out_i[i, 3] = send
    return outputs


numba.config.CACHE_DIR = _CACHE_DIR_BEFORE
