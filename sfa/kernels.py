"""Compiled mathematics of the track-constrained EKF: the only implementation of the filter equations.

Every function works on flat float64/int64 arrays whose slots are named in ``sfa.layout``:

- ``x`` (NX) state, ``P`` (NX x NX) covariance, ``aux`` (NAUX) integrity/time scalars,
  ``cnt`` (NCNT) counters, ``cfg`` (NCFG) configuration (built by ``FilterConfig.to_array``),
- the line geometry ``ts, te, tn, tg, tk``: arc length [m], local east/north [m], grade [-] and signed
  curvature [1/m] per vertex (``sfa.track_arrays``).

``TrackFilter.process`` calls one ``step_*`` function per message; ``sfa.batch`` calls the same
functions in a compiled loop. The equations are documented in docs/filter.md; each line here carries
its equation as a comment. Nothing in here reads a clock: time is always an argument.
"""

from __future__ import annotations

import math

import numpy as np

from sfa import gnss_noise
from sfa.engine import njit  # numba.njit, or the compiled engine (sfa.engine)
from sfa.layout import (
    A_CUSUM_N,
    A_CUSUM_P,
    A_DIR,
    A_FX,
    A_FX_MEAN,
    A_FX_VAR,
    A_FY,
    A_FZ,
    A_GM_SIG,
    A_GM_TAU,
    A_GPS_E,
    A_GPS_HOLD,
    A_GPS_N,
    A_GPS_REJ,
    A_GPS_TO,
    A_GY_HMX,
    A_GY_HS,
    A_GY_HSG,
    A_GY_HV,
    A_GY_LAM,
    A_GY_LAM_DCC,
    A_GY_LAM_DEN,
    A_GY_LAM_DFC,
    A_GY_LAM_NUM,
    A_GY_LAMC,
    A_GY_LAMC_NUM,
    A_GY_N,
    A_GY_RC,
    A_GY_RC0,
    A_GY_RCF,
    A_GY_RCF0,
    A_GY_T0,
    A_GY_Y,
    A_GYRO_OK,
    A_GZ,
    A_IMU_FAULT_T,
    A_IMU_SAME,
    A_IMU_TO,
    A_INIT,
    A_LAST_NIS_GPS,
    A_LAST_NIS_GYRO,
    A_LAST_NIS_ODO,
    A_LAST_S_GYRO,
    A_LAST_SHARE_GYRO,
    A_LOGLIK,
    A_ODO_TO,
    A_PB_H,
    A_PB_SB,
    A_PB_SF,
    A_PB_SM,
    A_PB_VB,
    A_PB_VF,
    A_PB_VM,
    A_QB_BB,
    A_QB_SB,
    A_QB_SS,
    A_QB_SV,
    A_QB_VB,
    A_QB_VV,
    A_RAMP_T,
    A_REJ_DS,
    A_REJ_E,
    A_REJ_MAXDEV,
    A_REJ_N,
    A_REJ_S,
    A_RELOC,
    A_RELOC_DS,
    A_RELOC_E,
    A_RELOC_E0,
    A_RELOC_N,
    A_RELOC_N0,
    A_SEG,
    A_SLIP,
    A_SLIP_BAD,
    A_SLIP_DS,
    A_SLIP_GOOD,
    A_SLIP_LLR,
    A_SLIP_S_ODO,
    A_SLIP_T0,
    A_SLIP_V_ODO,
    A_SS_DS,
    A_SS_MASK,
    A_SS_UNTIL,
    A_STEP_FLAG,
    A_STILL,
    A_T_FIRST_GPS_REJ,
    A_T_GPS,
    A_T_IMU,
    A_T_INIT,
    A_T_ODO,
    A_T_ODO_SEEN,
    A_T_STATE,
    A_WK_K,
    A_WK_PHT,
    A_WX,
    A_WY,
    BA,
    BG,
    C_COV_REPAIR,
    C_GPS_BAD,
    C_GPS_GATED,
    C_GPS_HELD,
    C_GPS_LATE,
    C_GPS_LATE_USED,
    C_GPS_NOFIX,
    C_GPS_OK,
    C_GPS_REACQ,
    C_GPS_TIMEOUT,
    C_GYRO_GATED,
    C_GYRO_OK,
    C_IMU_BAD,
    C_IMU_FAULT,
    C_IMU_LATE,
    C_IMU_OK,
    C_IMU_STUCK,
    C_IMU_TIMEOUT,
    C_INIT,
    C_NOT_INIT,
    C_ODO_BAD,
    C_ODO_GATED,
    C_ODO_LATE,
    C_ODO_OK,
    C_ODO_REANCHOR,
    C_ODO_TIMEOUT,
    C_RAMP,
    C_SLIP,
    C_SLIP_REWIND,
    C_STEP,
    C_ZUPT,
    FAULT_REASONS,
    GE,
    GN,
    K_AD_WINDOW,
    K_CURV_CORR_M,
    K_CURV_REG_M,
    K_CURV_REL,
    K_CURV_SIGMA,
    K_CUSUM_DT,
    K_CUSUM_H,
    K_CUSUM_K,
    K_DEGRADED_SIGMA,
    K_FAULT_SIGMA_SCALE,
    K_FX_EWMA_TAU,
    K_GATE_GPS,
    K_GATE_GYRO,
    K_GATE_ODO,
    K_GATE_ZUPT,
    K_GPS_HOLDOFF_S,
    K_GPS_LATE_MAX,
    K_GPS_MAX_LOGLIK_NIS,
    K_GPS_TIMEOUT,
    K_GRAVITY,
    K_GYRO_AD_M,
    K_GYRO_AVG_MAX_S,
    K_GYRO_AVG_N,
    K_GYRO_MIN_SPEED,
    K_GYRO_SIGMA,
    K_GYRO_TILT,
    K_GYRO_TWO_SCALES,
    K_IMU_FAULT_HOLD,
    K_IMU_STUCK_N,
    K_IMU_TIMEOUT,
    K_INIT_SIGMA_BA,
    K_INIT_SIGMA_BG,
    K_INIT_SIGMA_KO,
    K_INIT_SIGMA_MX,
    K_INIT_SIGMA_MY,
    K_INIT_SIGMA_S,
    K_INIT_SIGMA_SF,
    K_INIT_SIGMA_SG,
    K_INIT_SIGMA_V,
    K_LATE_TOL,
    K_LOST_SIGMA,
    K_MAX_DT,
    K_ODO_QUANT,
    K_ODO_SIGMA_MIN,
    K_ODO_TIMEOUT,
    K_P_MIN_VAR,
    K_Q_ACC,
    K_Q_BA,
    K_Q_BG,
    K_Q_KO,
    K_Q_NO_IMU,
    K_Q_REG,
    K_Q_SG,
    K_REACQ_CONSIST_M,
    K_REACQ_S,
    K_RELOC,
    K_SLIP_ARB_LLR,
    K_SLIP_BA_SIGMA,
    K_SLIP_CONFIRM_N,
    K_SLIP_MAX_S,
    K_SLIP_RELEASE_N,
    K_SNAP_PERIOD,
    K_STEP_MIN_M,
    K_STILL_FX_STD,
    K_STILL_SPEED,
    K_TRACK_LAT,
    K_TRACK_LAT_CORR_M,
    K_USE_GYRO,
    K_Z_INTERVAL,
    K_ZUPT_SIGMA,
    KO,
    MEM_A,
    MEM_B,
    MEM_H0,
    MEM_HH,
    MEM_HN,
    MEM_T_ROT,
    MX,
    MY,
    NH,
    NX,
    R_GNSS_RAMP,
    R_GNSS_REJECTING,
    R_GNSS_STEP,
    R_GPS_TIMEOUT,
    R_IMU_FAULT,
    R_IMU_STUCK,
    R_IMU_TIMEOUT,
    R_NO_MOTION_SENSOR,
    R_NOT_INIT,
    R_ODO_TIMEOUT,
    R_SEP_DETECTED,
    R_SEP_GNSS,
    R_SIGMA_HIGH,
    R_SIGMA_LOST,
    R_SLIP,
    R_STANDSTILL,
    SF,
    SG,
    SNAP,
    S,
    V,
)

# Outcome codes (same values as sfa.layout.Outcome; repeated as ints for the compiled code)
O_ACCEPTED = 0
O_GATED = 1
O_LATE = 2
O_INVALID = 3
O_NOT_INIT = 4
O_NO_FIX = 5
O_INITIALISED = 6
O_HELD_OFF = 7

LOG_2PI = math.log(2.0 * math.pi)
COS_MAX_ROLL = math.cos(0.35)  #: cos of the largest roll the gyro compensation accepts (0.35 rad)
BIG = 1e100  #: bound on the factors of an update: products stay far from overflow
GYRO_LAM_MAX = 1.0e4  #: largest learned curvature-error scale (the gyro then tells nearly nothing)
#: weight of the prior scale 1, as a share of the information of a memory full of windows whose residual
#: is all curvature error (gyro_window_update)
GYRO_LAM_PRIOR = 0.25
GPS_IEKF_ITERATIONS = 3  #: Gauss-Newton re-linearisations of a GNSS fix in the arc length (step_gps)
GPS_IEKF_TOL_M = 1e-3  #: they stop once the linearisation point moves less than this [m]
#: most fixes one draw of the centre line's lateral error is shared by (lateral_variance): bounds R at a
#: standstill, where every fix sees the same offset [-]
LAT_NC_MAX = 1.0e4


def _into_imu_step(expr, caller_ir, callee_ir) -> bool:
    """numba's IR-level inlining, for the functions on the IMU sample's path (prediction, track lookups,
    roll, timeouts, IMU ring): inlined into ``step_imu`` only, which runs for every IMU sample (100 Hz)
    and gets about 10 % cheaper; every other caller calls them (compiling them inline everywhere would
    double the kernels' first compile for no measurable gain)."""
    return caller_ir.func_id.func_name == "step_imu"


# ============================================================== track geometry on vertex arrays
@njit(cache=True, _nrt=False, error_model="numpy")
def seg_index(ts, s):
    """Index i of the segment [ts[i], ts[i+1]] holding s (clamped to the first/last segment)."""
    i = np.searchsorted(ts, s, side="right") - 1
    if i < 0:
        i = 0
    n = ts.shape[0]
    if i > n - 2:
        i = n - 2
    return i


@njit(cache=True, inline=_into_imu_step, _nrt=False, error_model="numpy")
def seg_hint(ts, s, aux):
    """``seg_index(ts, s)``, starting from the segment of the previous lookup (aux[A_SEG]): O(1) while s
    moves by at most one segment between lookups, and always the same answer as ``seg_index``."""
    n = ts.shape[0]
    if s >= ts[n - 1]:  # beyond the end (searchsorted: n, clamped to the last segment)
        return n - 2
    i = int(aux[A_SEG])
    if 0 <= i <= n - 2 and ts[i] <= s:
        if s < ts[i + 1]:
            return i
        if i + 1 <= n - 2 and s < ts[i + 2]:  # ts[i + 1] <= s: the next segment
            aux[A_SEG] = i + 1
            return i + 1
    i = seg_index(ts, s)
    aux[A_SEG] = i
    return i


