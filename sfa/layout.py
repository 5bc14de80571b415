"""Named indices of the filter's flat arrays (state, auxiliary scalars, counters, configuration).

The compiled kernels (``sfa.kernels``) work on plain float64/int64 arrays so that the per-message
path (``TrackFilter.process``) and the batch replay path (``sfa.batch``) run the very same code with
no Python object in the inner loop. This module is the single place that names every slot; the
configuration slots ``K_*`` come from the fields of ``sfa.config.FilterConfig`` that declare them.
Pure constants only: importing it is cheap (no numba, no numpy; sfa.config is standard library only).
"""

from __future__ import annotations

from enum import IntEnum

from sfa.config import CFG_SLOTS

# ---------------------------------------------------------------- state vector x (float64[NX])
S = 0  #: arc length along the current line [m]
V = 1  #: speed along the track, positive towards increasing arc length [m/s]
BA = 2  #: along-track accelerometer bias (incl. pitch misalignment) [m/s^2]
KO = 3  #: odometer scale-factor error: odometer reads v * (1 + KO) [dimensionless]
GE = 4  #: GNSS correlated (first-order Gauss-Markov) error, east [m]
GN = 5  #: GNSS correlated (first-order Gauss-Markov) error, north [m]
BG = 6  #: gyro z bias [rad/s] (observed only when the gyro update is enabled)
MY = 7  #: IMU yaw misalignment: the forward axis picks up MY * f_y (centripetal force in curves) [rad]
SF = 8  #: accelerometer forward scale-factor error: f_x reads (1 + SF) times the true force [-]
SG = 9  #: gyro z scale-factor error: the yaw rate reads (1 + SG) times the true rate [-]
MX = 10  #: gyro z axis tilt towards x: the yaw gyro picks up MX * (roll rate), seen in cant transitions [rad]
NX = 11

STATE_NAMES = (
    "s_m", "v_mps", "accel_bias_mps2", "odo_scale", "gnss_east_m", "gnss_north_m", "gyro_bias_radps",
    "imu_yaw_misalignment_rad", "accel_scale", "gyro_scale",
    "gyro_roll_coupling_rad",
)

