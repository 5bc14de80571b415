"""Solution separation: fault detection and exclusion by sub-filters that each leave out one aid.

The idea is ARAIM's (aviation's Advanced RAIM), applied to the filter's aids instead of satellites
(docs/filter.md, "Solution separation"). Beside the reported hypothesis run sub-filters, copies of it
that are fed every measurement but one aid's:

- ``AID_GNSS``: no GNSS fix (IMU and odometer dead reckoning on the track);
- ``AID_ODO``: no odometer sample (IMU and GNSS);
- ``AID_GYRO``: no gyro map matching (the configuration with ``use_gyro`` off; only when it is on).

A sub-filter that never sees an aid drifts where that aid was the only check (GNSS, over hours), so
each is re-anchored to the reported hypothesis every ``separation_window_s`` seconds; there are two per
aid, half a window apart, so one of them has always run without the aid for at least half a window.

After every IMU sample, for each sub-filter k at the main filter's time, the separation
``d_k = s_k - s_main`` is tested against its own variance, ARAIM's ``sigma_ss^2 = P_k - P_main``
(the main filter uses everything the sub-filter uses, and more): a fault-free ``d_k^2 / sigma_ss^2`` is
chi-square with one degree of freedom, gated at ``separation_probability``.

When only GNSS's sub-filters are beyond the gate, the two motion sensors agree with each other and not
with the fixes: GNSS is the faulty aid (of its two sub-filters, the one with the larger statistic is
kept):

- **exclude**: no hypothesis or sub-filter uses a fix for ``separation_hold_s`` (outcome HELD_OFF,
  counted ``separation_excluded``; a later detection extends it);
- **re-anchor**: the reported hypothesis takes the sub-filter's state and covariance (it never saw the
  fault), and the other aids' sub-filters are re-anchored to it;
- **widen**: for the hold, the interval covers the estimate before the re-anchoring as well (sigma +
  |jump| / z, ``sfa.kernels.status_of``) with reason ``gnss_excluded`` (a fault reason: the
  fault-confidence widening applies too).

Any other detection is ARAIM's detection without exclusion: nothing is excluded or re-anchored, the
interval covers the largest separation for the hold (reason ``separation_detected``). The odometer's
and the gyro's sub-filters detect but do not exclude: without the odometer only GNSS says where the
train is, and a GNSS error larger than its model (urban multipath) separates that sub-filter from a
main filter the odometer kept right. Excluding the odometer on it made urban runs worse (p95 2.28 m to
3.37 m over five seeds of ``urban-gnss``, docs/filter.md); the odometer's own faults are excluded by
the slip test against the IMU, the gyro's weighted by its learned curvature-error scale.

Any change of the reported hypothesis (another line or sense of travel, a (re)initialisation)
re-anchors every sub-filter to it. The sub-filters are stepped by the same kernels as the hypotheses,
on the reported hypothesis's line, inside ``sfa.bank.run_segment``: the listener, ``TrackFilter`` and
the replay run exactly this code. Arrays: ``SX, SPP, SAUX, SCNT, SMEM`` (NSUB sub-filters, the
hypothesis slots' shapes), ``SCFG`` (NSUB configuration vectors: :func:`sub_configs`), ``SS`` (NSS
scalars, named below).
"""

from __future__ import annotations

import math

import numpy as np

from sfa import kernels as K
from sfa import layout as L
from sfa.engine import njit  # numba.njit on the JIT; exported by the compiled engine (sfa.engine_build)

AID_GNSS = 0  #: GNSS fixes
AID_ODO = 1  #: odometer samples
AID_GYRO = 2  #: the gyro's map matching (the yaw rate against the track's curvature)
NAID = 3
# bits of A_SS_MASK (sfa.kernels.status_of reads them as 1 and 2)
EXCLUDED_GNSS = 1  #: GNSS excluded (and the estimate re-anchored)
DETECTED = 2  #: a detection nothing was excluded for (the interval widened)
COPIES = 2  #: sub-filters per aid, re-anchored half a window apart
NSUB = NAID * COPIES  #: sub-filter k leaves out aid k // COPIES