@njit(cache=True, _nrt=False, error_model="numpy")
def geom_at(ts, te, tn, s):
    """Point h(s) = (east, north) [m] and its derivative dh/ds (the segment tangent) at arc length s.

    Within a segment arc length maps linearly onto the local segment; beyond the ends the first/last
    segment is extended, so h stays smooth and finite for any finite s.
    """
    i = seg_index(ts, s)
    ds = ts[i + 1] - ts[i]
    if ds <= 0.0:
        ds = 1e-9
    de = (te[i + 1] - te[i]) / ds  # de/ds
    dn = (tn[i + 1] - tn[i]) / ds  # dn/ds
    u = s - ts[i]
    return te[i] + de * u, tn[i] + dn * u, de, dn


@njit(cache=True, _nrt=False, error_model="numpy")
def mirror(x, P, aux):
    """A copy of a hypothesis turned into the opposite sense of travel at the same place (the train
    may reverse while standing): v and the direction change sign, and so do P's row and column of v
    (TrackFilter's mirrored hypotheses and the fast replay's, one implementation)."""
    x[V] = -x[V]
    aux[A_DIR] = -aux[A_DIR]
    for q in range(NX):
        P[V, q] = -P[V, q]
    for q in range(NX):
        P[q, V] = -P[q, V]


@njit(cache=True, _nrt=False, error_model="numpy")
def cross_track(ts, te, tn, s, east, north):
    """Signed distance of the point (east, north) from the line, left of the direction of increasing
    arc length positive [m], the unit normal there and the foot's arc length: the foot found from s by
    three projections onto the local segment (s <- s + u . (z - h(s))), so the result does not depend on
    how far s is from the foot along the line."""
    for _ in range(3):
        e, n, de, dn = geom_at(ts, te, tn, s)
        g = math.sqrt(de * de + dn * dn)
        s += ((east - e) * de + (north - n) * dn) / (g * g)  # s += u . (z - h(s)) / |dh/ds|
    e, n, de, dn = geom_at(ts, te, tn, s)
    g = math.sqrt(de * de + dn * dn)
    ne = -dn / g  # n = (-u_n, u_e)
    nn = de / g
    return (east - e) * ne + (north - n) * nn, ne, nn, s


@njit(cache=True, _nrt=False, error_model="numpy")
def interp_at(ts, arr, s):
    """Piecewise-linear value of a per-vertex quantity at s, held constant beyond the ends."""
    return interp_seg(ts, arr, s, seg_index(ts, s))


@njit(cache=True, inline=_into_imu_step, _nrt=False, error_model="numpy")
def interp_seg(ts, arr, s, i):
    """``interp_at`` with the segment i = seg_index(ts, s) already known (``seg_hint``)."""
    n = ts.shape[0]
    if s <= ts[0]:
        return arr[0]
    if s >= ts[n - 1]:
        return arr[n - 1]
    ds = ts[i + 1] - ts[i]
    if ds <= 0.0:
        return arr[i]
    return arr[i] + (arr[i + 1] - arr[i]) * (s - ts[i]) / ds


@njit(cache=True, inline=_into_imu_step, _nrt=False, error_model="numpy")
def interp_slope_at(ts, arr, s, i):
    """Value (as ``interp_at``) and derivative d(arr)/ds (0 beyond the ends) of the piecewise-linear
    per-vertex quantity at s, in the segment i = seg_index(ts, s)."""
    n = ts.shape[0]
    if s <= ts[0]:
        return arr[0], 0.0
    if s >= ts[n - 1]:
        return arr[n - 1], 0.0
    ds = ts[i + 1] - ts[i]
    if ds <= 0.0:
        return arr[i], 0.0
    slope = (arr[i + 1] - arr[i]) / ds
    return arr[i] + (arr[i + 1] - arr[i]) * (s - ts[i]) / ds, slope


# ============================================================== covariance hygiene
@njit(cache=True, _nrt=False, error_model="numpy")
def _cholesky_ok(P):
    """True when the symmetric P is numerically positive definite (a plain Cholesky succeeds).

    Allocation-free: the factor's strict lower triangle is written into P's strict lower triangle
    (the upper triangle holds the same values, P being symmetric) and restored from the upper triangle
    afterwards; the diagonal of the factor is needed only within its own column."""
    n = P.shape[0]
    ok = True
    for j in range(n):
        d = P[j, j]
        for k in range(j):
            d -= P[j, k] * P[j, k]  # L[j,j]^2 = P[j,j] - sum_k L[j,k]^2
        if not (d > 0.0) or not math.isfinite(d):
            ok = False
            break
        ljj = math.sqrt(d)
        for i in range(j + 1, n):
            v = P[j, i]
            for k in range(j):
                v -= P[i, k] * P[j, k]  # L[i,j] = (P[i,j] - sum_k L[i,k] L[j,k]) / L[j,j]
            P[i, j] = v / ljj
    for i in range(n):
        for j in range(i):
            P[i, j] = P[j, i]
    return ok


@njit(cache=True, _nrt=False, error_model="numpy")
def _symmetrise_floor(P, cfg):
    """P = (P + P')/2 and a floor on the diagonal; True when the floor was hit (or a NaN replaced)."""
    n = P.shape[0]
    pmin = cfg[K_P_MIN_VAR]
    repaired = False
    for i in range(n):
        for j in range(i + 1, n):
            m = 0.5 * (P[i, j] + P[j, i])  # P = (P + P') / 2
            P[i, j] = m
            P[j, i] = m
        if not (P[i, i] >= pmin):  # also catches NaN
            P[i, i] = pmin
            repaired = True
    return repaired


@njit(cache=True, _nrt=False, error_model="numpy")
def _floor_diag(P, cfg):
    """The diagonal floor of ``_symmetrise_floor`` alone (for a P symmetric by construction)."""
    pmin = cfg[K_P_MIN_VAR]
    repaired = False
    for i in range(P.shape[0]):
        if not (P[i, i] >= pmin):  # also catches NaN
            P[i, i] = pmin
            repaired = True
    return repaired


@njit(cache=True, _nrt=False, error_model="numpy")
def condition_cov(P, cfg, cnt):
    """Keep P symmetric positive definite: P = (P + P')/2, floor the diagonal, and if a Cholesky
    factorisation still fails drop the correlations (P = diag(P)). Repairs are counted."""
    n = P.shape[0]
    repaired = _symmetrise_floor(P, cfg)
    if not _cholesky_ok(P):
        for i in range(n):
            for j in range(n):
                if i != j:
                    P[i, j] = 0.0
        repaired = True
    if repaired:
        cnt[C_COV_REPAIR] += 1


# ============================================================== prediction
@njit(cache=True, inline=_into_imu_step, _nrt=False, error_model="numpy")
def _predict_step(x, P, aux, cfg, ts, tg, h, imu_ok):
    """One prediction step of length h [s] with the held IMU specific force (zero-order hold).

    The mean moves now; the covariance step is folded into the pending block (``sync_block`` applies
    it): F_B <- F_h F_B and Q_B <- F_h Q_B F_h' + Q_h, which is exactly P <- F_h P F_h' + Q_h step by
    step, since F_h only couples s and v to v, b_a, m_y and s_f, and Q_h is block diagonal."""
    g = cfg[K_GRAVITY]
    grade = interp_seg(ts, tg, x[S], seg_hint(ts, x[S], aux))
    sin_th = grade / math.sqrt(1.0 + grade * grade)  # grade = tan(theta)
    d = aux[A_DIR]
    fx = aux[A_FX]
    fy = aux[A_FY]
    if imu_ok:
        # dv/dt = d (f_x - b_a - m_y f_y - s_f f_x) - g sin(theta)
        a = d * (fx - x[BA] - x[MY] * fy - x[SF] * fx) - g * sin_th
        q = cfg[K_Q_ACC]
        fsb, fvb = -0.5 * d * h * h, -d * h
    else:
        a = 0.0  # no IMU: constant-velocity model with a wider acceleration noise
        q = cfg[K_Q_NO_IMU]
        fsb, fvb = 0.0, 0.0
    # x = f(x): s += v h + a h^2 / 2 ; v += a h (the GNSS error's decay e *= exp(-H/tau) at the sync)
    x[S] += x[V] * h + 0.5 * a * h * h
    x[V] += a * h
    # F_h = df/dx = I except F[S,V] = h, F[S,BA] = -d h^2/2, F[V,BA] = -d h, F[S,MY] = -d h^2 f_y/2,
    # F[V,MY] = -d h f_y, F[S,SF] = -d h^2 f_x/2, F[V,SF] = -d h f_x (F[GE,GE] = F[GN,GN] at the sync)
    # F_B <- F_h F_B: rows S and V of the columns BA, MY, SF (row S first: it reads row V before)
    aux[A_PB_SB] += h * aux[A_PB_VB] + fsb
    aux[A_PB_VB] += fvb
    aux[A_PB_SM] += h * aux[A_PB_VM] + fsb * fy
    aux[A_PB_VM] += fvb * fy
    aux[A_PB_SF] += h * aux[A_PB_VF] + fsb * fx
    aux[A_PB_VF] += fvb * fx
    aux[A_PB_H] += h  # F_B[S, V]
    # Q_B <- F_h Q_B F_h' + Q_h on the (s, v, b_a) block, F_h = [[1, h, fsb], [0, 1, fvb], [0, 0, 1]]
    qss, qsv, qsb = aux[A_QB_SS], aux[A_QB_SV], aux[A_QB_SB]
    qvv, qvb, qbb = aux[A_QB_VV], aux[A_QB_VB], aux[A_QB_BB]
    rs_s = qss + h * qsv + fsb * qsb  # (F_h Q_B) row s
    rs_v = qsv + h * qvv + fsb * qvb
    rs_b = qsb + h * qvb + fsb * qbb
    rv_v = qvv + fvb * qvb  # (F_h Q_B) row v
    rv_b = qvb + fvb * qbb
    # Q_h: white acceleration, PSD q, and the map registration's random walk in distance travelled
    aux[A_QB_SS] = rs_s + h * rs_v + fsb * rs_b + q * h * h * h / 3.0 + cfg[K_Q_REG] * abs(x[V]) * h
    aux[A_QB_SV] = rs_v + fvb * rs_b + q * h * h / 2.0
    aux[A_QB_SB] = rs_b
    aux[A_QB_VV] = rv_v + fvb * rv_b + q * h
    aux[A_QB_VB] = rv_b
    aux[A_QB_BB] = qbb + cfg[K_Q_BA] * h  # bias random walk


@njit(cache=True, _nrt=False, error_model="numpy")
def restart_gnss_error(x, P, aux):
    """A new receiver solution (after an outage) or a new line (a relocalisation): the GNSS correlated
    error restarts from its stationary distribution, uncorrelated with the rest of the state, and the
    residual history is forgotten (no pairs across the restart). Call after sync_block."""
    gnss_noise.restart(aux)
    gm = aux[A_GM_SIG]
    for i in range(NX):  # no correlation with the rest
        P[GE, i] = 0.0
        P[i, GE] = 0.0
        P[GN, i] = 0.0
        P[i, GN] = 0.0
    x[GE] = 0.0  # E[e_gnss] = 0
    x[GN] = 0.0
    P[GE, GE] = gm * gm  # var(e_gnss) = sigma_g^2 per axis
    P[GN, GN] = gm * gm