# ---------------------------------------------------------------- auxiliary scalars aux (float64[NAUX])
A_T_STATE = 0  #: time the state refers to [s]
A_T_IMU = 1  #: time of the last accepted IMU sample [s]
A_T_ODO = 2  #: time of the last accepted odometer sample [s]
A_T_GPS = 3  #: time of the last accepted GPS fix [s]
A_FX = 4  #: held along-track specific force from the last IMU sample [m/s^2]
A_INIT = 5  #: 1 once initialised
A_SLIP = 6  #: 1 while an odometer slip/slide is declared
A_SLIP_BAD = 7  #: consecutive odometer samples outside the gate
A_SLIP_GOOD = 8  #: consecutive odometer samples back inside the gate while a slip is declared
A_CUSUM_P = 9  #: GNSS ramp CUSUM, positive side [sigma]
A_CUSUM_N = 10  #: GNSS ramp CUSUM, negative side [sigma]
A_GPS_HOLD = 11  #: GNSS fixes are held off (not used) until this time [s]
A_GPS_REJ = 12  #: consecutive GNSS fixes rejected by the gate
A_FX_MEAN = 13  #: exponentially weighted mean of the IMU forward specific force [m/s^2]
A_FX_VAR = 14  #: exponentially weighted variance of the IMU forward specific force [m^2/s^4]
A_STILL = 15  #: 1 while standstill is detected
A_GZ = 16  #: held gyro z rate [rad/s]
A_SLIP_T0 = 17  #: time the current slip was declared [s]
A_LOGLIK = 18  #: cumulative GNSS log-likelihood (hypothesis scoring at junctions)
A_LAST_NIS_GPS = 19  #: last GNSS normalised innovation squared
A_LAST_NIS_ODO = 20  #: last odometer normalised innovation squared
A_T_FIRST_GPS_REJ = 21  #: time of the first fix of the current rejection run [s]
A_T_INIT = 22  #: time of the last (re)initialisation [s]
A_STEP_FLAG = 23  #: 1 while the current GNSS rejection run was classified as a step
A_RAMP_T = 24  #: time of the last ramp detection [s]
A_IMU_TO = 25  #: 1 while the IMU is timed out (for counting transitions)
A_ODO_TO = 26  #: 1 while the odometer is timed out
A_GPS_TO = 27  #: 1 while GNSS is timed out
A_GPS_E = 28  #: last GNSS fix, local east [m] (for the re-acquisition consistency test)
A_GPS_N = 29  #: last GNSS fix, local north [m]
A_REJ_DS = 30  #: along-track residual of the first fix of the current rejection run [m]
A_REJ_MAXDEV = 31  #: largest change of that residual within the run [m]
A_DIR = 32  #: sense of travel: +1 the train's forward is increasing arc length, -1 decreasing
A_FY = 33  #: held lateral specific force from the last IMU sample [m/s^2]
A_LAST_NIS_GYRO = 34  #: last gyro normalised innovation squared (-1: no gyro update evaluated)
A_GYRO_OK = 35  #: 1 when the last gyro update was applied
A_FZ = 36  #: vertical specific force of the last IMU sample [m/s^2] (stuck-sensor detection)
A_WX = 37  #: roll rate of the last IMU sample [rad/s] (stuck-sensor detection)
A_WY = 38  #: pitch rate of the last IMU sample [rad/s] (stuck-sensor detection)
A_IMU_SAME = 39  #: consecutive IMU samples bit-identical to the previous one
A_SLIP_DS = 40  #: during a slip, the odometer's position minus the estimate's (A_SLIP_S_ODO - s) [m]
A_T_ODO_SEEN = 41  #: time of the last valid odometer sample, used or not [s]
A_IMU_FAULT_T = 42  #: time the accelerometer was last declared faulty (long slip, or by GNSS) [s]
#: The gyro window: the residuals and Jacobians of consecutive IMU samples, averaged into one gyro
#: update (docs/filter.md, "Gyro update"). The residual sum is kept relative to the current state.
A_GY_N = 43  #: samples in the window
A_GY_T0 = 44  #: time of the window's first sample [s]
A_GY_Y = 45  #: sum of the residuals gz - h(x) [rad/s]
A_GY_HS = 46  #: sum of dh/ds [rad/s/m]
A_GY_HV = 47  #: sum of dh/dv [1/m]
A_GY_HSG = 48  #: sum of dh/ds_g [rad/s]
A_GY_HMX = 49  #: sum of dh/dm_x (the roll rates) [rad/s]
A_GY_RC = 50  #: sum of the curvature-model variances (v sigma_k)^2 [rad^2/s^2]
A_SEG = 51  #: segment index of the last geometry lookup (a hint: every lookup checks it)
#: The covariance prediction pending since P was last brought up to the state time (``sync_block``):
#: the mean is predicted at every step, P once per block of steps with the block's transition
#: F_B = I + (these coefficients) and noise Q_B (docs/filter.md, "Prediction").
A_PB_H = 52  #: length of the pending block [s] (0: P is current)
A_PB_SB = 53  #: F_B[S, BA] [s^2]
A_PB_VB = 54  #: F_B[V, BA] [s]
A_PB_SM = 55  #: F_B[S, MY] [m]
A_PB_VM = 56  #: F_B[V, MY] [m/s]
A_PB_SF = 57  #: F_B[S, SF] [m]
A_PB_VF = 58  #: F_B[V, SF] [m/s]
#: the block's process noise in the (S, V, BA) block, accumulated step by step as Q_B = F_h Q_B F_h' + Q_h
A_QB_SS = 59  #: [m^2]
A_QB_SV = 60  #: [m^2/s]
A_QB_SB = 61  #: [m * m/s^2]
A_QB_VV = 62  #: [m^2/s^2]
A_QB_VB = 63  #: [m/s * m/s^2]
A_QB_BB = 64  #: [m^2/s^4]
#: log-likelihood ratio, over the GNSS fixes of the current slip, of "the accelerometer is faulty" (the
#: fixes agree with the estimate + A_SLIP_DS) against "the odometer slips" (they agree with the estimate)
A_SLIP_LLR = 65
A_SLIP_S_ODO = 66  #: the odometer's own position during the current slip, integrated from its declaration [m]
A_SLIP_V_ODO = 67  #: last odometer speed along increasing arc length, scale-corrected [m/s]
#: The GNSS error model in use (``sfa.gnss_noise``): the preset's values, or their estimates from the
#: fixes' cross-track residuals when ``gps_adaptive_window_s`` > 0 (docs/filter.md, "Adaptive GNSS
#: error model").
A_GM_SIG = 68  #: correlated (Gauss-Markov) error per axis, steady sigma [m]
A_GM_TAU = 69  #: its correlation time [s]
A_GW_SIG = 70  #: white error per axis [m]
A_AD_T = 71  #: time of the last residual taken into the statistics [s] (NaN: none yet)
A_AD_SH = 72  #: weighted mean of the reported sigma_h [m] (the white error scales with sigma_h / this)
#: Statistics of the cross-track residual c: AD_NMOM moments E[c(t) c(t - L)], index 0 the lag-0
#: moment E[c^2], then the history lags AD_LAGS_S; each with its mean lag L and its weight (seconds of
#: data, capped by the window)
#: lags of the moments 1.. [s]: up to 100 s, so that a correlation time near the 120 s real receivers
#: show is told from a constant (with 40 s the last, the fit ran to its 1000 s bound; docs/filter.md)
AD_LAGS_S = (2.0, 5.0, 15.0, 40.0, 100.0)
AD_NMOM = 1 + len(AD_LAGS_S)
A_AD_M = 73  #: moments [m^2]
A_AD_L = A_AD_M + AD_NMOM  #: mean lags [s]
A_AD_W = A_AD_L + AD_NMOM  #: weights [s]
#: History of residuals at least AD_HIST_SPACING_S apart: a ring of AD_HIST entries of AD_ENTRY values
#: (t [s], c [m], normal east, normal north, arc length of the foot [m], A_STILL when stored);
#: A_AD_HN entries are valid, the next goes to index A_AD_HI
AD_ENTRY = 6
#: structure function at a standstill, E[(c(t) - c(t - L))^2] / 2 of pairs both at the standstill,
#: its mean lags and weights (index 0 unused); like A_AD_M, A_AD_L, A_AD_W each set AD_NMOM apart
#: (gnss_noise._accumulate addresses a set by its first slot)
A_AD_D = A_AD_W + AD_NMOM
A_AD_DL = A_AD_D + AD_NMOM
A_AD_DW = A_AD_DL + AD_NMOM
A_AD_HN = A_AD_DW + AD_NMOM
A_AD_HI = A_AD_HN + 1
#: 1 while this hypothesis's statistics must not learn: several hypotheses are alive and it is not the
#: reported one (``gnss_noise.share``, called by TrackFilter and the fast replay before each GNSS fix)
A_AD_FREEZE = A_AD_HI + 1
A_AD_HIST = A_AD_FREEZE + 1
AD_HIST = 110  #: history entries (covers AD_HIST x AD_HIST_SPACING_S seconds, beyond the longest lag)
AD_HIST_SPACING_S = 1.0  #: spacing of the history entries [s]
#: start of the correlation-time grid the model is fitted over (its top: FilterConfig
#: gps_adaptive_tau_max_s) [s]
AD_TAU_MIN_S = 1.0
#: Maximum-likelihood GNSS error model (``gps_adaptive_ml``; sfa.gnss_noise.ml_update): a bank of
#: scalar Kalman filters of the cross-track residual, one per grid point (AD_ML_R white shares of the
#: total variance x the TAU_N correlation times of the moment fit's grid, tau-major), each with unit
#: total variance; per point its state and variance, and the forgetting sums of nu^2 / S and log S
AD_ML_R = (0.02, 0.1, 0.2, 0.35, 0.5, 0.65, 0.8, 0.92)
AD_ML_TAU_N = 25  #: correlation times of the grid (gnss_noise.TAU_N: the same grid)
AD_ML_NG = AD_ML_TAU_N * len(AD_ML_R)
A_ML_T = A_AD_HIST + AD_ENTRY * AD_HIST  #: time of the last residual in the bank [s] (NaN: none)
A_ML_N = A_ML_T + 1  #: forgetting count of residuals (the prior's counted as its seconds at 1 Hz) [-]
A_ML_X = A_ML_T + 2  #: per point: the correlated error's estimate [unit]
A_ML_P = A_ML_X + AD_ML_NG  #: its variance [unit^2]
A_ML_A = A_ML_P + AD_ML_NG  #: forgetting sum of nu^2 / S [m^2]
A_ML_B = A_ML_A + AD_ML_NG  #: forgetting sum of log S [-]
#: Scale of the curvature-model variance (>= 1), learned from the gyro innovations when K_GYRO_AD_M > 0
#: (docs/filter.md, "Curvature error"): like the GNSS model, one value for every hypothesis, the
#: reported one's (it lies inside gnss_noise.share's range, and the bank copies it to the others before
#: each IMU sample), so that a wrong hypothesis cannot widen its own model until it fits
A_GY_LAM = A_ML_B + AD_ML_NG
#: its weighted least-squares estimate over the windows, numerator and denominator, each an EWMA:
#: sum(rc0 a / s0^2) and sum(rc0^2 / s0^2) (sfa.kernels.gyro_window_update), so that a window whose
#: modelled curvature error is small next to the gyro's own noise barely moves it
A_GY_LAM_NUM = A_GY_LAM + 1
A_GY_LAM_DEN = A_GY_LAM + 2
#: With K_GYRO_TWO_SCALES the floor's scale is A_GY_LAM and the curve terms' (r k, l dk/ds) their own,
#: A_GY_LAMC: its numerator, and the normal matrix's other two entries sum(rc0_c^2 / s0^2) and
#: sum(rc0_f rc0_c / s0^2) (A_GY_LAM_NUM, A_GY_LAM_DEN then hold the floor's)
A_GY_LAMC = A_GY_LAM + 3
A_GY_LAMC_NUM = A_GY_LAM + 4
A_GY_LAM_DCC = A_GY_LAM + 5
A_GY_LAM_DFC = A_GY_LAM + 6
A_GY_RC0 = A_GY_LAM + 7  #: the window's A_GY_RC before the correlation inflation n_c [rad^2/s^2]
A_GY_RCF0 = A_GY_LAM + 8  #: the floor's part of A_GY_RC0 [rad^2/s^2]
A_GY_RCF = A_GY_LAM + 9  #: the floor's part of A_GY_RC [rad^2/s^2]
#: Scratch for the updates (no meaning between calls): P H' (two columns of NX) and the gain K (two
#: columns of NX). Kept in aux so the compiled updates allocate nothing per measurement.
A_WK_PHT = A_GY_RCF + 1
A_WK_K = A_WK_PHT + 2 * NX
#: Solution separation (``sfa.separation``; docs/filter.md, "Solution separation"), the same in every
#: live hypothesis: what was detected (bits EXCLUDED_GNSS, DETECTED of sfa.separation) until A_SS_UNTIL,
#: and the largest separation or the estimate's jump at the re-anchoring (the interval covers both)
A_SS_MASK = A_WK_K + 2 * NX  #: bit mask (0: nothing detected)
A_SS_UNTIL = A_SS_MASK + 1  #: the exclusion and the widening last until this time [s]
A_SS_DS = A_SS_MASK + 2  #: that separation or jump [m]
#: The current run of rejected fixes: its first fix, local east and north [m], and the arc length then [m]
A_REJ_E = A_SS_MASK + 3
A_REJ_N = A_SS_MASK + 4
A_REJ_S = A_SS_MASK + 5
#: Relocalisation (``TrackFilter._relocalise``; docs/filter.md, "Lines, junctions"): A_RELOC is 1 when a
#: run of rejected fixes as long as ``reacquire_s`` ended without agreeing along this hypothesis's line;
#: that run's last and first fixes, local east and north [m], and the distance the hypothesis travelled
#: forward between them [m]
A_RELOC = A_SS_MASK + 6
A_RELOC_E = A_SS_MASK + 7
A_RELOC_N = A_SS_MASK + 8
A_RELOC_E0 = A_SS_MASK + 9
A_RELOC_N0 = A_SS_MASK + 10
A_RELOC_DS = A_SS_MASK + 11
#: The last gyro window's innovation variance S [(rad/s)^2], and the share of an independent
#: measurement it carries [-]: s0 / S, its residual's variance over S, which counts the curvature error
#: n_c times over (kernels.step_imu: n_c windows share one draw of it), for the hypotheses' score
A_LAST_S_GYRO = A_SS_MASK + 12
A_LAST_SHARE_GYRO = A_SS_MASK + 13
NAUX = A_SS_MASK + 14