# slots of SS (float64[NSS])
SS_ON = 0  #: 1 while the sub-filters follow the reported hypothesis below
SS_SLOT = 1  #: its slot
SS_LINE = 2  #: its line (index into the bank's Lines)
SS_DIR = 3  #: its sense of travel
SS_TINIT = 4  #: its time of (re)initialisation [s]
SS_NEXT = 5  #: NSUB times of the next scheduled re-anchoring [s]
NSS = SS_NEXT + NSUB


def sub_configs(cfg: np.ndarray) -> np.ndarray:
    """The NSUB configuration vectors: ``cfg``, with the gyro update off for the gyro's sub-filters."""
    scfg = np.ascontiguousarray(np.tile(cfg, (NSUB, 1)))
    scfg[AID_GYRO * COPIES: (AID_GYRO + 1) * COPIES, L.K_USE_GYRO] = 0.0
    return scfg


@njit(cache=True, inline="always", _nrt=False, error_model="numpy")
def gnss_excluded(aux, t):
    """True while solution separation excludes GNSS (the mask and hold in ``aux``)."""
    return t < aux[L.A_SS_UNTIL] and int(aux[L.A_SS_MASK]) & EXCLUDED_GNSS != 0


@njit(cache=True, inline="always", _nrt=False, error_model="numpy")
def _detecting(aux, t):
    """True while a detection holds (an exclusion or a widening: A_SS_MASK until A_SS_UNTIL)."""
    return aux[L.A_SS_MASK] != 0.0 and t < aux[L.A_SS_UNTIL]


@njit(cache=True, inline="always", _nrt=False, error_model="numpy")
def _active(k, cfg):
    """Sub-filter k runs: the gyro's only while the main filter uses the gyro (else it is the main one)."""
    return k // COPIES != AID_GYRO or cfg[L.K_USE_GYRO] != 0.0


@njit(cache=True, _nrt=False, error_model="numpy")
def _anchor(k, r, X, PP, AUX, CNT, MEM, SX, SPP, SAUX, SCNT, SMEM):
    """Sub-filter k = a copy of hypothesis slot r (state, covariance, auxiliaries, rewind memory); its
    counters start from zero (they count what the sub-filter did since)."""
    for i in range(L.NX):
        SX[k, i] = X[r, i]
        for j in range(L.NX):
            SPP[k, i, j] = PP[r, i, j]
    for i in range(L.NAUX):
        SAUX[k, i] = AUX[r, i]
    for i in range(L.NCNT):
        SCNT[k, i] = 0
    for i in range(L.NMEM):
        SMEM[k, i] = MEM[r, i]


@njit(cache=True, _nrt=False, error_model="numpy")
def _anchor_all(t, r, skip_aid, X, PP, AUX, CNT, MEM, SX, SPP, SAUX, SCNT, SMEM, SS, cfg):
    """Re-anchor every sub-filter but ``skip_aid``'s (-1: none) to slot r, copy c of each aid next due
    (c + 1) / COPIES windows from now."""
    w = cfg[L.K_SEP_WINDOW]
    for k in range(NSUB):
        if k // COPIES == skip_aid or not _active(k, cfg):
            continue
        _anchor(k, r, X, PP, AUX, CNT, MEM, SX, SPP, SAUX, SCNT, SMEM)
        SS[SS_NEXT + k] = t + w * (k % COPIES + 1) / COPIES