@njit(cache=True, _nrt=False, error_model="numpy")
def sync_block(x, P, aux, cfg, cnt):
    """Bring P (and the GNSS error's mean) up to the state time: P = F_B P F_B' + Q_B for the pending
    block of prediction steps, then empty the block. Every reader of P calls this first."""
    hb = aux[A_PB_H]
    if hb == 0.0:
        return
    phi = math.exp(-hb / aux[A_GM_TAU])  # Gauss-Markov transition exp(-H/tau)
    x[GE] *= phi  # e_gnss *= exp(-H/tau)
    x[GN] *= phi
    fsb, fvb = aux[A_PB_SB], aux[A_PB_VB]
    fsm, fvm = aux[A_PB_SM], aux[A_PB_VM]
    fss, fvs = aux[A_PB_SF], aux[A_PB_VF]
    # P = F_B P F_B' + Q_B, with F_B's sparsity written out (rows, then columns)
    for j in range(NX):  # A = F_B P (rows S, V, GE, GN change)
        ps, pv = P[S, j], P[V, j]
        P[S, j] = ps + hb * pv + fsb * P[BA, j] + fsm * P[MY, j] + fss * P[SF, j]
        P[V, j] = pv + fvb * P[BA, j] + fvm * P[MY, j] + fvs * P[SF, j]
        P[GE, j] *= phi
        P[GN, j] *= phi
    for i in range(NX):  # P = A F_B' (columns S, V, GE, GN change)
        a_s, a_v = P[i, S], P[i, V]
        P[i, S] = a_s + hb * a_v + fsb * P[i, BA] + fsm * P[i, MY] + fss * P[i, SF]
        P[i, V] = a_v + fvb * P[i, BA] + fvm * P[i, MY] + fvs * P[i, SF]
        P[i, GE] *= phi
        P[i, GN] *= phi
    P[S, S] += aux[A_QB_SS]  # Q_B: the accumulated (s, v, b_a) block ..
    P[S, V] += aux[A_QB_SV]
    P[V, S] += aux[A_QB_SV]
    P[S, BA] += aux[A_QB_SB]
    P[BA, S] += aux[A_QB_SB]
    P[V, V] += aux[A_QB_VV]
    P[V, BA] += aux[A_QB_VB]
    P[BA, V] += aux[A_QB_VB]
    P[BA, BA] += aux[A_QB_BB]
    P[KO, KO] += cfg[K_Q_KO] * hb  # .. and the uncoupled random walks: odometer scale
    gm = aux[A_GM_SIG]
    P[GE, GE] += gm * gm * (1.0 - phi * phi)  # Gauss-Markov driving noise
    P[GN, GN] += gm * gm * (1.0 - phi * phi)
    P[BG, BG] += cfg[K_Q_BG] * hb  # gyro bias
    P[SG, SG] += cfg[K_Q_SG] * hb  # gyro scale
    block_clear(aux)
    if _symmetrise_moved_floor(P, cfg):
        cnt[C_COV_REPAIR] += 1


@njit(cache=True, inline="always", _nrt=False, error_model="numpy")
def _symmetrise_moved_floor(P, cfg):
    """``_symmetrise_floor`` after ``sync_block``, on the pairs that can differ: F_B moves the rows and
    columns S, V, GE and GN only. An entry with one index outside them is written by the row pass and
    its mirror by the column pass with the same operations on the same (symmetric) values, so the two
    are equal already; (P + P')/2 changes nothing there. Within the 4 x 4 block the passes round
    differently: those 6 pairs are averaged. P is symmetric on entry: every kernel leaves it so (scalar
    updates write mirrored, the rest go through ``condition_cov``)."""
    for a in range(4):
        i = S if a == 0 else (V if a == 1 else (GE if a == 2 else GN))
        for b in range(a + 1, 4):
            j = V if b == 1 else (GE if b == 2 else GN)
            m = 0.5 * (P[i, j] + P[j, i])  # P = (P + P') / 2
            P[i, j] = m
            P[j, i] = m
    return _floor_diag(P, cfg)


@njit(cache=True, _nrt=False, error_model="numpy")
def block_clear(aux):
    """Forget the pending block (after a sync, or when P is replaced by a snapshot)."""
    for k in range(A_PB_H, A_QB_BB + 1):
        aux[k] = 0.0


@njit(cache=True, _nrt=False, error_model="numpy")
def pending_var_s(P, aux):
    """Variance of s of the synced P, without changing anything: (F_B P F_B' + Q_B)[S,S] (status_of reads
    it after every measurement)."""
    hb = aux[A_PB_H]
    if hb == 0.0:
        return P[S, S]
    # f = row S of F_B on (S, V, BA, MY, SF) = (1, H, sb, sm, sf)
    sb, sm_, sf = aux[A_PB_SB], aux[A_PB_SM], aux[A_PB_SF]
    ps = P[S, S] + hb * P[V, S] + sb * P[BA, S] + sm_ * P[MY, S] + sf * P[SF, S]  # (f P)_S
    pv = P[S, V] + hb * P[V, V] + sb * P[BA, V] + sm_ * P[MY, V] + sf * P[SF, V]  # (f P)_V
    pb = P[S, BA] + hb * P[V, BA] + sb * P[BA, BA] + sm_ * P[MY, BA] + sf * P[SF, BA]
    pm = P[S, MY] + hb * P[V, MY] + sb * P[BA, MY] + sm_ * P[MY, MY] + sf * P[SF, MY]
    pf = P[S, SF] + hb * P[V, SF] + sb * P[BA, SF] + sm_ * P[MY, SF] + sf * P[SF, SF]
    return ps + hb * pv + sb * pb + sm_ * pm + sf * pf + aux[A_QB_SS]  # f P f' + Q_B[S,S]


@njit(cache=True, _nrt=False, error_model="numpy")
def pending_var_v(P, aux):
    """Variance of v of the synced P, without changing anything: (F_B P F_B' + Q_B)[V,V]."""
    if aux[A_PB_H] == 0.0:
        return P[V, V]
    # g = row V of F_B on (V, BA, MY, SF) = (1, vb, vm, vf)
    vb, vm, vf = aux[A_PB_VB], aux[A_PB_VM], aux[A_PB_VF]
    gv = P[V, V] + vb * P[BA, V] + vm * P[MY, V] + vf * P[SF, V]  # (g P)_V
    gb = P[V, BA] + vb * P[BA, BA] + vm * P[MY, BA] + vf * P[SF, BA]
    gm = P[V, MY] + vb * P[BA, MY] + vm * P[MY, MY] + vf * P[SF, MY]
    gf = P[V, SF] + vb * P[BA, SF] + vm * P[MY, SF] + vf * P[SF, SF]
    return gv + vb * gb + vm * gm + vf * gf + aux[A_QB_VV]  # g P g' + Q_B[V,V]


@njit(cache=True, inline=_into_imu_step, _nrt=False, error_model="numpy")
def predict_to(x, P, aux, cnt, cfg, ts, tg, t):
    """Propagate the state from aux[A_T_STATE] to t in steps of at most cfg[K_MAX_DT] (the covariance
    into the pending block)."""
    dt_total = t - aux[A_T_STATE]
    if dt_total <= 0.0:
        return
    imu_ok = (t - aux[A_T_IMU]) <= cfg[K_IMU_TIMEOUT]
    if dt_total <= cfg[K_MAX_DT]:  # one step (every IMU sample): ceil(dt / max_dt) = 1, h = dt / 1
        _predict_step(x, P, aux, cfg, ts, tg, dt_total, imu_ok)
        aux[A_T_STATE] = t
        return
    n = int(math.ceil(dt_total / cfg[K_MAX_DT]))
    if n < 1:
        n = 1
    if n > 10000:  # a long confirmed gap: the status is LOST long before, keep the cost bounded
        n = 10000
    h = dt_total / n
    for _ in range(n):
        _predict_step(x, P, aux, cfg, ts, tg, h, imu_ok)
    aux[A_T_STATE] = t
    # F P F' + Q keeps a positive definite P positive definite: the Cholesky check runs after GNSS
    # updates, before snapshots and at init (scalar updates floor the diagonal); after a long
    # prediction (a gap of more than 10 steps) P is brought up to date and checked here
    if n > 10:
        sync_block(x, P, aux, cfg, cnt)
        condition_cov(P, cfg, cnt)


# ============================================================== updates (allocation-free)
# A scalar measurement's Jacobian h has at most five nonzeros: (i0, h0) .. (i4, h4); an index
# < 0 is unused. P h' and the gain K go to the scratch slots of aux (A_WK_PHT, A_WK_K).
@njit(cache=True, _nrt=False, error_model="numpy")
def innovation1(P, aux, i0, h0, i1, h1, i2, h2, i3, h3, i4, h4, r, y):
    """Scalar innovation: P h' (into aux scratch), S = h P h' + r, NIS = y^2 / S. Returns (S, NIS)."""
    for i in range(NX):
        v = 0.0
        if i0 >= 0:
            v += P[i, i0] * h0
        if i1 >= 0:
            v += P[i, i1] * h1
        if i2 >= 0:
            v += P[i, i2] * h2
        if i3 >= 0:
            v += P[i, i3] * h3
        if i4 >= 0:
            v += P[i, i4] * h4
        aux[A_WK_PHT + i] = v  # (P h')_i
    sm = r  # S = h P h' + r
    if i0 >= 0:
        sm += h0 * aux[A_WK_PHT + i0]
    if i1 >= 0:
        sm += h1 * aux[A_WK_PHT + i1]
    if i2 >= 0:
        sm += h2 * aux[A_WK_PHT + i2]
    if i3 >= 0:
        sm += h3 * aux[A_WK_PHT + i3]
    if i4 >= 0:
        sm += h4 * aux[A_WK_PHT + i4]
    return sm, y * y / sm  # NIS = y' S^-1 y


@njit(cache=True, _nrt=False, error_model="numpy")
def apply_update1(x, P, aux, sm, y, cfg, cnt):
    """Scalar update after ``innovation1``: K = P h' / S ; x = x + K y ; Joseph form
    P = (I - K h) P (I - K h)' + K r K', expanded for the rank-one h as P - K (P h')' - (P h') K' + S K K'.

    The expansion is symmetric: the upper triangle is computed and mirrored, then the diagonal floored.
    The Joseph form with S > 0 keeps a positive definite P positive definite; the full check
    (``condition_cov``, with its Cholesky test) runs after every GNSS update, before every rewind
    snapshot (each second while the odometer is clean) and after long predictions.

    The update is abandoned (state unchanged) if it could produce a non-finite value: every factor of
    the correction is checked finite and below 1e100 in magnitude (so no product can overflow), which
    costs O(NX) instead of evaluating the O(NX^2) update twice."""
    if not (math.isfinite(sm) and 0.0 < sm <= BIG):
        return False
    for i in range(NX):
        p = aux[A_WK_PHT + i]
        k = p / sm  # K = P h' S^-1
        aux[A_WK_K + i] = k
        if not (abs(p) <= BIG and abs(k) <= BIG and abs(k * y) <= BIG):
            return False  # also catches NaN
    _gyro_window_shift(aux, aux[A_WK_K + S] * y, aux[A_WK_K + V] * y, aux[A_WK_K + BG] * y,
                       aux[A_WK_K + SG] * y, aux[A_WK_K + MX] * y)
    for i in range(NX):
        x[i] += aux[A_WK_K + i] * y  # x = x + K y
        ki, pi = aux[A_WK_K + i], aux[A_WK_PHT + i]
        for j in range(i, NX):
            kj, pj = aux[A_WK_K + j], aux[A_WK_PHT + j]
            v = P[i, j] - (ki * pj + pi * kj) + sm * (ki * kj)  # Joseph form, rank one
            P[i, j] = v
            P[j, i] = v
    if _floor_diag(P, cfg):
        cnt[C_COV_REPAIR] += 1
    return True