# ---------------------------------------------------------------- counters cnt (int64[NCNT])
C_IMU_OK = 0
C_IMU_LATE = 1
C_IMU_BAD = 2
C_ODO_OK = 3
C_ODO_GATED = 4
C_ODO_LATE = 5
C_ODO_BAD = 6
C_GPS_OK = 7
C_GPS_GATED = 8
C_GPS_LATE = 9
C_GPS_BAD = 10
C_GPS_NOFIX = 11
C_ZUPT = 12
C_SLIP = 13
C_STEP = 14
C_RAMP = 15
C_IMU_TIMEOUT = 16
C_ODO_TIMEOUT = 17
C_GPS_TIMEOUT = 18
C_INIT = 19
C_COV_REPAIR = 20
C_NOT_INIT = 21
C_GPS_HELD = 22
C_GPS_REACQ = 23
C_ODO_REANCHOR = 24
C_GYRO_OK = 25
C_GYRO_GATED = 26
C_GPS_LATE_USED = 27
C_SLIP_REWIND = 28
C_TIME_JUMP = 29
C_IMU_STUCK = 30
C_IMU_FAULT = 31
C_SEP_DETECT = 32  #: solution-separation detections (runs of them: an exclusion, or a widening)
C_SEP_EXCLUDED = 33  #: GNSS fixes not used while it is excluded
#: relocalisations: hypotheses added on lines the rejected fixes agree along (TrackFilter._relocalise)
C_RELOC = 34
NCNT = 35