@njit(cache=True, _nrt=False, error_model="numpy")
def _step_subs(kind, t, v, r, AUX, ts, te, tn, tg, tk, SX, SPP, SAUX, SCNT, SMEM, SCFG, cfg):
    """Measurement (kind, t, v) into every sub-filter that uses it."""
    gps_out = gnss_excluded(AUX[r], t)
    for k in range(NSUB):
        if not _active(k, cfg):
            continue
        aid = k // COPIES
        c = SCFG[k]
        if kind == 1:
            K.step_imu(SX[k], SPP[k], SAUX[k], SCNT[k], SMEM[k], c, ts, tg, tk, t, v[0], v[1], v[2], v[3],
                       v[4], v[5])
        elif kind == 2:
            if aid != AID_ODO:
                K.step_odo(SX[k], SPP[k], SAUX[k], SCNT[k], SMEM[k], c, ts, tg, t, v[0], v[1])
        elif aid != AID_GNSS and not gps_out:
            fq = -1 if not math.isfinite(v[3]) else int(v[3])
            K.step_gps(SX[k], SPP[k], SAUX[k], SCNT[k], c, ts, te, tn, tg, t, v[0], v[1], v[2], fq)


@njit(cache=True, _nrt=False, error_model="numpy")
def _worst(r, X, PP, AUX, SX, SPP, SAUX, cfg):
    """(k, flagged, jump): the sub-filter whose separation from slot r is the largest beyond the gate (-1:
    none is), the bit mask of the aids with a sub-filter beyond it, and the largest separation beyond it
    [m]."""
    vm = K.pending_var_s(PP[r], AUX[r])
    best = -1
    q_best = cfg[L.K_SEP_GATE]
    flagged = 0
    jump = 0.0
    for k in range(NSUB):
        if not _active(k, cfg):
            continue
        if SAUX[k, L.A_INIT] == 0.0 or SAUX[k, L.A_T_STATE] != AUX[r, L.A_T_STATE]:
            continue
        d = SX[k, L.S] - X[r, L.S]  # the separation
        # sigma_ss^2 = P_k - P_0, plus the floor (separation_floor_m)
        vd = max(K.pending_var_s(SPP[k], SAUX[k]) - vm, 0.0) + cfg[L.K_SEP_FLOOR_VAR]
        q = d * d / vd
        if q > cfg[L.K_SEP_GATE]:  # (NaN never is)
            flagged |= 1 << (k // COPIES)
            jump = max(jump, abs(d))
            if q > q_best:
                best = k
                q_best = q
    return best, flagged, jump


@njit(cache=True, _nrt=False, error_model="numpy")
def _exclude(k, t, r, order, n, X, PP, AUX, CNT, MEM, SX, SPP, SAUX, SCNT, SMEM, SCFG, SS, cfg):
    """Detection by GNSS's sub-filter k: exclude GNSS, re-anchor slot r to the sub-filter, widen the
    interval, and re-anchor the other aids' sub-filters."""
    K.sync_block(X[r], PP[r], AUX[r], cfg, CNT[r])
    K.sync_block(SX[k], SPP[k], SAUX[k], SCFG[k], SCNT[k])
    jump = X[r, L.S] - SX[k, L.S]
    for i in range(L.NX):
        X[r, i] = SX[k, i]
        for j in range(L.NX):
            PP[r, i, j] = SPP[k, i, j]
    AUX[r, L.A_GY_N] = 0.0  # its gyro window was summed relative to the old state
    K.mem_reset(MEM[r])  # its rewind snapshots are of the old state
    held = _detecting(AUX[r], t)
    mask = float(int(AUX[r, L.A_SS_MASK]) | EXCLUDED_GNSS) if held else float(EXCLUDED_GNSS)
    for q in range(n):
        h = order[q]
        AUX[h, L.A_SS_MASK] = mask
        AUX[h, L.A_SS_UNTIL] = t + cfg[L.K_SEP_HOLD]
        AUX[h, L.A_SS_DS] = jump
    CNT[r, L.C_SEP_DETECT] += 1
    _anchor_all(t, r, AID_GNSS, X, PP, AUX, CNT, MEM, SX, SPP, SAUX, SCNT, SMEM, SS, cfg)


@njit(cache=True, _nrt=False, error_model="numpy")
def _detect(t, r, order, n, AUX, CNT, jump, cfg):
    """Detection without exclusion (module docstring): every aid stays in, nothing is re-anchored, the
    interval is widened by the largest separation for the hold."""
    held = _detecting(AUX[r], t)
    mask = float(int(AUX[r, L.A_SS_MASK]) | DETECTED) if held else float(DETECTED)
    if not (held and int(AUX[r, L.A_SS_MASK]) & DETECTED):
        CNT[r, L.C_SEP_DETECT] += 1  # (counted once per run of detections)
    for q in range(n):
        h = order[q]
        AUX[h, L.A_SS_MASK] = mask
        AUX[h, L.A_SS_UNTIL] = t + cfg[L.K_SEP_HOLD]
        AUX[h, L.A_SS_DS] = max(jump, abs(AUX[h, L.A_SS_DS])) if held else jump


@njit(cache=True, _nrt=False, error_model="numpy")
def advance(kind, t, v, X, PP, AUX, CNT, MEM, IDX_line, order, ns, cfg, ts, te, tn, tg, tk,
            SX, SPP, SAUX, SCNT, SMEM, SCFG, SS):
    """After the bank has taken measurement (kind, t, v): the sub-filters take it, then (after an IMU
    sample) the separation test and, on a detection, the exclusion (module docstring). ``IDX_line`` is
    the reported slot's line; ``ts .. tk`` its geometry. Called only with ``separation_window_s`` > 0."""
    r = order[ns[1]]
    if AUX[r, L.A_INIT] == 0.0:
        SS[SS_ON] = 0.0
        return
    if SS[SS_ON] == 0.0 or SS[SS_SLOT] != r or SS[SS_LINE] != IDX_line or SS[SS_DIR] != AUX[r, L.A_DIR] \
            or SS[SS_TINIT] != AUX[r, L.A_T_INIT]:
        if SS[SS_ON] == 0.0 or SS[SS_TINIT] != AUX[r, L.A_T_INIT]:
            AUX[r, L.A_SS_MASK] = 0.0  # a (re)initialisation forgets the exclusions
            AUX[r, L.A_SS_DS] = 0.0
        SS[SS_ON] = 1.0
        SS[SS_SLOT] = r
        SS[SS_LINE] = IDX_line
        SS[SS_DIR] = AUX[r, L.A_DIR]
        SS[SS_TINIT] = AUX[r, L.A_T_INIT]
        _anchor_all(t, r, -1, X, PP, AUX, CNT, MEM, SX, SPP, SAUX, SCNT, SMEM, SS, cfg)
        return
    _step_subs(kind, t, v, r, AUX, ts, te, tn, tg, tk, SX, SPP, SAUX, SCNT, SMEM, SCFG, cfg)
    if kind != 1:
        return
    k, flagged, jump = _worst(r, X, PP, AUX, SX, SPP, SAUX, cfg)
    if flagged == 1 << AID_GNSS:  # GNSS alone explains it: exclude it (module docstring)
        _exclude(k, t, r, order, ns[0], X, PP, AUX, CNT, MEM, SX, SPP, SAUX, SCNT, SMEM, SCFG, SS, cfg)
        return
    if k >= 0:  # the odometer's or the gyro's sub-filters disagree: detection without exclusion
        _detect(t, r, order, ns[0], AUX, CNT, jump, cfg)
        return
    w = cfg[L.K_SEP_WINDOW]
    for k in range(NSUB):
        if SS[SS_NEXT + k] > t or not _active(k, cfg):
            continue
        if not _detecting(AUX[r], t):  # none re-anchored mid-detection
            _anchor(k, r, X, PP, AUX, CNT, MEM, SX, SPP, SAUX, SCNT, SMEM)
        SS[SS_NEXT + k] += w * (math.floor((t - SS[SS_NEXT + k]) / w) + 1.0)  # (the copies keep their phase)