@njit(cache=True, _nrt=False, error_model="numpy")
def _gyro_window_shift(aux, d_s, d_v, d_bg, d_sg, d_mx):
    """Keep the gyro window's residual sum relative to the current state after an update moved it by
    dx: each residual y_i = gz_i - h_i(x) changes by -h_i dx (first order), the sum by -(sum h_i) dx."""
    if aux[A_GY_N] > 0.0:
        aux[A_GY_Y] -= (aux[A_GY_HS] * d_s + aux[A_GY_HV] * d_v + aux[A_GY_N] * d_bg
                        + aux[A_GY_HSG] * d_sg + aux[A_GY_HMX] * d_mx)


@njit(cache=True, _nrt=False, error_model="numpy")
def innovation2(P, aux, H, R, y):
    """Two-row innovation (GNSS): P H' (into aux scratch), S = H P H' + R, S^-1, NIS = y' S^-1 y and
    log det S. Returns (s00, s01, s11, si00, si01, si11, nis, logdet)."""
    for i in range(NX):
        a = 0.0
        b = 0.0
        for k in range(NX):
            a += P[i, k] * H[0, k]
            b += P[i, k] * H[1, k]
        aux[A_WK_PHT + i] = a  # (P H')_i0
        aux[A_WK_PHT + NX + i] = b  # (P H')_i1
    s00 = R[0, 0]
    s01 = R[0, 1]
    s11 = R[1, 1]
    for k in range(NX):  # S = H P H' + R
        s00 += H[0, k] * aux[A_WK_PHT + k]
        s01 += H[0, k] * aux[A_WK_PHT + NX + k]
        s11 += H[1, k] * aux[A_WK_PHT + NX + k]
    det = s00 * s11 - s01 * s01
    si00 = s11 / det  # S^-1 of the symmetric 2 x 2
    si11 = s00 / det
    si01 = -s01 / det
    nis = y[0] * (si00 * y[0] + si01 * y[1]) + y[1] * (si01 * y[0] + si11 * y[1])  # y' S^-1 y
    logdet = math.log(det) if det > 0.0 else 1e300
    return s00, s01, s11, si00, si01, si11, nis, logdet


@njit(cache=True, _nrt=False, error_model="numpy")
def apply_update2(x, P, aux, y, s00, s01, s11, si00, si01, si11, cfg, cnt):
    """Two-row update after ``innovation2``: K = P H' S^-1 ; x = x + K y ; Joseph form
    P = (I - K H) P (I - K H)' + K R K', expanded as P - K (P H')' - (P H') K' + K S K'.

    The update is abandoned (state unchanged) if it would produce a non-finite value."""
    for i in range(NX):
        p0 = aux[A_WK_PHT + i]
        p1 = aux[A_WK_PHT + NX + i]
        k0 = p0 * si00 + p1 * si01  # K = P H' S^-1
        k1 = p0 * si01 + p1 * si11
        aux[A_WK_K + i] = k0
        aux[A_WK_K + NX + i] = k1
        if not (math.isfinite(k0) and math.isfinite(k1) and math.isfinite(x[i] + k0 * y[0] + k1 * y[1])):
            return False
    for rep in range(2):  # pass 0 checks, pass 1 writes: the update is all or nothing
        for i in range(NX):
            ki0, ki1 = aux[A_WK_K + i], aux[A_WK_K + NX + i]
            pi0, pi1 = aux[A_WK_PHT + i], aux[A_WK_PHT + NX + i]
            a0 = ki0 * s00 + ki1 * s01  # (K S)_i
            a1 = ki0 * s01 + ki1 * s11
            for j in range(NX):
                kj0, kj1 = aux[A_WK_K + j], aux[A_WK_K + NX + j]
                pj0, pj1 = aux[A_WK_PHT + j], aux[A_WK_PHT + NX + j]
                v = P[i, j] - (ki0 * pj0 + ki1 * pj1) - (pi0 * kj0 + pi1 * kj1) + (a0 * kj0 + a1 * kj1)
                if rep == 0:
                    if not math.isfinite(v):
                        return False
                else:
                    P[i, j] = v  # Joseph form: P - K (PH')' - (PH') K' + K S K'
    _gyro_window_shift(aux, aux[A_WK_K + S] * y[0] + aux[A_WK_K + NX + S] * y[1],
                       aux[A_WK_K + V] * y[0] + aux[A_WK_K + NX + V] * y[1],
                       aux[A_WK_K + BG] * y[0] + aux[A_WK_K + NX + BG] * y[1],
                       aux[A_WK_K + SG] * y[0] + aux[A_WK_K + NX + SG] * y[1],
                       aux[A_WK_K + MX] * y[0] + aux[A_WK_K + NX + MX] * y[1])
    for i in range(NX):
        x[i] += aux[A_WK_K + i] * y[0] + aux[A_WK_K + NX + i] * y[1]  # x = x + K y
    condition_cov(P, cfg, cnt)
    return True


# ============================================================== timeouts and status
@njit(cache=True, inline=_into_imu_step, _nrt=False, error_model="numpy")
def check_timeouts(aux, cnt, cfg, t):
    """Count each sensor's transition into time-out at time t."""
    flags = (
        (A_IMU_TO, A_T_IMU, K_IMU_TIMEOUT, C_IMU_TIMEOUT),
        (A_ODO_TO, A_T_ODO, K_ODO_TIMEOUT, C_ODO_TIMEOUT),
        (A_GPS_TO, A_T_GPS, K_GPS_TIMEOUT, C_GPS_TIMEOUT),
    )
    for k in range(3):
        a_flag, a_t, k_to, c_to = flags[k]
        out = (t - aux[a_t]) > cfg[k_to]
        if out and aux[a_flag] == 0.0:
            cnt[c_to] += 1
        aux[a_flag] = 1.0 if out else 0.0


@njit(cache=True, _nrt=False, error_model="numpy")
def status_of(x, P, aux, cfg, t):
    """(status, reason bits, sigma_s) at time t >= state time. Status codes as sfa.layout.FilterStatus."""
    if aux[A_INIT] == 0.0:
        return 0, R_NOT_INIT, math.inf
    bits = 0
    imu_to = (t - aux[A_T_IMU]) > cfg[K_IMU_TIMEOUT]
    odo_to = (t - aux[A_T_ODO]) > cfg[K_ODO_TIMEOUT]
    gps_to = (t - aux[A_T_GPS]) > cfg[K_GPS_TIMEOUT]
    if imu_to:
        bits |= R_IMU_TIMEOUT
    if odo_to:
        bits |= R_ODO_TIMEOUT
    if gps_to:
        bits |= R_GPS_TIMEOUT
    if imu_to and odo_to:
        bits |= R_NO_MOTION_SENSOR
    if aux[A_SLIP] != 0.0:
        bits |= R_SLIP
    if aux[A_GPS_REJ] > 0.0:
        bits |= R_GNSS_REJECTING
        if aux[A_STEP_FLAG] != 0.0:
            bits |= R_GNSS_STEP
    if t < aux[A_GPS_HOLD]:
        bits |= R_GNSS_RAMP
    if aux[A_STILL] != 0.0:
        bits |= R_STANDSTILL
    if cfg[K_IMU_STUCK_N] > 0.0 and aux[A_IMU_SAME] >= cfg[K_IMU_STUCK_N]:
        bits |= R_IMU_STUCK
    if t - aux[A_IMU_FAULT_T] <= cfg[K_IMU_FAULT_HOLD]:
        bits |= R_IMU_FAULT
    separated = aux[A_SS_MASK] != 0.0 and t < aux[A_SS_UNTIL]
    if separated:  # a solution-separation detection (sfa.separation)
        m = int(aux[A_SS_MASK])  # (bits of sfa.separation: EXCLUDED_GNSS 1, DETECTED 2)
        if m & 1:
            bits |= R_SEP_GNSS
        if m & 2:
            bits |= R_SEP_DETECTED
    var = pending_var_s(P, aux)
    sigma = math.sqrt(var) if var > 0.0 else 0.0
    if separated:
        # the interval also covers the separated sub-filter, or where the estimate was before it was
        # re-anchored to the sub-filter without GNSS (half-width z sigma + |A_SS_DS|), as for a slip below
        sigma += abs(aux[A_SS_DS]) / cfg[K_Z_INTERVAL]
    if aux[A_SLIP] != 0.0 and aux[A_SLIP_LLR] > -cfg[K_SLIP_ARB_LLR]:
        # slip or accelerometer fault not yet told apart by GNSS: the interval also covers the
        # odometer's position, estimate + A_SLIP_DS (half-width z sigma + |A_SLIP_DS|)
        sigma += abs(aux[A_SLIP_DS]) / cfg[K_Z_INTERVAL]
    if (bits & FAULT_REASONS) != 0:
        # a sensor faulty or missing: widen to the fault_confidence interval (config: fault_confidence)
        sigma *= cfg[K_FAULT_SIGMA_SCALE]
    code, bits = classify(bits, sigma, cfg)
    return code, bits, sigma


@njit(cache=True, _nrt=False, error_model="numpy")
def classify(bits, sigma, cfg):
    """(status, reason bits) from the reason bits and the reported sigma_s: the sigma bits set afresh
    from sigma (``degraded_sigma_m``, ``lost_sigma_m``), then LOST, DEGRADED or NOMINAL."""
    bits &= ~(R_SIGMA_LOST | R_SIGMA_HIGH)
    if sigma > cfg[K_LOST_SIGMA]:
        bits |= R_SIGMA_LOST
    elif sigma > cfg[K_DEGRADED_SIGMA]:
        bits |= R_SIGMA_HIGH
    if (bits & (R_SIGMA_LOST | R_NO_MOTION_SENSOR)) != 0:
        return 3, bits
    if (bits & ~R_STANDSTILL) != 0:
        return 2, bits
    return 1, bits