COUNTER_NAMES = (
    "imu_accepted", "imu_late", "imu_invalid",
    "odo_accepted", "odo_gated", "odo_late", "odo_invalid",
    "gps_accepted", "gps_gated", "gps_late", "gps_invalid", "gps_no_fix",
    "zupt_updates", "slip_detections", "gnss_step_detections", "gnss_ramp_detections",
    "imu_timeouts", "odo_timeouts", "gps_timeouts",
    "initialisations", "covariance_repairs", "not_initialised",
    "gps_held_off", "gps_reacquisitions", "odo_reanchors",
    "gyro_accepted", "gyro_gated", "gps_late_applied", "slip_rewinds", "time_jumps_rejected",
    "imu_stuck_samples", "imu_faults", "separation_detections", "separation_excluded",
    "relocalisations",
)
assert len(COUNTER_NAMES) == NCNT

# ---------------------------------------------------------------- rewind memory mem (float64[NMEM])
# Two state snapshots taken about a second apart while the odometer is clean, and a ring of the IMU
# forward specific force since then: when a slip is declared the state is restored to the older
# snapshot and re-propagated with the IMU alone (the odometer samples of the slip onset are dropped).
SNAP = NX + NX * NX + 4  #: one snapshot: x, P (row-major), state time, held f_x, held f_y, valid flag
MEM_A = 0  #: older snapshot
MEM_B = SNAP  #: newer snapshot
MEM_T_ROT = 2 * SNAP  #: time of the last snapshot rotation [s]
MEM_HN = 2 * SNAP + 1  #: IMU samples in the ring
MEM_HH = 2 * SNAP + 2  #: index of the oldest ring entry
MEM_H0 = 2 * SNAP + 3  #: ring start: (t, f_x, f_y) triples
NH = 512  #: ring capacity [samples] (5.1 s at 100 Hz)
NMEM = MEM_H0 + 3 * NH

