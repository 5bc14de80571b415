"""The filter's hypothesis bank: every line / direction hypothesis as a slot of arrays, and the compiled
rules that step, score, prune and mirror them.

One implementation for every user: ``sfa.filter.TrackFilter.process`` runs :func:`run_segment` over a run
of one measurement, and ``TrackFilter.run`` (the replay) over a run of packed measurements
(``sfa.batch.Packed`` layout). Slots (``sfa.layout`` names the columns):

- ``X[slot]`` state (NX), ``PP[slot]`` covariance (NX, NX), ``AUX[slot]`` auxiliary scalars (NAUX),
  ``CNT[slot]`` counters (NCNT), ``MEM[slot]`` rewind memory (NMEM);
- ``IDX[:, slot]``: the slot's line (an index into :class:`Lines`), the set of junctions its lineage
  has branched at (an index into :attr:`HypothesisBank.spawn_sets`) and, as a range of ``JS``, the arc
  lengths on its line of the junctions it has not branched at yet;
- ``order[:ns[0]]`` the live slots in the filter's order (the order scoring, pruning and spawning see,
  the one ``TrackFilter`` kept its hypothesis list in), ``order[ns[1]]`` the reported one.

The rules, from docs/filter.md ("Line hypotheses"): the score is the robust log-likelihood -NIS/2
(capped at ``loglik_nis_cap``; for a GNSS fix under a learned model the Student-t's, with that model's
degrees of freedom) of gyro windows, odometer samples and GNSS fixes at least one hypothesis
accepted (:func:`score`); pruning drops a hypothesis whose score trails the best by more than
``prune_log_ratio``, one off the end of its line while others remain, duplicates (:func:`same_track`)
and the excess over ``max_hypotheses``, and keeps the reported one unless another leads by
``switch_log_ratio`` (:func:`prune`); at standstill the mirrored sense of travel is kept too
(:func:`spawn_reversals`). Spawning branches at junctions needs the track database and stays in
Python (``TrackFilter._spawn_branches``): :func:`run_segment` stops after a measurement that brings a
hypothesis within the junction window of a junction it has not branched at, and its caller runs it.

The loop's parameters reach it by name, as slots of the configuration vector (``cfg``,
``FilterConfig.to_array``): ``K_JUNCTION_WINDOW``, ``K_PRUNE_LOG_RATIO``, ``K_SWITCH_LOG_RATIO``,
``K_MAX_HYPOTHESES``, ``K_REVERSAL``, ``K_MAX_TIME_JUMP``, ``K_GPS_MAX_LOGLIK_NIS``, ``K_Z_INTERVAL``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from sfa import gnss_noise
from sfa import kernels as K
from sfa import layout as L
from sfa import separation as SEP
from sfa.engine import njit  # numba.njit on the JIT; exported by the compiled engine (sfa.engine_build)

# rows of IDX (int64[NIDX, cap]), per slot
I_LINE = 0  #: index of the slot's line in Lines
I_SPAWN = 1  #: index of the junction set its lineage branched at (HypothesisBank.spawn_sets)
I_JLO = 2  #: its junctions not branched at yet: JS[I_JLO:I_JHI] (arc lengths on its line) [m]
I_JHI = 3
NIDX = 4

# rows of the packed line geometry G (float64[NG, total vertices])
G_S, G_E, G_N, G_GRADE, G_CURV = range(5)
NG = 5

#: slots of the replay output state ``ost`` (int64[NOST]): next estimate row, estimates not sent as
#: stale, last sent measurement (-1: none yet), its reason bits, smallest and largest line id sent
O_ROW, O_STALE, O_LAST, O_BITS, O_LINE_LO, O_LINE_HI = range(6)
NOST = 6
NEF = 7  #: rows of the estimate columns e_f: epoch, s, arrival, speed, sigma, interval low and high
NEI = 4  #: rows of e_i: output SEQ, status, line id, reason bits

DONE = 0  #: every measurement processed
STOP_BEFORE = 1  #: stopped before measurement i (state untouched by it): TrackFilter.process takes it
STOP_AFTER = 3  #: measurement i processed up to the junction spawning, which the caller runs


# ------------------------------------------------------------------------------ compiled rules
@njit(cache=True, _nrt=False)
def _copy_slot(dst, src, X, PP, AUX, CNT, MEM, IDX, keep_mem):
    """Slot dst = a copy of slot src; its rewind memory empty unless ``keep_mem`` (the snapshots are of
    another line or sense of travel)."""
    for i in range(X.shape[1]):
        X[dst, i] = X[src, i]
    for i in range(PP.shape[1]):
        for j in range(PP.shape[2]):
            PP[dst, i, j] = PP[src, i, j]
    for i in range(AUX.shape[1]):
        AUX[dst, i] = AUX[src, i]
    for i in range(CNT.shape[1]):
        CNT[dst, i] = CNT[src, i]
    for i in range(MEM.shape[1]):
        MEM[dst, i] = MEM[src, i] if keep_mem else 0.0
    for i in range(IDX.shape[0]):
        IDX[i, dst] = IDX[i, src]


@njit(cache=True, _nrt=False)
def twin(order, n, X, AUX, IDX, h):
    """True when one of ``order[:n]`` is on h's line, the other sense of travel, within 1 m of it: the
    reversal of h is already kept (and the estimate's direction is ambiguous)."""
    dh = int(AUX[h, L.A_DIR])
    for q in range(n):
        g = order[q]
        if IDX[I_LINE, g] == IDX[I_LINE, h] and int(AUX[g, L.A_DIR]) != dh \
                and abs(X[g, L.S] - X[h, L.S]) < 1.0:
            return True
    return False


@njit(cache=True, _nrt=False, error_model="numpy")
def _ahead(q, X, AUX, IDX, G, LOFF, ahead):
    """(on the line, east, north now, east, north ``ahead`` metres on, direction of travel east, north)
    of slot q; False first when it or the point ahead is off its line."""
    d = int(AUX[q, L.A_DIR])
    s0 = X[q, L.S]
    s1 = s0 + d * ahead
    a = LOFF[IDX[I_LINE, q]]
    b = LOFF[IDX[I_LINE, q] + 1]
    ts = G[G_S, a:b]
    if not (ts[0] <= s0 <= ts[b - a - 1] and ts[0] <= s1 <= ts[b - a - 1]):
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    e0, n0, de, dn = K.geom_at(ts, G[G_E, a:b], G[G_N, a:b], s0)
    e1, n1, _, _ = K.geom_at(ts, G[G_E, a:b], G[G_N, a:b], s1)
    return True, e0, n0, e1, n1, d * de, d * dn


@njit(cache=True, _nrt=False, error_model="numpy")
def same_track(g, h, X, AUX, IDX, G, LOFF, window):
    """True when slot h duplicates slot g: the same line, sense of travel and place (within 1 m); or
    another line that runs on g's track: the same place and way of travel in the plane now and 2 x the
    junction window ahead (several routes of a network share one track: hypotheses on them cannot be
    told apart until the lines part, where that junction spawns them again). A branch just spawned is
    not a duplicate: 2 x the window ahead reaches at least one window past its junction, where the
    lines have parted."""
    if IDX[I_LINE, g] == IDX[I_LINE, h]:
        return int(AUX[g, L.A_DIR]) == int(AUX[h, L.A_DIR]) and abs(X[g, L.S] - X[h, L.S]) < 1.0
    ok, ga, gb, gc, gd, gu, gv = _ahead(g, X, AUX, IDX, G, LOFF, 2.0 * window)
    if not ok:
        return False
    ok, ha, hb, hc, hd, hu, hv = _ahead(h, X, AUX, IDX, G, LOFF, 2.0 * window)
    if not ok:
        return False
    return (math.hypot(ga - ha, gb - hb) < 1.0 and math.hypot(gc - hc, gd - hd) < 1.0
            and gu * hu + gv * hv > 0.0)


@njit(cache=True, _nrt=False, error_model="numpy")
def score(order, nh, AUX, slot, cap, weight, dof, dim):
    """The hypotheses' score update (before the prune): loglik -= weight min(NIS, cap) / 2 with the NIS
    in ``slot`` (the normal), or with ``dof`` > 0 the Student-t's weight (dof + dim) / 2 log(1 +
    min(NIS, cap) / dof) for a ``dim``-dimensional measurement (GNSS under a learned model:
    gnss_noise.score_dof); a NIS that is not a number counts as the cap (the worst a measurement
    scores). ``weight`` is the share of an independent measurement's evidence the measurement carries
    (1, or for GNSS the CUSUM's rate weight, see run_segment)."""
    for j in range(nh):
        h = order[j]
        nis = AUX[h, slot]
        x = nis if nis < cap else cap
        if dof > 0.0:
            AUX[h, L.A_LOGLIK] -= weight * 0.5 * (dof + dim) * math.log1p(x / dof)  # -log t
        else:
            AUX[h, L.A_LOGLIK] -= weight * 0.5 * x  # -log normal


@njit(cache=True, _nrt=False, error_model="numpy")
def score_log_s(order, nh, AUX, slot, weight):
    """The normal log-likelihood's other term: loglik -= weight log S / 2 with S in ``slot``. With
    it a hypothesis does not gain by predicting a wider spread (a gyro window on a curve, whose
    curvature error is larger, against one on a straight: a score of NIS alone favoured the curve's).
    ``weight``, the same for every hypothesis so that the unit of S cancels, is the share of an
    independent measurement the measurement carries."""
    for j in range(nh):
        h = order[j]
        AUX[h, L.A_LOGLIK] -= weight * 0.5 * math.log(AUX[h, slot])


@njit(cache=True, _nrt=False, error_model="numpy")
def prune(order, ns, X, AUX, IDX, G, LOFF, LLEN, cfg, keep, key):
    """Prune ``order[:ns[0]]`` (reported ``order[ns[1]]``) as the module docstring says; ``keep`` (int64)
    and ``key`` (float64) are scratch of the bank's capacity."""
    window = cfg[L.K_JUNCTION_WINDOW]
    nh = ns[0]
    rep = order[ns[1]]
    best = AUX[order[0], L.A_LOGLIK]
    for j in range(1, nh):
        v = AUX[order[j], L.A_LOGLIK]
        if v > best:
            best = v
    # the reported one first, the others stably by decreasing score
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
        if AUX[h, L.A_LOGLIK] < best - cfg[L.K_PRUNE_LOG_RATIO]:
            continue
        s = X[h, L.S]
        if s > LLEN[IDX[I_LINE, h]] + window or s < -window:
            if nh > 1:
                continue  # ran off the end of its line while others remain
        dup = False
        for q in range(kept):
            if same_track(keep[q], h, X, AUX, IDX, G, LOFF, window):
                dup = True
                break
        if dup:
            continue
        keep[kept] = h  # kept <= j: in place
        kept += 1
    if kept == 0:
        keep[0] = rep
        kept = 1
    max_hyps = int(cfg[L.K_MAX_HYPOTHESES])
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
        chosen = lead if AUX[lead, L.A_LOGLIK] > AUX[rep, L.A_LOGLIK] + cfg[L.K_SWITCH_LOG_RATIO] else rep
    else:
        chosen = lead
    if kept == 1:
        AUX[keep[0], L.A_LOGLIK] = 0.0  # alone: restart the score so it never drifts
    for q in range(kept):
        order[q] = keep[q]
        if keep[q] == chosen:
            ns[1] = q
    ns[0] = kept


@njit(cache=True, _nrt=False)
def empty_gyro_windows(order, n, AUX):
    """After new hypotheses: every gyro window starts empty, so that all close at the same sample (the
    likelihood compares their NIS there) and none of a copy's residuals, taken on its parent's line or
    sense of travel, is applied to it."""
    for q in range(n):
        AUX[order[q], L.A_GY_N] = 0.0


@njit(cache=True, _nrt=False)
def free_slot(order, n, cap):
    """The first slot not in ``order[:n]`` (-1 when all ``cap`` are used)."""
    for c in range(cap):
        used = False
        for q in range(n):
            if order[q] == c:
                used = True
                break
        if not used:
            return c
    return -1


@njit(cache=True, _nrt=False, error_model="numpy")
def spawn_reversals(order, ns, X, PP, AUX, CNT, MEM, IDX, cfg):
    """At standstill the train may change its sense of travel: add the mirrored copy of every standing
    hypothesis whose reversal is not kept yet (its P synced first); True when any was added (the
    caller prunes)."""
    nh = ns[0]
    total = nh
    for j in range(nh):
        h = order[j]
        if AUX[h, L.A_STILL] == 0.0 or twin(order, total, X, AUX, IDX, h):
            continue
        free = free_slot(order, total, X.shape[0])
        if free < 0:  # (the bank keeps twice max_hypotheses + 2 slots: never)
            break
        K.sync_block(X[h], PP[h], AUX[h], cfg, CNT[h])
        _copy_slot(free, h, X, PP, AUX, CNT, MEM, IDX, False)
        K.mirror(X[free], PP[free], AUX[free])
        AUX[free, L.A_LOGLIK] -= cfg[L.K_REVERSAL_PRIOR]  # a reversal is a priori unlikely
        order[total] = free
        total += 1
    if total > nh:
        empty_gyro_windows(order, total, AUX)
    ns[0] = total
    return total > nh


@njit(cache=True, _nrt=False, error_model="numpy")
def _mass_inside(lo, hi, s, sig):
    """Probability that N(s, sig^2) lies in [lo, hi] (a point mass for sig = 0)."""
    if sig > 0.0:
        k = 1.0 / (sig * math.sqrt(2.0))
        return 0.5 * (math.erf((hi - s) * k) - math.erf((lo - s) * k))
    return 1.0 if lo <= s <= hi else 0.0


@njit(cache=True, _nrt=False, error_model="numpy")
def _on_line(h, r, AUX, IDX):
    """Whether slot h is a live hypothesis on the reported slot r's line (r itself included)."""
    return IDX[I_LINE, h] == IDX[I_LINE, r] and AUX[h, L.A_INIT] != 0.0


@njit(cache=True, _nrt=False, error_model="numpy")
def _mixture_mass(order, n, X, sg, lo, hi):
    """Mass in [lo, hi] of the mixture of hypotheses ``order[:n]`` with spreads ``sg[:n]`` and weights
    ``sg[n:2n]`` (zero: not in the mixture)."""
    m = 0.0
    for q in range(n):
        w = sg[n + q]
        if w != 0.0:
            m += w * _mass_inside(lo, hi, X[order[q], L.S], sg[q])
    return m


@njit(cache=True, _nrt=False, error_model="numpy")
def status(order, n, X, PP, AUX, IDX, cfg, r, t, sg):
    """(status, reason bits, sigma_s) the output carries for the reported slot r at time t: its own
    (``K.status_of``), widened while other hypotheses on its line are alive so that the interval
    s_r +- z sigma_s holds the confidence (erf(z / sqrt 2), 95 %) of their mixture: each hypothesis h a
    normal N(s_h, sigma_h^2) (its own reported sigma) weighted by its share exp(score) of the line's
    hypotheses (the score is the log-likelihood, with the reversal prior: ``score``, ``prune``).

    Two senses of travel alive at a departure part at twice the speed: while both hold a share the
    interval spans both, whichever is reported (the report only changes at a lead of
    ``switch_log_ratio``, so a reported hypothesis can hold as little as 1 %). A copy at its prior's
    1 % (a reversal spawned at a stop, nothing to tell it apart in a GNSS outage) widens the interval
    only by the 1 % it takes from the reported one's mass. Hypotheses on other lines have another
    line's arc lengths (and the output names r's line): the mixture is the reported line's.
    ``sg`` (float64, twice the bank's capacity): scratch for the hypotheses' sigmas ``sg[:n]`` and
    mixture weights ``sg[n:2n]``."""
    st, bits, sig = K.status_of(X[r], PP[r], AUX[r], cfg, t)
    z = cfg[L.K_Z_INTERVAL]
    ll0 = AUX[r, L.A_LOGLIK]
    others = 0
    for q in range(n):
        h = order[q]
        sg[n + q] = 0.0
        if not _on_line(h, r, AUX, IDX):
            continue
        sg[n + q] = 1.0  # in the mixture; its weight below
        if h != r:
            others += 1
        if AUX[h, L.A_LOGLIK] > ll0:
            ll0 = AUX[h, L.A_LOGLIK]
    if others == 0 or not (math.isfinite(sig) and math.isfinite(ll0)):
        return st, bits, sig
    wsum = 0.0
    far = z * sig
    for q in range(n):
        if sg[n + q] == 0.0:
            continue
        h = order[q]
        _, _, sg[q] = K.status_of(X[h], PP[h], AUX[h], cfg, t)
        sg[n + q] = math.exp(AUX[h, L.A_LOGLIK] - ll0)
        wsum += sg[n + q]
        reach = abs(X[h, L.S] - X[r, L.S]) + 10.0 * sg[q]  # beyond: mass 1 - 1e-23
        if not reach <= far:
            far = reach
    if not math.isfinite(far):  # a sigma gone infinite or NaN: so is the interval
        st, bits = K.classify(bits, far, cfg)
        return st, bits, far
    for q in range(n):
        sg[n + q] /= wsum  # the shares, summing to 1
    conf = math.erf(z / math.sqrt(2.0))
    s_r = X[r, L.S]
    lo = z * sig
    if _mixture_mass(order, n, X, sg, s_r - lo, s_r + lo) >= conf:
        return st, bits, sig
    hi = far
    for _ in range(64):  # bisection on the half-width: the mass grows with it
        mid = 0.5 * (lo + hi)
        if _mixture_mass(order, n, X, sg, s_r - mid, s_r + mid) >= conf:
            hi = mid
        else:
            lo = mid
        if hi - lo <= 1e-9 * hi:
            break
    wide = hi / z  # the smallest half-width found that holds the confidence, over z
    st, bits = K.classify(bits, wide, cfg)
    return st, bits, wide


@njit(cache=True, _nrt=False)
def put_row(e_f, e_i, ost, i, epoch, s, arrival, speed, sig, status, bits, line_id, seq0, z):
    """One sent output, for measurement i, into the estimate columns at row ost[O_ROW]."""
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


@njit(cache=True, _nrt=False, error_model="numpy")
def emit(i, X, PP, AUX, IDX, order, ns, cfg, LID, fresh_min, last, m_time, e_f, e_i, ost, seq0, work_f):
    """The listener's output rule on the estimate after measurement i (``listener.pipeline``'s
    ``_maybe_output``): a finite epoch and arc length, not stale against the clock (epoch below
    ``fresh_min[i]``: counted in ost[O_STALE]), not older than the last output ``last`` (epoch, s) and
    not the same epoch and arc length; a sent one goes into the estimate columns (:func:`put_row`).
    True when sent."""
    r = order[ns[1]]
    epoch = AUX[r, L.A_T_STATE]
    s = X[r, L.S]
    if not (math.isfinite(epoch) and math.isfinite(s)):
        return False
    if epoch < fresh_min[i]:
        ost[O_STALE] += 1
        return False
    if not (epoch >= last[0] and not (epoch == last[0] and s == last[1])):
        return False
    last[0] = epoch
    last[1] = s
    st, bits, sig = status(order, ns[0], X, PP, AUX, IDX, cfg, r, epoch, work_f)  # what the output carries
    put_row(e_f, e_i, ost, i, epoch, s, m_time[i], float(int(AUX[r, L.A_DIR])) * X[r, L.V], sig, st, bits,
            LID[IDX[I_LINE, r]], seq0, cfg[L.K_Z_INTERVAL])
    return True


@njit(cache=True, _nrt=False, error_model="numpy")
def run_segment(kind, t, vals, i0, stop_jumps, X, PP, AUX, CNT, MEM, IDX, order, ns, cfg, G, LOFF, LLEN, LID,
                JS, work_i, work_f, SX, SPP, SAUX, SCNT, SMEM, SCFG, SS, u_out, u_nis, fresh_min, last,
                m_time, e_f, e_i, ost, seq0):
    """Step measurements i0, i0 + 1, ... of (kind, t, vals) (``sfa.batch.Packed``'s layout) with the
    hypotheses ``order[:ns[0]]``, reported ``order[ns[1]]``, as ``TrackFilter.process`` defines it.

    Per measurement i: its outcome ``u_out[i]`` and NIS ``u_nis[i]`` (NaN for IMU), the reported
    hypothesis's; then, when ``e_f`` has columns, the output rule (:func:`emit`). ``work_i`` (int64, the
    bank's capacity) and ``work_f`` (float64, twice it: :func:`status`) are scratch (the loop is compiled
    without numba's allocator, ``_nrt=False``: it allocates nothing). ``SX .. SS`` are the
    solution-separation sub-filters (``sfa.separation``), stepped after the hypotheses; while they
    exclude GNSS no hypothesis is given a fix.

    Returns (i, why): DONE with i = n; STOP_BEFORE with i the first measurement not processed (a kind
    other than IMU, odometer, GNSS, or with ``stop_jumps`` one further ahead of the state than
    ``K_MAX_TIME_JUMP``, which the time-jump rule of ``TrackFilter.process`` looks at); STOP_AFTER with
    i the measurement after which a hypothesis is within ``K_JUNCTION_WINDOW`` of a junction it has not
    branched at (or at an arc length that is not finite), or after which the reported hypothesis asks
    for a relocalisation (``A_RELOC``): the caller relocalises and spawns the branches, then applies the
    output rule to i.
    """
    n = kind.shape[0]
    window = cfg[L.K_JUNCTION_WINDOW]
    cap = cfg[L.K_GPS_MAX_LOGLIK_NIS]
    emitting = e_f.shape[1] > 0
    separating = cfg[L.K_SEP_WINDOW] > 0.0  # solution separation on (sfa.separation)
    for i in range(i0, n):
        k = kind[i]
        ti = t[i]
        v = vals[i]
        if k != 1 and k != 2 and k != 3:
            return i, STOP_BEFORE
        nh = ns[0]
        rep = ns[1]
        if stop_jumps and math.isfinite(ti) and ti - AUX[order[rep], L.A_T_STATE] > cfg[L.K_MAX_TIME_JUMP]:
            return i, STOP_BEFORE
        if k == 3:  # one GNSS model, the reported hypothesis's (gnss_noise.share)
            for j in range(nh):
                gnss_noise.share(AUX[order[j]], AUX[order[rep]], j == rep)
        elif k == 1 and nh > 1:  # one learned curvature-error scale, the reported hypothesis's
            for j in range(nh):
                for q in range(L.A_GY_LAM, L.A_GY_LAM_DFC + 1):
                    AUX[order[j], q] = AUX[order[rep], q]
        code = K.O_INVALID
        accepted = False
        explained = False  # a fix within some hypothesis's gate, whether or not it updated it
        t_gps_prev = AUX[order[rep], L.A_T_GPS]  # the previous fix in use (the step below moves it)
        t_odo_prev = AUX[order[rep], L.A_T_ODO_SEEN]  # the previous valid odometer sample
        # solution separation's GNSS exclusion (one decision for the bank, kept in every hypothesis's
        # aux): a valid fix goes to no hypothesis
        skip = separating and k == 3 and SEP.gnss_excluded(AUX[order[rep]], ti) and v[3] != 0.0 \
            and not K.gps_invalid(ti, v[0], v[1], v[2])
        for j in range(nh):
            h = order[j]
            a = LOFF[IDX[I_LINE, h]]
            b = LOFF[IDX[I_LINE, h] + 1]
            if skip:
                CNT[h, L.C_SEP_EXCLUDED] += 1
                c = K.O_HELD_OFF
            elif k == 1:
                c = K.step_imu(X[h], PP[h], AUX[h], CNT[h], MEM[h], cfg, G[G_S, a:b], G[G_GRADE, a:b],
                               G[G_CURV, a:b], ti, v[0], v[1], v[2], v[3], v[4], v[5])
            elif k == 2:
                c = K.step_odo(X[h], PP[h], AUX[h], CNT[h], MEM[h], cfg, G[G_S, a:b], G[G_GRADE, a:b], ti,
                               v[0], v[1])
            else:
                fq = -1 if not math.isfinite(v[3]) else int(v[3])
                c = K.step_gps(X[h], PP[h], AUX[h], CNT[h], cfg, G[G_S, a:b], G[G_E, a:b], G[G_N, a:b],
                               G[G_GRADE, a:b], ti, v[0], v[1], v[2], fq)
            if c == K.O_ACCEPTED:
                accepted = True
            elif (k == 3 and (c == K.O_GATED or c == K.O_HELD_OFF)
                  and AUX[h, L.A_LAST_NIS_GPS] <= cfg[L.K_GATE_GPS]):
                # scored against this fix (kernels.step_gps sets the NIS first) and inside the gate, but
                # kept out of the state: a ramp's hold-off, a slip's arbitration, the CUSUM firing
                explained = True
            if j == rep:
                code = c
        nis = math.nan
        if k == 2:
            nis = AUX[order[rep], L.A_LAST_NIS_ODO]
        elif k == 3:
            nis = AUX[order[rep], L.A_LAST_NIS_GPS]
        if nh > 1:
            if k == 1:  # the yaw rate tells branches apart by their curvature
                all_ok = True
                any_on = False
                for j in range(nh):
                    h = order[j]
                    if not AUX[h, L.A_LAST_NIS_GYRO] >= 0.0:
                        all_ok = False
                    if AUX[h, L.A_GYRO_OK] != 0.0:
                        any_on = True
                if all_ok and any_on:
                    score(order, nh, AUX, L.A_LAST_NIS_GYRO, cap, 1.0, 0.0, 1.0)
                    if cfg[L.K_GYRO_LOGDET] != 0.0:  # one share for all: log S's unit cancels
                        score_log_s(order, nh, AUX, L.A_LAST_S_GYRO, AUX[order[rep], L.A_LAST_SHARE_GYRO])
                    prune(order, ns, X, AUX, IDX, G, LOFF, LLEN, cfg, work_i, work_f)
            elif accepted or explained:
                # a measurement every hypothesis rejects is a sensor fault, not evidence; one inside some
                # hypothesis's gate is evidence even where none takes it into its state (a hold-off on
                # the right hypothesis kept a wrong sense of travel reported for 19 s, 277 m away:
                # urban-gnss seed 52)
                # a fix carries the share of an independent fix's evidence the CUSUM gives it
                # (kernels.gps_evidence_weight): a 10 Hz receiver's fixes counted one by one pruned the
                # right branch within 1.5 s of a diverging junction (tests/test_wrong_branch_recovery);
                # an odometer sample its share of odo_evidence_interval_s: 20 Hz samples counted one by
                # one pruned the right sense of travel 0.5 s into a departure, where its speed ran
                # 0.1 m/s above the odometer's (urban-gnss seed 23, the same test module)
                if k == 3:
                    wt = K.gps_evidence_weight(ti, t_gps_prev, cfg)
                else:
                    wt = K.evidence_weight(ti, t_odo_prev, cfg[L.K_ODO_EVIDENCE_DT])
                if k == 2:
                    score(order, nh, AUX, L.A_LAST_NIS_ODO, cap, wt, 0.0, 1.0)
                else:  # under the model every hypothesis shares (gnss_noise.share), the reported one's
                    dof = gnss_noise.score_dof(AUX[order[rep]], cfg)
                    score(order, nh, AUX, L.A_LAST_NIS_GPS, cap, wt, dof, 2.0)
                prune(order, ns, X, AUX, IDX, G, LOFF, LLEN, cfg, work_i, work_f)
        if k == 2 and cfg[L.K_REVERSAL] != 0.0 and AUX[order[ns[1]], L.A_STILL] != 0.0:
            if spawn_reversals(order, ns, X, PP, AUX, CNT, MEM, IDX, cfg):
                prune(order, ns, X, AUX, IDX, G, LOFF, LLEN, cfg, work_i, work_f)
        if separating:
            lr = IDX[I_LINE, order[ns[1]]]
            a = LOFF[lr]
            b = LOFF[lr + 1]
            SEP.advance(k, ti, v, X, PP, AUX, CNT, MEM, lr, order, ns, cfg, G[G_S, a:b], G[G_E, a:b],
                        G[G_N, a:b], G[G_GRADE, a:b], G[G_CURV, a:b], SX, SPP, SAUX, SCNT, SMEM, SCFG, SS)
        u_nis[i] = nis
        u_out[i] = code
        if k == 3 or (k == 2 and code == K.O_ACCEPTED):
            for j in range(ns[0]):
                h = order[j]
                lo = IDX[I_JLO, h]
                hi = IDX[I_JHI, h]
                if hi == lo:
                    continue
                s = X[h, L.S]
                if not math.isfinite(s):
                    return i, STOP_AFTER
                for q in range(lo, hi):
                    if s - window <= JS[q] <= s + window:
                        return i, STOP_AFTER
        if k == 3:  # a relocalisation request (kernels.step_gps): only the reported hypothesis's counts
            for j in range(ns[0]):
                if j != ns[1]:
                    AUX[order[j], L.A_RELOC] = 0.0
            if AUX[order[ns[1]], L.A_RELOC] != 0.0:
                return i, STOP_AFTER
        if emitting:
            emit(i, X, PP, AUX, IDX, order, ns, cfg, LID, fresh_min, last, m_time, e_f, e_i, ost, seq0,
                 work_f)
    return n, DONE


# ------------------------------------------------------------------------------ Python side
class Lines:
    """The lines hypotheses are on, packed into one geometry array for the compiled loop: line k's
    vertices are columns ``OFF[k]:OFF[k + 1]`` of ``G`` (rows G_S, G_E, G_N, G_GRADE, G_CURV), its
    length ``LEN[k]``, its id ``ID[k]``, its arrays ``arrays[k]``."""

    def __init__(self) -> None:
        self.arrays: list = []  #: sfa.track_arrays.TrackArrays per line
        self.index: dict[int, int] = {}
        self.G = np.zeros((NG, 0))
        self.OFF = np.zeros(1, dtype=np.int64)
        self.LEN = np.zeros(0)
        self.ID = np.zeros(0, dtype=np.int64)

    def add(self, arr) -> int:
        """The index of ``arr``'s line, packing it when new."""
        k = self.index.get(arr.line_id)
        if k is not None:
            return k
        cols = np.stack([arr.s_m, arr.east_m, arr.north_m, arr.grade, arr.curvature_inv_m])
        self.G = np.ascontiguousarray(np.concatenate((self.G, cols), axis=1))
        self.OFF = np.append(self.OFF, self.OFF[-1] + arr.s_m.shape[0]).astype(np.int64)
        self.LEN = np.append(self.LEN, float(arr.length_m))
        self.ID = np.append(self.ID, int(arr.line_id)).astype(np.int64)
        k = len(self.arrays)
        self.arrays.append(arr)
        self.index[arr.line_id] = k
        return k


@dataclass
class RunOutput:
    """Where :func:`run_segment` writes a replay's results: per measurement its outcome ``u_out`` and NIS
    ``u_nis``; per sent output a column of ``e_f`` (NEF rows) and ``e_i`` (NEI rows) from ``ost[O_ROW]``
    on, SEQ ``seq0 + row``; ``fresh_min`` the oldest epoch not stale per measurement, ``m_time`` its
    arrival [s]; ``last`` the last output's (epoch, s)."""

    u_out: np.ndarray
    u_nis: np.ndarray
    e_f: np.ndarray
    e_i: np.ndarray
    fresh_min: np.ndarray
    m_time: np.ndarray
    last: np.ndarray
    ost: np.ndarray
    seq0: int

    @cached_property
    def args(self) -> tuple:
        """The arguments of :func:`run_segment` after the bank's, in its order (the fields are never
        reassigned: their arrays are written in place)."""
        return (self.u_out, self.u_nis, self.fresh_min, self.last, self.m_time, self.e_f, self.e_i, self.ost,
                self.seq0)

    @classmethod
    def none(cls) -> RunOutput:
        """Outcomes of one measurement and no output rule (TrackFilter.process)."""
        z = np.zeros(1)
        return cls(np.zeros(1, dtype=np.int64), np.zeros(1), np.zeros((NEF, 0)),
                   np.zeros((NEI, 0), dtype=np.int64), z, z, np.zeros(2), np.zeros(NOST, dtype=np.int64), 0)


class HypothesisBank:
    """The slots and their live order (module docstring); grows when junction spawning needs room.

    Every lineage's set of junctions branched at is interned (``spawn_sets``) with its junction range
    in ``JS``; :meth:`compact` forgets the sets no live slot has (a daemon passes junctions for days)."""

    #: interned junction sets above which :meth:`compact` rebuilds them from the live slots
    MAX_SPAWN_SETS = 64

    def __init__(self, max_hypotheses: int) -> None:
        self.lines = Lines()
        self.spawn_sets: list[frozenset] = [frozenset()]
        self._spawn_ids: dict[frozenset, int] = {frozenset(): 0}
        self.JS = np.zeros(0)
        self._junc: dict[tuple[int, int], tuple[int, int]] = {}
        self.junction_s = None  #: line_id -> [(junction key, s on the line)]: set by the filter
        self.order = np.zeros(0, dtype=np.int64)
        self.ns = np.zeros(2, dtype=np.int64)
        self._args = None  # run_segment's arguments from X to work_f (rebuilt when an array is replaced)
        self._alloc(2 * max(int(max_hypotheses), 2) + 2)  # a reversal may double them before the prune

    def _alloc(self, cap: int) -> None:
        self._args = None
        old = getattr(self, "X", None)
        n_old = 0 if old is None else old.shape[0]
        new = {
            "X": np.zeros((cap, L.NX)), "PP": np.zeros((cap, L.NX, L.NX)), "AUX": np.zeros((cap, L.NAUX)),
            "CNT": np.zeros((cap, L.NCNT), dtype=np.int64), "MEM": np.zeros((cap, L.NMEM)),
        }
        for name, arr in new.items():
            if old is not None:
                arr[:n_old] = getattr(self, name)
            setattr(self, name, arr)
        idx = np.zeros((NIDX, cap), dtype=np.int64)
        order = np.zeros(cap, dtype=np.int64)
        if old is not None:
            idx[:, :n_old] = self.IDX
            order[:n_old] = self.order
        self.IDX, self.order = idx, order
        self.work_i = np.zeros(cap, dtype=np.int64)
        self.work_f = np.zeros(2 * cap)  # status: sigmas and weights
        if old is None:  # the solution-separation sub-filters (sfa.separation): a fixed number
            n = SEP.NSUB
            self.SX, self.SPP = np.zeros((n, L.NX)), np.zeros((n, L.NX, L.NX))
            self.SAUX = np.zeros((n, L.NAUX))
            self.SCNT, self.SMEM = np.zeros((n, L.NCNT), dtype=np.int64), np.zeros((n, L.NMEM))
            self.SS = np.zeros(SEP.NSS)
            self._scfg: tuple = (None, None)

    @property
    def cap(self) -> int:
        return self.X.shape[0]

    @property
    def n(self) -> int:
        return int(self.ns[0])

    @property
    def reported(self) -> int:
        """The reported hypothesis's slot."""
        return int(self.order[self.ns[1]])

    def slots(self) -> list[int]:
        """The live slots in order."""
        return [int(c) for c in self.order[: self.ns[0]]]

    def line(self, slot: int):
        """The ``sfa.track_arrays.TrackArrays`` of the slot's line."""
        return self.lines.arrays[int(self.IDX[I_LINE, slot])]

    def spawned(self, slot: int) -> frozenset:
        return self.spawn_sets[int(self.IDX[I_SPAWN, slot])]

    def direction(self, slot: int) -> int:
        return int(self.AUX[slot, L.A_DIR])

    def new_slot(self, pending: list[int]) -> int:
        """A slot neither live nor in ``pending`` (slots handed out, not yet live), growing the bank."""
        taken = set(self.slots()) | set(pending)
        for c in range(self.cap):
            if c not in taken:
                return c
        c = self.cap
        self._alloc(2 * self.cap)
        return c

    def place(self, slot: int, line, spawned: frozenset) -> None:
        """Put ``slot`` on ``line`` with the lineage ``spawned`` (its junctions still to branch at)."""
        self._args = None  # (a new line replaces the geometry arrays)
        self.IDX[I_LINE, slot] = self.lines.add(line)
        self.set_spawned(slot, spawned)

    def set_spawned(self, slot: int, spawned: frozenset) -> None:
        sid = self._spawn_ids.get(spawned)
        if sid is None:
            sid = len(self.spawn_sets)
            self.spawn_sets.append(spawned)
            self._spawn_ids[spawned] = sid
        self.IDX[I_SPAWN, slot] = sid
        self.IDX[I_JLO, slot], self.IDX[I_JHI, slot] = self._junctions(int(self.IDX[I_LINE, slot]), sid)

    def _junctions(self, line: int, sid: int) -> tuple[int, int]:
        got = self._junc.get((line, sid))
        if got is None:
            items = [] if self.junction_s is None else self.junction_s(self.lines.arrays[line].line_id)
            spawned = self.spawn_sets[sid]
            s = np.array([s for key, s in items if key not in spawned], dtype=np.float64)
            got = (self.JS.shape[0], self.JS.shape[0] + s.shape[0])
            self.JS = np.concatenate((self.JS, s))
            self._args = None
            self._junc[(line, sid)] = got
        return got

    def compact(self) -> None:
        """Keep only the junction sets (and their JS ranges) of the live slots, when more than
        MAX_SPAWN_SETS are interned. Only the indices change: no result does."""
        if len(self.spawn_sets) <= self.MAX_SPAWN_SETS:
            return
        live = [(h, self.spawned(h)) for h in self.slots()]
        self.spawn_sets = [frozenset()]
        self._spawn_ids = {frozenset(): 0}
        self.JS = np.zeros(0)
        self._junc = {}
        self._args = None
        for h, spawned in live:
            self.set_spawned(h, spawned)

    def copy_slot(self, dst: int, src: int, keep_mem: bool = False) -> None:
        """Slot dst = slot src (its rewind memory empty unless ``keep_mem``)."""
        _copy_slot(dst, src, self.X, self.PP, self.AUX, self.CNT, self.MEM, self.IDX, keep_mem)

    def clear_slot(self, slot: int) -> None:
        """Slot ``slot`` all zeros (a hypothesis not initialised yet)."""
        for arr in (self.X, self.PP, self.AUX, self.CNT, self.MEM):
            arr[slot] = 0

    def set_live(self, slots: list[int], reported: int) -> None:
        """The live slots in order, ``slots[reported]`` the reported one (the bank grows to keep room for
        the reversals of all of them: :func:`run_segment` needs 2 x the live slots)."""
        if 2 * len(slots) > self.cap:
            self._alloc(2 * len(slots) + 2)
        self.order[: len(slots)] = slots
        self.ns[0] = len(slots)
        self.ns[1] = reported

    def prune(self, cfg: np.ndarray) -> None:
        ln = self.lines
        prune(self.order, self.ns, self.X, self.AUX, self.IDX, ln.G, ln.OFF, ln.LEN, cfg, self.work_i,
              self.work_f)

    def empty_gyro_windows(self) -> None:
        empty_gyro_windows(self.order, self.ns[0], self.AUX)

    def same_track(self, g: int, h: int, cfg: np.ndarray) -> bool:
        return bool(same_track(g, h, self.X, self.AUX, self.IDX, self.lines.G, self.lines.OFF,
                               cfg[L.K_JUNCTION_WINDOW]))

    def direction_ambiguous(self) -> bool:
        """The reported hypothesis's reversal is kept too."""
        return bool(twin(self.order, self.ns[0], self.X, self.AUX, self.IDX, self.reported))

    def status(self, cfg: np.ndarray, t: float, X=None, PP=None, AUX=None) -> tuple[int, int, float]:
        """:func:`status` of the reported hypothesis at t (on the bank's arrays, or copies of them
        given as X, PP, AUX)."""
        X = self.X if X is None else X
        PP = self.PP if PP is None else PP
        AUX = self.AUX if AUX is None else AUX
        st, bits, sig = status(self.order, self.ns[0], X, PP, AUX, self.IDX, cfg, self.reported, t,
                               self.work_f)
        return int(st), int(bits), float(sig)

    def args(self, cfg: np.ndarray) -> tuple:
        """:func:`run_segment`'s arguments from X to work_f (built once per change of an array)."""
        a = self._args
        if a is None or a[8] is not cfg:
            ln = self.lines
            a = (self.X, self.PP, self.AUX, self.CNT, self.MEM, self.IDX, self.order, self.ns, cfg, ln.G,
                 ln.OFF, ln.LEN, ln.ID, self.JS, self.work_i, self.work_f, self.SX, self.SPP, self.SAUX,
                 self.SCNT, self.SMEM, self.sub_configs(cfg), self.SS)
            self._args = a
        return a

    def sub_configs(self, cfg: np.ndarray) -> np.ndarray:
        """The sub-filters' configuration vectors for ``cfg`` (sfa.separation.sub_configs), kept."""
        if self._scfg[0] is not cfg:
            self._scfg = (cfg, SEP.sub_configs(cfg))
        return self._scfg[1]

    def run(self, kind, t, vals, i0: int, stop_jumps: bool, cfg: np.ndarray, out: RunOutput):
        """:func:`run_segment` on this bank; returns (i, why). The live slots never exceed half the
        capacity here (set_live; in the loop, each prune keeps at most K_MAX_HYPOTHESES)."""
        i, why = run_segment(kind, t, vals, i0, stop_jumps, *self.args(cfg), *out.args)
        return int(i), int(why)

    def emit(self, i: int, cfg: np.ndarray, out: RunOutput) -> bool:
        """The output rule (:func:`emit`) after measurement i."""
        return bool(emit(i, self.X, self.PP, self.AUX, self.IDX, self.order, self.ns, cfg, self.lines.ID,
                         out.fresh_min, out.last, out.m_time, out.e_f, out.e_i, out.ost, out.seq0,
                         self.work_f))