# ============================================================== initialisation (GROUND TRUTH)
@njit(cache=True, _nrt=False, error_model="numpy")
def step_init(x, P, aux, cnt, mem, cfg, ts, tg, t, s, v, direction):
    """(Re)initialise arc length and speed at time t. v is the speed in the train's forward direction
    (GROUND TRUTH's vx), direction +1 when forward is increasing arc length, -1 otherwise.

    First initialisation: every state and covariance from the configuration. Re-initialisation keeps
    the learned sensor error states (biases, scale factor, GNSS error) and their covariance, and
    resets only the rows/columns of s and v."""
    if not (math.isfinite(t) and math.isfinite(s) and math.isfinite(v)) or abs(v) > 1000.0 \
            or abs(direction) != 1.0:
        return O_INVALID
    if aux[A_INIT] != 0.0:
        sync_block(x, P, aux, cfg, cnt)  # the kept error states' covariance, up to the old state time
    else:
        block_clear(aux)
        gnss_noise.reset(aux, cfg)  # the GNSS error model: the preset's (and the statistics' prior)
        x[:] = 0.0
        P[:, :] = 0.0
        P[BA, BA] = cfg[K_INIT_SIGMA_BA] ** 2
        P[KO, KO] = cfg[K_INIT_SIGMA_KO] ** 2
        P[GE, GE] = aux[A_GM_SIG] ** 2
        P[GN, GN] = aux[A_GM_SIG] ** 2
        P[BG, BG] = cfg[K_INIT_SIGMA_BG] ** 2
        P[MY, MY] = cfg[K_INIT_SIGMA_MY] ** 2
        P[SF, SF] = cfg[K_INIT_SIGMA_SF] ** 2
        P[SG, SG] = cfg[K_INIT_SIGMA_SG] ** 2
        P[MX, MX] = cfg[K_INIT_SIGMA_MX] ** 2
    for i in range(NX):
        P[S, i] = 0.0
        P[i, S] = 0.0
        P[V, i] = 0.0
        P[i, V] = 0.0
    x[S] = s
    x[V] = direction * v  # speed along increasing arc length
    aux[A_DIR] = direction
    P[S, S] = cfg[K_INIT_SIGMA_S] ** 2
    P[V, V] = cfg[K_INIT_SIGMA_V] ** 2
    grade = interp_at(ts, tg, s)
    # until the first IMU sample the held force keeps the speed constant: f_x = b_a + d g sin(theta)
    aux[A_FX] = x[BA] + direction * cfg[K_GRAVITY] * grade / math.sqrt(1.0 + grade * grade)
    aux[A_FY] = 0.0
    aux[A_T_STATE] = t
    aux[A_T_IMU] = t
    aux[A_T_ODO] = t
    aux[A_T_GPS] = t
    aux[A_T_INIT] = t
    aux[A_INIT] = 1.0
    aux[A_SLIP] = 0.0
    aux[A_SLIP_BAD] = 0.0
    aux[A_SLIP_GOOD] = 0.0
    aux[A_CUSUM_P] = 0.0
    aux[A_CUSUM_N] = 0.0
    aux[A_GPS_HOLD] = -math.inf
    aux[A_GPS_REJ] = 0.0
    aux[A_STEP_FLAG] = 0.0
    aux[A_LOGLIK] = 0.0
    aux[A_STILL] = 0.0
    aux[A_IMU_TO] = 0.0
    aux[A_ODO_TO] = 0.0
    aux[A_GPS_TO] = 0.0
    aux[A_IMU_SAME] = 0.0
    aux[A_IMU_FAULT_T] = -math.inf
    aux[A_SLIP_DS] = 0.0
    aux[A_SLIP_LLR] = 0.0
    aux[A_SLIP_S_ODO] = s
    aux[A_SLIP_V_ODO] = x[V]
    aux[A_T_ODO_SEEN] = t
    aux[A_GY_N] = 0.0
    mem_reset(mem)
    cnt[C_INIT] += 1
    condition_cov(P, cfg, cnt)
    return O_INITIALISED


# ============================================================== rewind memory (slip onset)
@njit(cache=True, _nrt=False, error_model="numpy")
def mem_reset(mem):
    """Forget snapshots and IMU history (at (re)initialisation)."""
    mem[:] = 0.0
    mem[MEM_T_ROT] = -math.inf


@njit(cache=True, _nrt=False, error_model="numpy")
def _mem_save(x, P, aux, mem, off):
    for i in range(NX):
        mem[off + i] = x[i]
    k = off + NX
    for i in range(NX):
        for j in range(NX):
            mem[k] = P[i, j]
            k += 1
    mem[k] = aux[A_T_STATE]
    mem[k + 1] = aux[A_FX]
    mem[k + 2] = aux[A_FY]
    mem[k + 3] = 1.0


@njit(cache=True, inline=_into_imu_step, _nrt=False, error_model="numpy")
def _mem_push_imu(mem, t, fx, fy):
    n = int(mem[MEM_HN])
    head = int(mem[MEM_HH])
    if n < NH:
        i = (head + n) % NH
        mem[MEM_HN] = n + 1
    else:
        i = head
        mem[MEM_HH] = (head + 1) % NH
    mem[MEM_H0 + 3 * i] = t
    mem[MEM_H0 + 3 * i + 1] = fx
    mem[MEM_H0 + 3 * i + 2] = fy


@njit(cache=True, _nrt=False, error_model="numpy")
def mem_rotate(x, P, aux, cnt, mem, cfg, t):
    """Every snapshot period (while the odometer is clean): older <- newer <- current state. P gets
    the full check (``condition_cov``, with its Cholesky test) first: a snapshot holds a checked P."""
    if cfg[K_SNAP_PERIOD] <= 0.0 or t - mem[MEM_T_ROT] < cfg[K_SNAP_PERIOD]:
        return
    condition_cov(P, cfg, cnt)
    for k in range(SNAP):  # element by element: the kernels run without numba's allocator (_nrt=False)
        mem[MEM_A + k] = mem[MEM_B + k]
    _mem_save(x, P, aux, mem, MEM_B)  # P is synced: called right after an odometer update
    mem[MEM_T_ROT] = t


@njit(cache=True, _nrt=False, error_model="numpy")
def rewind_imu_only(x, P, aux, cnt, cfg, ts, tg, mem, ba_var_add):
    """Restore the older snapshot, add ``ba_var_add`` [m^2/s^4] to the accelerometer bias variance
    there, and re-propagate to the current time with the IMU alone.

    Returns False (and changes nothing) when there is no snapshot or the IMU ring does not reach back
    to it."""
    if cfg[K_SNAP_PERIOD] <= 0.0 or mem[MEM_A + SNAP - 1] != 1.0:
        return False
    k = MEM_A + NX + NX * NX
    t_snap = mem[k]
    n = int(mem[MEM_HN])
    head = int(mem[MEM_HH])
    if n == 0 or mem[MEM_H0 + 3 * head] > t_snap + 0.05:
        return False
    t_now = aux[A_T_STATE]
    fx_now = aux[A_FX]
    fy_now = aux[A_FY]
    for i in range(NX):
        x[i] = mem[MEM_A + i]
    q = MEM_A + NX
    for i in range(NX):
        for j in range(NX):
            P[i, j] = mem[q]
            q += 1
    aux[A_T_STATE] = t_snap
    block_clear(aux)  # the snapshot's P is at its own time (saved synced); the re-propagation starts a block
    aux[A_GY_N] = 0.0  # the window's residuals belong to the abandoned trajectory
    aux[A_FX] = mem[k + 1]
    aux[A_FY] = mem[k + 2]
    P[BA, BA] += ba_var_add
    for m in range(n):
        i = (head + m) % NH
        ti = mem[MEM_H0 + 3 * i]
        if ti <= t_snap or ti > t_now:
            continue
        predict_to(x, P, aux, cnt, cfg, ts, tg, ti)  # x, P propagated with the held force
        aux[A_FX] = mem[MEM_H0 + 3 * i + 1]
        aux[A_FY] = mem[MEM_H0 + 3 * i + 2]
    predict_to(x, P, aux, cnt, cfg, ts, tg, t_now)
    aux[A_FX] = fx_now
    aux[A_FY] = fy_now
    aux[A_T_STATE] = t_now
    mem[MEM_A + SNAP - 1] = 0.0  # used: the next rewind needs fresh snapshots
    mem[MEM_B + SNAP - 1] = 0.0
    cnt[C_SLIP_REWIND] += 1
    return True


# ============================================================== IMU
@njit(cache=True, inline=_into_imu_step, _nrt=False, error_model="numpy")
def roll_cos(f_lat_mps2, f_up_mps2, fy, fz):
    """cos(phi) of the IMU's roll phi about the track axis (cant plus mounting), from the accelerometer.

    The expected specific force in the track's level frame is (f_lat, f_up) = (v^2 k, -g); the body
    measures it rotated by the roll: fy + i fz = (f_lat + i f_up) exp(-i phi), so
    phi = atan2(f_up, f_lat) - atan2(fz, fy) and cos(phi) = (f_lat fy + f_up fz) / (|f_level| |f_body|)
    (the angle difference's cosine from the two vectors, without the two atan2). A rolled gyro reads the
    yaw rate times cos(phi) (plus the pitch rate times sin(phi), neglected: small, and the y gyro's bias
    is not estimated).
    Returns 1 (no compensation rather than a wrong one) when the measured force is not plausible
    (|f| not within 20 % of the expected) or the roll would exceed 0.35 rad (20 deg): cos(phi) below
    cos(0.35), or the two vectors on either side of atan2's branch cut (phi = atan2 - atan2 then
    differs from the roll by 2 pi)."""
    nb = math.sqrt(fy * fy + fz * fz)
    nl = math.sqrt(f_lat_mps2 * f_lat_mps2 + f_up_mps2 * f_up_mps2)
    if not (0.8 * nl <= nb <= 1.25 * nl):
        return 1.0
    c = (f_lat_mps2 * fy + f_up_mps2 * fz) / (nl * nb)  # cos(phi) = <f_level, f_body> / (|.| |.|)
    if not (c >= COS_MAX_ROLL):  # |phi| > 0.35 rad (NaN: both forces zero)
        return 1.0
    if f_lat_mps2 < 0.0 and fy < 0.0 and (math.copysign(1.0, f_up_mps2) != math.copysign(1.0, fz)):
        return 1.0  # across the branch cut at +-pi: atan2(f_up, f_lat) - atan2(fz, fy) is near +-2 pi
    return c