# ---------------------------------------------------------------- configuration vector cfg (float64[NCFG])
# K_<NAME> = index for every slot, numbered in the order the FilterConfig fields declare them
# (sfa.config.CFG_SLOTS: each field's ``slot(...)``, where its meaning and unit are documented, and
# FilterConfig.to_array fills them). Set here as plain module globals like the indices above: numba
# reads ``K_*`` as compile-time constants, benchmarks/c/cref.py writes them into the C header, and
# sfa.engine keys the compiled engine on sfa/config.py too. Use them by name, never by number.
globals().update({_name: _i for _i, _name in enumerate(CFG_SLOTS)})
NCFG = len(CFG_SLOTS)

# ---------------------------------------------------------------- measurement kinds and result codes
M_IMU = 1
M_ODO = 2
M_GPS = 3
M_INIT = 8


class Outcome(IntEnum):
    """What ``process`` did with one measurement."""

    ACCEPTED = 0  #: used by the filter
    GATED = 1  #: rejected by the chi-square innovation gate (or a declared slip / GNSS fault)
    LATE = 2  #: older than the filter state beyond the late-data policy: dropped and counted
    INVALID = 3  #: non-finite or out-of-range values: rejected and counted
    NOT_INITIALISED = 4  #: arrived before the first GROUND TRUTH / initialisation
    NO_FIX = 5  #: GNSS fix quality 0: carries no position
    INITIALISED = 6  #: GROUND TRUTH (re)initialised the state
    HELD_OFF = 7  #: GNSS fix not used during a hold-off after a ramp detection