@njit(cache=True, _nrt=False, error_model="numpy")
def step_imu(x, P, aux, cnt, mem, cfg, ts, tg, tk, t, fx, fy, fz, wx, wy, wz):
    """IMU sample at t: propagate with the previously held force, then hold this sample's force.

    Also updates the standstill detector (EWMA mean/variance of f_x) and, when enabled, applies the
    gyro update gz = v * curvature(s) + b_g."""
    if not (
        math.isfinite(t) and math.isfinite(fx) and math.isfinite(fy) and math.isfinite(fz)
        and math.isfinite(wx) and math.isfinite(wy) and math.isfinite(wz)
    ) or abs(fx) > 300.0 or abs(fy) > 300.0 or abs(fz) > 300.0 or abs(wz) > 100.0:
        cnt[C_IMU_BAD] += 1
        return O_INVALID
    if aux[A_INIT] == 0.0:
        cnt[C_NOT_INIT] += 1
        return O_NOT_INIT
    if aux[A_T_STATE] - t > cfg[K_LATE_TOL]:
        cnt[C_IMU_LATE] += 1
        return O_LATE
    if cfg[K_IMU_STUCK_N] > 0.0:
        # a stuck sensor repeats its last output: real sensor noise never repeats on all six axes
        if fx == aux[A_FX] and fy == aux[A_FY] and fz == aux[A_FZ] and wx == aux[A_WX] \
                and wy == aux[A_WY] and wz == aux[A_GZ]:
            aux[A_IMU_SAME] += 1.0
        else:
            aux[A_IMU_SAME] = 0.0
        if aux[A_IMU_SAME] >= cfg[K_IMU_STUCK_N]:
            # not used: the IMU times out and the filter bridges without it (its time still counts)
            cnt[C_IMU_STUCK] += 1
            predict_to(x, P, aux, cnt, cfg, ts, tg, t)
            check_timeouts(aux, cnt, cfg, t)
            return O_INVALID
    predict_to(x, P, aux, cnt, cfg, ts, tg, t)
    dt_imu = t - aux[A_T_IMU]
    alpha = dt_imu / cfg[K_FX_EWMA_TAU]
    if alpha > 1.0 or cnt[C_IMU_OK] == 0:
        alpha = 1.0
    if alpha < 0.0:
        alpha = 0.0
    d = fx - aux[A_FX_MEAN]
    aux[A_FX_MEAN] += alpha * d  # EWMA mean
    aux[A_FX_VAR] = (1.0 - alpha) * (aux[A_FX_VAR] + alpha * d * d)  # EWMA variance
    aux[A_FX] = fx
    aux[A_FY] = fy
    aux[A_FZ] = fz
    aux[A_WX] = wx
    aux[A_WY] = wy
    aux[A_GZ] = wz
    aux[A_T_IMU] = t
    _mem_push_imu(mem, t, fx, fy)
    cnt[C_IMU_OK] += 1
    check_timeouts(aux, cnt, cfg, t)
    aux[A_LAST_NIS_GYRO] = -1.0
    aux[A_GYRO_OK] = 0.0
    if cfg[K_USE_GYRO] != 0.0 and abs(x[V]) >= cfg[K_GYRO_MIN_SPEED]:
        if aux[A_GY_N] > 0.0 and t - aux[A_GY_T0] > cfg[K_GYRO_AVG_MAX_S]:
            # the window spans too long: apply what it holds (before this sample's residual, which
            # must be taken at the state that update leaves)
            gyro_window_update(x, P, aux, cnt, cfg)
        k, dk_ds = interp_slope_at(ts, tk, x[S], seg_hint(ts, x[S], aux))
        c = 1.0  # cos(roll): the cant turns the gyro's z axis away from the vertical
        if cfg[K_GYRO_TILT] != 0.0:
            c = roll_cos(x[V] * x[V] * aux[A_DIR] * k, -cfg[K_GRAVITY], fy, fz)
        g1 = c * (1.0 + x[SG])
        y = wz - (g1 * x[V] * k + x[BG] + x[MX] * wx)  # y = gz - (c (1 + s_g) v k(s) + b_g + m_x gx)
        if aux[A_GY_N] == 0.0:
            aux[A_GY_T0] = t
            aux[A_GY_Y] = 0.0
            aux[A_GY_HS] = 0.0
            aux[A_GY_HV] = 0.0
            aux[A_GY_HSG] = 0.0
            aux[A_GY_HMX] = 0.0
            aux[A_GY_RC] = 0.0
            aux[A_GY_RC0] = 0.0
            aux[A_GY_RCF] = 0.0
            aux[A_GY_RCF0] = 0.0
        # h = [c (1 + s_g) v dk/ds, c (1 + s_g) k, .., 1 (b_g), .., c v k (s_g), gx (m_x)], summed
        aux[A_GY_N] += 1.0
        aux[A_GY_Y] += y
        aux[A_GY_HS] += g1 * x[V] * dk_ds
        aux[A_GY_HV] += g1 * k
        aux[A_GY_HSG] += c * x[V] * k
        aux[A_GY_HMX] += wx
        # curvature-model error from the geometry: a floor, a share of the curvature itself, and the
        # curve's onset uncertain by the registration length (sigma_k^2 = s0^2 + (r k)^2 + (l dk/ds)^2)
        rcf = (x[V] * cfg[K_CURV_SIGMA]) ** 2
        rc = rcf + (x[V] * (cfg[K_CURV_REL] * k)) ** 2 + (x[V] * (cfg[K_CURV_REG_M] * dk_ds)) ** 2
        # the error is correlated over K_CURV_CORR_M metres: the n_c windows inside that length share
        # one draw of it, so each counts it n_c times over (n_c = L / distance per window, >= 1)
        aux[A_GY_RC0] += rc  # before the inflation: the variance the residual carries
        aux[A_GY_RCF0] += rcf
        if cfg[K_CURV_CORR_M] > 0.0:
            dw = abs(x[V]) * cfg[K_GYRO_AVG_N] * min(max(dt_imu, 1e-3), cfg[K_GYRO_AVG_MAX_S])
            nc = cfg[K_CURV_CORR_M] / dw if dw > 0.0 else 1.0
            if nc > 1.0:
                rc *= nc
                rcf *= nc
        aux[A_GY_RC] += rc  # (v sigma_k)^2 n_c: does not average out
        aux[A_GY_RCF] += rcf
        if aux[A_GY_N] >= cfg[K_GYRO_AVG_N]:
            gyro_window_update(x, P, aux, cnt, cfg)
    else:
        aux[A_GY_N] = 0.0  # a window holds consecutive samples that all qualify
    return O_ACCEPTED


@njit(cache=True, inline="always", _nrt=False, error_model="numpy")
def _two_scales(nf, nc, dff, dcc, dfc):
    """The two curvature-error scales (floor, curve terms) in [1, GYRO_LAM_MAX] that solve the normal
    equations [[dff, dfc], [dfc, dcc]] (lf, lc) = (nf, nc): where one falls below 1 it is held at 1 and
    the other solved alone."""
    det = dff * dcc - dfc * dfc
    lf = (nf * dcc - nc * dfc) / det if det > 0.0 else 1.0
    lc = (nc * dff - nf * dfc) / det if det > 0.0 else 1.0
    if lf < 1.0:
        lf = 1.0
        lc = (nc - dfc) / dcc
    elif lc < 1.0:
        lc = 1.0
        lf = (nf - dfc) / dff
    return min(max(lf, 1.0), GYRO_LAM_MAX), min(max(lc, 1.0), GYRO_LAM_MAX)


@njit(cache=True, _nrt=False, error_model="numpy")
def gyro_window_update(x, P, aux, cnt, cfg):
    """One gyro update from the window's n samples: the mean residual against the mean Jacobian,
    R = sigma_g^2 / n (white sensor noise averages) + lam mean (v sigma_k)^2 n_c (the curvature-model
    error does not; lam is the learned scale of it, 1 unless K_GYRO_AD_M > 0). Empties the window; sets
    the gyro NIS and outcome slots, and learns lam from the innovation."""
    n = aux[A_GY_N]
    aux[A_GY_N] = 0.0  # emptied before the update: its own correction must not shift the window
    sync_block(x, P, aux, cfg, cnt)
    two = cfg[K_GYRO_TWO_SCALES] != 0.0
    lam = aux[A_GY_LAM] if aux[A_GY_LAM] >= 1.0 else 1.0  # learned curvature-error scale (1: none yet)
    lamc = (aux[A_GY_LAMC] if aux[A_GY_LAMC] >= 1.0 else 1.0) if two else lam  # the curve terms' scale
    rw = cfg[K_GYRO_SIGMA] ** 2 / n  # white gyro noise of the window mean
    rc0 = aux[A_GY_RC0] / n  # mean curvature-model variance (v sigma_k)^2
    rcf0 = aux[A_GY_RCF0] / n  # ... its floor's part (v s0)^2
    rcc0 = max(rc0 - rcf0, 0.0)  # ... and its curve terms' (v r k)^2 + (v l dk/ds)^2
    rcf = aux[A_GY_RCF] / n
    # R: the white noise, and the curvature error inflated by n_c and scaled, its curve terms by lamc
    # (written as lam's and lamc's difference: with one scale the same bits as the single-scale R)
    r = rw + lam * aux[A_GY_RC] / n + (lamc - lam) * max(aux[A_GY_RC] / n - rcf, 0.0)
    y = aux[A_GY_Y] / n  # mean residual
    sm, nis = innovation1(P, aux, S, aux[A_GY_HS] / n, V, aux[A_GY_HV] / n, BG, 1.0, SG, aux[A_GY_HSG] / n,
                          MX, aux[A_GY_HMX] / n, r, y)
    aux[A_LAST_NIS_GYRO] = nis
    # the window's Gaussian log-likelihood is -(NIS + log S) / 2: with S inflated by n_c, its NIS counts
    # the curvature error once per n_c windows, and so must its log S (the score weights it by s0 / S)
    s0 = (sm - r) + rw + lam * rc0 + (lamc - lam) * rcc0  # the residual's variance h P h' + rw + .. (no n_c)
    aux[A_LAST_S_GYRO] = sm  # (S >= r > 0; its log is taken only where hypotheses are scored)
    aux[A_LAST_SHARE_GYRO] = s0 / sm
    if cfg[K_GYRO_AD_M] > 0.0 and rc0 > 0.0:
        # innovation-based estimate of the scale: the residual's variance is s0 = h P h' + rw + lam rc0
        # (the n_c inflation counts information, it is not variance), so each window observes
        # a = y^2 - h P h' - rw = lam rc0 + noise of variance 2 s0^2: the weighted least-squares lam is
        # sum(rc0 a / s0^2) / sum(rc0^2 / s0^2), each sum an EWMA over K_GYRO_AD_M metres (weight: the
        # window's length), started from the prior lam = 1 worth GYRO_LAM_PRIOR of that information.
        # Two scales: a = lam rc0_f + lam_c rc0_c, the same least squares in two unknowns
        w = min(abs(x[V]) * max(aux[A_T_IMU] - aux[A_GY_T0], 1e-3) / cfg[K_GYRO_AD_M], 1.0)
        a = y * y - (sm - r) - rw
        i2 = 1.0 / (s0 * s0)
        if aux[A_GY_LAM_DEN] == 0.0:
            aux[A_GY_LAM_NUM] = GYRO_LAM_PRIOR
            aux[A_GY_LAM_DEN] = GYRO_LAM_PRIOR
            aux[A_GY_LAMC_NUM] = GYRO_LAM_PRIOR
            aux[A_GY_LAM_DCC] = GYRO_LAM_PRIOR
            aux[A_GY_LAM_DFC] = 0.0
        if two:
            aux[A_GY_LAM_NUM] += w * (rcf0 * a * i2 - aux[A_GY_LAM_NUM])
            aux[A_GY_LAM_DEN] += w * (rcf0 * rcf0 * i2 - aux[A_GY_LAM_DEN])
            aux[A_GY_LAMC_NUM] += w * (rcc0 * a * i2 - aux[A_GY_LAMC_NUM])
            aux[A_GY_LAM_DCC] += w * (rcc0 * rcc0 * i2 - aux[A_GY_LAM_DCC])
            aux[A_GY_LAM_DFC] += w * (rcf0 * rcc0 * i2 - aux[A_GY_LAM_DFC])
            lf, lc = _two_scales(aux[A_GY_LAM_NUM], aux[A_GY_LAMC_NUM], aux[A_GY_LAM_DEN],
                                 aux[A_GY_LAM_DCC], aux[A_GY_LAM_DFC])
            aux[A_GY_LAM] = lf
            aux[A_GY_LAMC] = lc
        else:
            aux[A_GY_LAM_NUM] += w * (rc0 * a * i2 - aux[A_GY_LAM_NUM])
            aux[A_GY_LAM_DEN] += w * (rc0 * rc0 * i2 - aux[A_GY_LAM_DEN])
            aux[A_GY_LAM] = min(max(aux[A_GY_LAM_NUM] / aux[A_GY_LAM_DEN], 1.0), GYRO_LAM_MAX)
    if nis <= cfg[K_GATE_GYRO]:
        if apply_update1(x, P, aux, sm, y, cfg, cnt):
            cnt[C_GYRO_OK] += 1
            aux[A_GYRO_OK] = 1.0
    else:
        cnt[C_GYRO_GATED] += 1


# ============================================================== odometer (+ slip detection, ZUPT)
@njit(cache=True, _nrt=False, error_model="numpy")
def step_odo(x, P, aux, cnt, mem, cfg, ts, tg, t, speed, sigma):
    """Odometer speed z = d v (1 + k_o) + noise with the sample's own sigma, slip/slide detection
    against the IMU-propagated speed, and a zero-velocity update at detected standstill."""
    if not (math.isfinite(t) and math.isfinite(speed) and math.isfinite(sigma)) or sigma <= 0.0 \
            or abs(speed) > 300.0:
        cnt[C_ODO_BAD] += 1
        return O_INVALID
    if aux[A_INIT] == 0.0:
        cnt[C_NOT_INIT] += 1
        return O_NOT_INIT
    if aux[A_T_STATE] - t > cfg[K_LATE_TOL]:
        cnt[C_ODO_LATE] += 1
        return O_LATE
    predict_to(x, P, aux, cnt, cfg, ts, tg, t)
    sync_block(x, P, aux, cfg, cnt)
    check_timeouts(aux, cnt, cfg, t)
    sig = max(sigma, cfg[K_ODO_SIGMA_MIN])
    d = aux[A_DIR]
    h_v = d * (1.0 + x[KO])  # dh/dv
    h_ko = d * x[V]  # dh/dk_o
    r = sig * sig + cfg[K_ODO_QUANT] ** 2 / 12.0  # sample sigma^2 + quantisation
    y = speed - d * x[V] * (1.0 + x[KO])  # y = z - d v (1 + k_o)
    sm, nis = innovation1(P, aux, V, h_v, KO, h_ko, -1, 0.0, -1, 0.0, -1, 0.0, r, y)
    aux[A_LAST_NIS_ODO] = nis
    v_odo = speed / h_v if h_v != 0.0 else x[V]  # odometer speed along increasing s, scale-corrected
    if aux[A_SLIP] != 0.0:
        # the odometer's own position since the declaration (trapezoid) and its distance beyond the
        # estimate (whatever moved the estimate meanwhile: prediction, gyro or GNSS updates)
        dt_odo = min(max(t - aux[A_T_ODO_SEEN], 0.0), 1.0)
        aux[A_SLIP_S_ODO] += 0.5 * (aux[A_SLIP_V_ODO] + v_odo) * dt_odo
        aux[A_SLIP_DS] = aux[A_SLIP_S_ODO] - x[S]
    aux[A_SLIP_V_ODO] = v_odo
    aux[A_T_ODO_SEEN] = t
    imu_timely = (t - aux[A_T_IMU]) <= cfg[K_IMU_TIMEOUT]
    still = (
        abs(speed) < cfg[K_STILL_SPEED]
        and imu_timely
        and math.sqrt(max(aux[A_FX_VAR], 0.0)) < cfg[K_STILL_FX_STD]
    )
    aux[A_STILL] = 1.0 if still else 0.0
    use = False
    outcome = O_GATED
    by_gnss = aux[A_SLIP] != 0.0 and aux[A_SLIP_LLR] >= cfg[K_SLIP_ARB_LLR]
    if by_gnss or (nis > cfg[K_GATE_ODO] and aux[A_SLIP] != 0.0 and t - aux[A_SLIP_T0] > cfg[K_SLIP_MAX_S]):
        # the accelerometer is the faulty sensor: GNSS agrees with the odometer's position (by_gnss),
        # or the odometer has disagreed for longer than a wheel slips. Re-anchor on the odometer: widen
        # the speed by the disagreement and the accelerometer bias; the arc length moves to the
        # odometer's position (GNSS confirmed it) or its variance grows by that distance
        P[V, V] += y * y
        P[BA, BA] += cfg[K_SLIP_BA_SIGMA] ** 2
        # the gyro sees the speed only through gz = c (1 + s_g) v k: while the faulty accelerometer
        # bridged alone, its speed error (y, relative y / v) went into the gyro scale
        P[SG, SG] += (y / max(abs(x[V]), 1.0)) ** 2
        if by_gnss:
            # the odometer's position does not depend on the accelerometer: keep the variance of s,
            # drop its IMU-bridging correlations (with b_a, v, ...), which would drag it back
            _gyro_window_shift(aux, aux[A_SLIP_DS], 0.0, 0.0, 0.0, 0.0)  # the window follows the move
            x[S] += aux[A_SLIP_DS]
            for i in range(NX):
                if i != S:
                    P[S, i] = 0.0
                    P[i, S] = 0.0
        else:
            P[S, S] += aux[A_SLIP_DS] ** 2
        aux[A_IMU_FAULT_T] = t
        cnt[C_IMU_FAULT] += 1
        sm, nis = innovation1(P, aux, V, h_v, KO, h_ko, -1, 0.0, -1, 0.0, -1, 0.0, r, y)
        use = True
        aux[A_SLIP] = 0.0
        aux[A_SLIP_BAD] = 0.0
        cnt[C_ODO_REANCHOR] += 1
    elif nis > cfg[K_GATE_ODO]:
        aux[A_SLIP_BAD] += 1.0
        aux[A_SLIP_GOOD] = 0.0
        cnt[C_ODO_GATED] += 1
        if aux[A_SLIP] == 0.0 and aux[A_SLIP_BAD] >= cfg[K_SLIP_CONFIRM_N]:
            aux[A_SLIP] = 1.0  # slip / slide declared
            aux[A_SLIP_T0] = t
            aux[A_SLIP_LLR] = 0.0
            # one aid excluded at a time: GNSS, on hold after a ramp detection, comes back to arbitrate
            # the slip and to bound the accelerometer (with both out it would bridge alone)
            aux[A_GPS_HOLD] = -math.inf
            cnt[C_SLIP] += 1
            # the onset samples that passed the gate pulled the speed: rewind and use the IMU alone.
            # The odometer-aided position before the rewind is where the odometer puts the train
            s_odo = x[S]
            rewind_imu_only(x, P, aux, cnt, cfg, ts, tg, mem, 0.0)
            aux[A_SLIP_S_ODO] = s_odo
            aux[A_SLIP_DS] = s_odo - x[S]
    elif aux[A_SLIP] != 0.0:
        aux[A_SLIP_GOOD] += 1.0
        if aux[A_SLIP_GOOD] >= cfg[K_SLIP_RELEASE_N]:
            aux[A_SLIP] = 0.0
            aux[A_SLIP_BAD] = 0.0
            use = True
        else:
            cnt[C_ODO_GATED] += 1
    else:
        aux[A_SLIP_BAD] = 0.0
        use = True
    if use:
        if apply_update1(x, P, aux, sm, y, cfg, cnt):
            cnt[C_ODO_OK] += 1
            aux[A_T_ODO] = t
            outcome = O_ACCEPTED
            if aux[A_SLIP] == 0.0 and aux[A_SLIP_BAD] == 0.0 and nis <= cfg[K_GATE_ODO] / 4.0:
                mem_rotate(x, P, aux, cnt, mem, cfg, t)
    if still:
        # zero-velocity pseudo-measurement: z = 0 = v + noise(zupt_sigma)
        sync_block(x, P, aux, cfg, cnt)  # (a rewind above re-propagated P into a new block)
        y = -x[V]
        r = cfg[K_ZUPT_SIGMA] ** 2
        sm, nis = innovation1(P, aux, V, 1.0, -1, 0.0, -1, 0.0, -1, 0.0, -1, 0.0, r, y)  # h = [0, 1, 0, ..]
        if nis <= cfg[K_GATE_ZUPT]:
            if apply_update1(x, P, aux, sm, y, cfg, cnt):
                cnt[C_ZUPT] += 1
    return outcome


# ============================================================== GNSS
@njit(cache=True, inline="always", _nrt=False, error_model="numpy")
def evidence_weight(t, t_prev, interval):
    """The share of an independent measurement's evidence a measurement at t carries, t_prev the
    previous one: min(1, (t - t_prev) / interval); 1 with the interval 0 or no previous measurement.
    Measurements closer than ``interval`` [s] share their correlated error."""
    if interval <= 0.0 or not math.isfinite(t_prev):
        return 1.0
    return min(1.0, max(t - t_prev, 0.0) / interval)


@njit(cache=True, inline="always", _nrt=False, error_model="numpy")
def gps_evidence_weight(t, t_prev, cfg):
    """The share of an independent fix's evidence a fix at t carries, t_prev the previous fix in use:
    :func:`evidence_weight` over cusum_min_interval_s. Fixes faster than that share their correlated
    error (and the map's): the ramp CUSUM (step_gps) and the hypotheses' score (sfa.bank.run_segment)
    weight them by it."""
    return evidence_weight(t, t_prev, cfg[K_CUSUM_DT])


@njit(cache=True, inline="always", _nrt=False, error_model="numpy")
def gps_invalid(t, east, north, sigma_h):
    """A GNSS fix no step may use (counted invalid): non-finite, beyond 1e7 m, sigma_h > 1e4 m or infinite."""
    return not (math.isfinite(t) and math.isfinite(east) and math.isfinite(north)) \
        or abs(east) > 1e7 or abs(north) > 1e7 or (math.isfinite(sigma_h) and sigma_h > 1e4) \
        or math.isinf(sigma_h)


@njit(cache=True, _nrt=True)  # allocates H: numba's allocator, whatever the caller's flags
def gps_model(x, ts, te, tn, dl, s_lin):
    """h(x*) = point_at(s_lin - v dl) + (e_gnss, n_gnss) and its Jacobian rows (2 x NX) at x*, the state
    with its arc length replaced by s_lin (the linearisation point; s_lin = x[S]: the plain EKF).

    dl >= 0 is how much older the fix is than the state (late-fix back-propagation; 0 normally)."""
    s_eval = s_lin - x[V] * dl
    e, n, de, dn = geom_at(ts, te, tn, s_eval)
    H = np.zeros((2, NX))
    H[0, S] = de  # dh/ds = tangent
    H[1, S] = dn
    H[0, V] = -dl * de
    H[1, V] = -dl * dn
    H[0, GE] = 1.0
    H[1, GN] = 1.0
    return e + x[GE], n + x[GN], H, de, dn


@njit(cache=True, _nrt=True)  # allocates R
def gps_noise_matrix(cfg, sw, ue, un, dl, sl2):
    """R of a fix: sw^2 I + sl2 n n' (n = unit normal to the track; sl2 the centre line's lateral
    variance as this fix counts it, :func:`lateral_variance`; (ue, un) the unit tangent), plus, for a fix
    dl > 0 older than the state, the speed noise over dl, q dl^3 / 3, along the tangent."""
    R = np.zeros((2, 2))
    R[0, 0] = sw * sw + sl2 * un * un
    R[1, 1] = sw * sw + sl2 * ue * ue
    R[0, 1] = -sl2 * ue * un
    R[1, 0] = R[0, 1]
    if dl > 0.0:
        qa = cfg[K_Q_ACC] * dl * dl * dl / 3.0
        R[0, 0] += qa * ue * ue
        R[1, 1] += qa * un * un
        R[0, 1] += qa * ue * un
        R[1, 0] += qa * ue * un
    return R


@njit(cache=True, _nrt=False)
def lateral_variance(x, aux, cfg, t):
    """The centre line's lateral variance in a fix's R [m^2]: sigma_lat^2, times n_c = L / (|v| dt)
    (>= 1, at most LAT_NC_MAX) when the error is correlated over L = K_TRACK_LAT_CORR_M metres and the
    train moved |v| dt since the last fix in use: the n_c fixes inside one correlation length see one
    draw of the map's offset, which does not average out (at a standstill they all see the same)."""
    sl2 = cfg[K_TRACK_LAT] ** 2
    if cfg[K_TRACK_LAT_CORR_M] > 0.0:
        step = abs(x[V]) * max(t - aux[A_T_GPS], 0.0)
        nc = cfg[K_TRACK_LAT_CORR_M] / step if step * LAT_NC_MAX > cfg[K_TRACK_LAT_CORR_M] else LAT_NC_MAX
        if nc > 1.0:
            sl2 *= nc
    return sl2