# reason bits reported with the status
R_NOT_INIT = 1 << 0
R_IMU_TIMEOUT = 1 << 1
R_ODO_TIMEOUT = 1 << 2
R_GPS_TIMEOUT = 1 << 3
R_SLIP = 1 << 4
R_GNSS_STEP = 1 << 5
R_GNSS_RAMP = 1 << 6
R_SIGMA_HIGH = 1 << 7
R_SIGMA_LOST = 1 << 8
R_NO_MOTION_SENSOR = 1 << 9
R_STANDSTILL = 1 << 10
R_GNSS_REJECTING = 1 << 11
R_IMU_STUCK = 1 << 12
R_IMU_FAULT = 1 << 13
R_SEP_GNSS = 1 << 14  #: solution separation excluded GNSS
R_SEP_DETECTED = 1 << 15  #: solution separation detected a fault it excluded no aid for

REASON_NAMES = {
    R_NOT_INIT: "not_initialised",
    R_IMU_TIMEOUT: "imu_timeout",
    R_ODO_TIMEOUT: "odometer_timeout",
    R_GPS_TIMEOUT: "gnss_timeout",
    R_SLIP: "odometer_slip",
    R_GNSS_STEP: "gnss_step",
    R_GNSS_RAMP: "gnss_ramp",
    R_SIGMA_HIGH: "sigma_high",
    R_SIGMA_LOST: "sigma_too_high",
    R_NO_MOTION_SENSOR: "no_motion_sensor",
    R_STANDSTILL: "standstill",
    R_GNSS_REJECTING: "gnss_rejected",
    R_IMU_STUCK: "imu_stuck",
    R_IMU_FAULT: "imu_fault",
    R_SEP_GNSS: "gnss_excluded",
    R_SEP_DETECTED: "separation_detected",
}

#: a sensor declared faulty or missing: while any is set the reported sigma is widened by K_FAULT_SIGMA_SCALE
FAULT_REASONS = (
    R_SLIP | R_GNSS_STEP | R_GNSS_RAMP | R_IMU_STUCK | R_IMU_FAULT
    | R_GPS_TIMEOUT | R_ODO_TIMEOUT | R_IMU_TIMEOUT | R_SEP_GNSS | R_SEP_DETECTED
)

#: reasons that are informative only (do not degrade the status)
INFO_REASONS = R_STANDSTILL


class FilterStatus(IntEnum):
    """Integrity status of the estimate."""

    INITIALISING = 0  #: no GROUND TRUTH (or other initialisation) yet
    NOMINAL = 1  #: all sensors timely, no fault declared, sigma small
    DEGRADED = 2  #: usable but a sensor is missing or faulty, or sigma is above the degraded threshold
    LOST = 3  #: the interval is too wide to be useful, or no motion sensor is left


_REASONS_CACHE: dict[int, tuple[str, ...]] = {}


def reasons_from_bits(bits: int) -> tuple[str, ...]:
    """Short reason strings, in a fixed order, for a reason bit mask."""
    found = _REASONS_CACHE.get(bits)
    if found is None:
        found = tuple(name for bit, name in REASON_NAMES.items() if bits & bit)
        _REASONS_CACHE[bits] = found
    return found