@njit(cache=True, _nrt=True)  # calls gps_model (allocates)
def step_gps(x, P, aux, cnt, cfg, ts, te, tn, tg, t, east, north, sigma_h, fix_quality):
    """GNSS fix at t, already in the database's local metric frame (east, north) [m].

    sigma_h <= 0 or NaN: not reported; fix_quality < 0: not reported; 0: no fix."""
    if fix_quality == 0:
        cnt[C_GPS_NOFIX] += 1
        return O_NO_FIX
    if gps_invalid(t, east, north, sigma_h):
        cnt[C_GPS_BAD] += 1
        return O_INVALID
    if aux[A_INIT] == 0.0:
        cnt[C_NOT_INIT] += 1
        return O_NOT_INIT
    dl = aux[A_T_STATE] - t
    if dl > cfg[K_GPS_LATE_MAX]:
        cnt[C_GPS_LATE] += 1
        return O_LATE
    if dl <= 0.0:
        predict_to(x, P, aux, cnt, cfg, ts, tg, t)
        dl = 0.0
    sync_block(x, P, aux, cfg, cnt)
    if t - aux[A_T_GPS] > cfg[K_GPS_TIMEOUT] and aux[A_GPS_REJ] == 0.0:
        restart_gnss_error(x, P, aux)  # after an outage the receiver computes a new solution
    check_timeouts(aux, cnt, cfg, max(t, aux[A_T_STATE]))
    if cfg[K_AD_WINDOW] > 0.0:  # the fix's distance from the line into the GNSS statistics (gnss_noise)
        c_x, n_e, n_n, s_foot = cross_track(ts, te, tn, x[S] - x[V] * dl, east, north)
        gnss_noise.observe(aux, cfg, t, c_x, n_e, n_n, s_foot, sigma_h)
    # white noise: the model's white sigma, scaled up when the receiver reports a worse sigma_h
    sw = gnss_noise.white_sigma(aux, sigma_h)
    sl2 = lateral_variance(x, aux, cfg, t)
    # iterated EKF in the arc length (Bell & Cathey): h is linearised at the posterior's s, found by at
    # most GPS_IEKF_ITERATIONS Gauss-Newton steps from the prior's. Where the line bends between the
    # estimate and the fix, the tangent at the estimate points away from the fix and one linearisation's
    # NIS grows with the square of the bend's offset, not with the distance along the line: a widened
    # arc-length variance would never re-admit a fix past a curve
    y = np.zeros(2)
    s_lin = x[S]
    # the linearisation point stays where the prior admits the train: within the gate's sigmas of the
    # prior's arc length (a linear update that passes the gate moves s by at most sqrt(gate P_ss), since
    # |K_s y| <= sqrt(P_ss NIS)). Beyond it, a fix off a curved line can lie on the tangent at some far
    # point, and a fix the prior rejects would pass there with a small NIS
    s_reach = math.sqrt(cfg[K_GATE_GPS] * P[S, S])
    for it in range(GPS_IEKF_ITERATIONS + 1):
        he, hn, H, de, dn = gps_model(x, ts, te, tn, dl, s_lin)
        y[0] = east - he - de * (x[S] - s_lin)  # y = z - h(x*) - H (x - x*): x - x* is along s only
        y[1] = north - hn - dn * (x[S] - s_lin)
        tnorm = math.sqrt(de * de + dn * dn)
        ue = de / tnorm
        un = dn / tnorm
        R = gps_noise_matrix(cfg, sw, ue, un, dl, sl2)
        s00, s01, s11, si00, si01, si11, nis, logdet = innovation2(P, aux, H, R, y)
        if it == GPS_IEKF_ITERATIONS:
            break
        w0 = si00 * y[0] + si01 * y[1]  # S^-1 y
        w1 = si01 * y[0] + si11 * y[1]
        s_next = x[S] + aux[A_WK_PHT + S] * w0 + aux[A_WK_PHT + NX + S] * w1  # s + (P H' S^-1 y)_s
        s_next = min(max(s_next, x[S] - s_reach), x[S] + s_reach)
        if abs(s_next - s_lin) < GPS_IEKF_TOL_M:
            break
        s_lin = s_next
    aux[A_LAST_NIS_GPS] = nis
    along = y[0] * ue + y[1] * un  # along-track component of the innovation [m]
    if aux[A_SLIP] != 0.0 and (aux[A_SLIP_LLR] > -cfg[K_SLIP_ARB_LLR] or nis > cfg[K_GATE_GPS]):
        # a declared slip not yet confirmed, or confirmed and now contradicted by a fix the IMU-bridged
        # estimate fails (the vote goes on from the floor, -slip_arbitration_log_ratio: a sequential test
        # that never latches): GNSS arbitrates instead of correcting (an update would let
        # the correlated GNSS error state absorb the very difference being tested). The fix against the
        # odometer's position, estimate + A_SLIP_DS along the tangent: log-likelihood ratio (equal S)
        # (NIS - NIS_odo) / 2, NIS capped (robust); a fix neither position explains carries no vote
        ds = aux[A_SLIP_DS]
        y0 = y[0] - de * ds
        y1 = y[1] - dn * ds
        nis_odo = y0 * (si00 * y0 + si01 * y1) + y1 * (si01 * y0 + si11 * y1)
        if min(nis, nis_odo) <= cfg[K_GATE_GPS]:
            cap = cfg[K_GPS_MAX_LOGLIK_NIS]
            # a fix dt after the previous one in use votes min(1, dt / cusum_min_interval_s) of an
            # independent fix's log-likelihood ratio (gps_evidence_weight): a 10 Hz receiver's fixes,
            # counted one by one, declared the accelerometer faulty 1.5 s into a wheel spin
            wt = gps_evidence_weight(t, aux[A_T_GPS], cfg)
            llr = aux[A_SLIP_LLR] + wt * 0.5 * (min(nis, cap) - min(nis_odo, cap))
            aux[A_SLIP_LLR] = max(llr, -cfg[K_SLIP_ARB_LLR])
            aux[A_T_GPS] = t  # GNSS is alive and in use
        cnt[C_GPS_HELD] += 1
        return O_HELD_OFF
    if t < aux[A_GPS_HOLD]:
        # a ramp hold-off keeps the fixes out of the state; they still arbitrate a declared slip (above):
        # the vote compares two positions with the same fix, and excluding GNSS must not leave the
        # accelerometer alone against an odometer the fixes agree with
        cnt[C_GPS_HELD] += 1
        return O_HELD_OFF
    if nis > cfg[K_GATE_GPS]:
        cnt[C_GPS_GATED] += 1
        aux[A_GPS_REJ] += 1.0
        if aux[A_GPS_REJ] == 1.0:
            aux[A_T_FIRST_GPS_REJ] = t
            aux[A_REJ_DS] = along
            aux[A_REJ_MAXDEV] = 0.0
            aux[A_REJ_E] = east
            aux[A_REJ_N] = north
            aux[A_REJ_S] = x[S]
            if math.sqrt(y[0] * y[0] + y[1] * y[1]) >= cfg[K_STEP_MIN_M]:
                aux[A_STEP_FLAG] = 1.0  # a jump: large innovation after accepted fixes
                cnt[C_STEP] += 1
        else:
            aux[A_REJ_MAXDEV] = max(aux[A_REJ_MAXDEV], abs(along - aux[A_REJ_DS]))
        if t - aux[A_T_FIRST_GPS_REJ] >= cfg[K_REACQ_S] and aux[A_REJ_MAXDEV] <= cfg[K_REACQ_CONSIST_M]:
            # GNSS has been self-consistent and away from the estimate for long: the estimate is the
            # one that is wrong. Widen the arc-length variance by the residual and accept.
            P[S, S] += along * along + y[0] * y[0] + y[1] * y[1]
            s00, s01, s11, si00, si01, si11, nis, logdet = innovation2(P, aux, H, R, y)
            if apply_update2(x, P, aux, y, s00, s01, s11, si00, si01, si11, cfg, cnt):
                cnt[C_GPS_REACQ] += 1
                aux[A_GPS_REJ] = 0.0
                aux[A_STEP_FLAG] = 0.0
                aux[A_T_GPS] = t
                aux[A_GPS_E] = east
                aux[A_GPS_N] = north
                return O_ACCEPTED
        elif t - aux[A_T_FIRST_GPS_REJ] >= cfg[K_REACQ_S]:
            # inconsistent rejected fixes: start a new run from this fix, and ask for a relocalisation
            # (the caller spawns hypotheses where this fix is on the network: TrackFilter._relocalise)
            if cfg[K_RELOC] != 0.0:
                aux[A_RELOC] = 1.0
                aux[A_RELOC_E] = east
                aux[A_RELOC_N] = north
                aux[A_RELOC_E0] = aux[A_REJ_E]
                aux[A_RELOC_N0] = aux[A_REJ_N]
                aux[A_RELOC_DS] = aux[A_DIR] * (x[S] - aux[A_REJ_S])  # distance travelled forward
            aux[A_GPS_REJ] = 1.0
            aux[A_T_FIRST_GPS_REJ] = t
            aux[A_REJ_DS] = along
            aux[A_REJ_MAXDEV] = 0.0
            aux[A_REJ_E] = east
            aux[A_REJ_N] = north
            aux[A_REJ_S] = x[S]
        return O_GATED
    # ramp detection: two-sided CUSUM of the normalised along-track innovation
    s_along = ue * (s00 * ue + s01 * un) + un * (s01 * ue + s11 * un)  # u' S u
    r = along / math.sqrt(s_along)
    k = cfg[K_CUSUM_K]
    # a fix dt after the previous one in use adds min(1, dt / cusum_min_interval_s) of an independent
    # fix's evidence (weighted CUSUM): the detector's run lengths do not shrink with the fix rate
    wt = gps_evidence_weight(t, aux[A_T_GPS], cfg)
    if aux[A_SLIP] != 0.0:
        # while the odometer is out for a slip GNSS is the only aid, and there is no reference to tell a
        # ramp from the accelerometer's drift: nothing accumulates (nor fires the moment the slip ends)
        wt = 0.0
        aux[A_CUSUM_P] = 0.0
        aux[A_CUSUM_N] = 0.0
    aux[A_CUSUM_P] = max(0.0, aux[A_CUSUM_P] + wt * (r - k))
    aux[A_CUSUM_N] = max(0.0, aux[A_CUSUM_N] + wt * (-r - k))
    if aux[A_CUSUM_P] > cfg[K_CUSUM_H] or aux[A_CUSUM_N] > cfg[K_CUSUM_H]:
        cnt[C_RAMP] += 1
        aux[A_RAMP_T] = t
        aux[A_GPS_HOLD] = t + cfg[K_GPS_HOLDOFF_S]
        aux[A_CUSUM_P] = 0.0
        aux[A_CUSUM_N] = 0.0
        cnt[C_GPS_GATED] += 1
        return O_GATED
    if not apply_update2(x, P, aux, y, s00, s01, s11, si00, si01, si11, cfg, cnt):
        cnt[C_GPS_BAD] += 1
        return O_INVALID
    aux[A_GPS_REJ] = 0.0
    aux[A_STEP_FLAG] = 0.0
    aux[A_T_GPS] = t
    aux[A_GPS_E] = east
    aux[A_GPS_N] = north
    cnt[C_GPS_OK] += 1
    if dl > 0.0:
        cnt[C_GPS_LATE_USED] += 1
    return O_ACCEPTED
