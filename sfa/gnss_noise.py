"""Adaptive GNSS error model: the receiver's error statistics estimated from its own fixes.

The filter models a fix as ``z = p(s) + g + w``: the track point, a correlated error ``g`` (first-order
Gauss-Markov per axis, steady sigma ``sigma_g``, correlation time ``tau``) and a white error ``w``
(sigma ``sigma_w``). A receiver's datasheet gives none of the three reliably, and the reported sigma_h
is often wrong by a factor of two or more. Fixed values that are wrong cost both ways: a ``tau`` that is
too long makes the filter trust the correlated error state where it has already moved on, a sigma too
small narrows the interval below the truth.

The fixes carry the statistics themselves. The train is on the track, so the component of
``z - p(s)`` across the track, ``c = n . (z - p(s))`` (``n`` the track's unit normal), is the GNSS
error's cross-track component, whatever the estimate's error along the track. With the error isotropic
in the horizontal, ``c`` has the per-axis statistics:

    E[c(t) c(t - L)] = sigma_g^2 exp(-L / tau)  (L > 0),   E[c^2] = sigma_g^2 + sigma_w^2

(the map's own lateral error adds to both; it is counted as GNSS error, on the safe side).
The moments at lag 0 and at ``AD_LAGS_S`` (pairs at least MIN_PAIR_DISTANCE_M apart along the
track) are kept as weighted means with a memory of ``gps_adaptive_window_s`` seconds, starting from
the preset's model with a weight of ``gps_adaptive_prior_s`` seconds of data; each residual is
clipped at 3 sigma of the current lag-0 moment (a multipath jump widens the model, it does not blow
it up). Pairs both at one standstill (``gps_fit_standstill``) give instead the structure
function ``D(L) = E[(c(t) - c(t - L))^2] / 2 = sigma_w^2 + sigma_g^2 (1 - exp(-L / tau))``: at one place
the map's offset is the same in both residuals and cancels, so the short lags a slow train never spends
25 m in are observed at every stop. After each fix the model is refitted: ``tau`` by least squares
over a logarithmic grid,
``sigma_g^2`` in closed form for it, and ``sigma_w^2 = E[c^2] - sigma_g^2``; the correlated variance
the filter uses is that estimate plus one standard error (``variance_inflation``: a few hundred seconds
of a process correlated over tens of seconds hold only a few independent samples of it), within the floors
(FLOOR_GM, FLOOR_WHITE times the preset's: an interval too narrow is a safety defect) and the ceiling
(CEILING times the mean reported sigma_h). With several hypotheses alive, ``share`` gives them the
reported one's model and lets only that one learn.

With ``gps_adaptive_ml`` the model is instead the maximum-likelihood point of a bank of scalar Kalman
filters of the same residual over a (tau, white share) grid (``ml_update``; docs/filter.md, "Adaptive
GNSS error model"); on in the datasheet presets since session 35, off in a FilterConfig built by hand.

With ``gps_adaptive_window_s = 0`` the preset's model is used unchanged and these functions only
copy it into ``aux``. Slots: ``sfa.layout`` (A_GM_SIG .. A_AD_HIST, A_ML_T .. A_ML_B).
"""

from __future__ import annotations

import math

from sfa.engine import njit  # numba.njit, or the compiled engine (sfa.engine)
from sfa.layout import (
    A_AD_D,
    A_AD_DL,
    A_AD_DW,
    A_AD_FREEZE,
    A_AD_HI,
    A_AD_HIST,
    A_AD_HN,
    A_AD_L,
    A_AD_M,
    A_AD_SH,
    A_AD_T,
    A_AD_W,
    A_GM_SIG,
    A_GM_TAU,
    A_GW_SIG,
    A_ML_A,
    A_ML_B,
    A_ML_N,
    A_ML_P,
    A_ML_T,
    A_ML_X,
    A_STILL,
    A_WK_PHT,
    AD_ENTRY,
    AD_HIST,
    AD_HIST_SPACING_S,
    AD_LAGS_S,
    AD_ML_R,
    AD_ML_TAU_N,
    AD_NMOM,
    AD_TAU_MIN_S,
    K_AD_ML,
    K_AD_PRIOR,
    K_AD_STILL,
    K_AD_TAU_MAX,
    K_AD_WINDOW,
    K_GM_SIGMA,
    K_GM_TAU,
    K_GPS_NOMINAL_SIGMA_H,
    K_GPS_SCORE_T,
    K_GPS_WHITE,
)

LAG_TOL_S = 0.6  #: a history entry pairs with a lag L if its age is within L +- this [s]
MIN_NORMAL_DOT = 0.5  #: pairs whose track normals differ by more than 60 degrees are not used
#: pairs closer than this along the track are not used: the map's own lateral error is the same at
#: both, and at a standstill it would pass for a GNSS error that never decorrelates
MIN_PAIR_DISTANCE_M = 25.0
CLIP_SIGMA = 3.0  #: residuals are clipped at this many sigma of the current lag-0 moment
FLOOR_GM = 0.25  #: the correlated error's sigma does not go below this fraction of the preset's [-]
#: the white error's sigma does not go below this fraction of the preset's: without pairs closer than
#: the shortest lag it is an extrapolation (E[c^2] minus the fitted sigma_g^2), and a white error
#: estimated too small makes every fix of a 10 Hz receiver count as independent evidence
FLOOR_WHITE = 1.0
#: neither sigma goes above this multiple of the receiver's mean reported sigma_h: where the map's own
#: lateral error dominates the residual (RTK on a digitised map), the residual says little about GNSS
CEILING = 4.0
#: the correlation-time grid: TAU_N values, logarithmic from TAU_MIN_S to the configuration's
#: gps_adaptive_tau_max_s (K_AD_TAU_MAX)
TAU_MIN_S = AD_TAU_MIN_S
TAU_N = AD_ML_TAU_N
NR = len(AD_ML_R)  #: white shares of the maximum-likelihood grid


@njit(cache=True, inline="always", _nrt=False, error_model="numpy")
def _lag(i):
    """Nominal lag of moment i [s] (0: lag 0; then AD_LAGS_S)."""
    if i == 0:
        return 0.0
    return AD_LAGS_S[i - 1]


@njit(cache=True, inline="always", _nrt=False, error_model="numpy")
def grid_tau(cfg, g):
    """Correlation time g of the grid (0 .. TAU_N - 1) the moment fit and the bank search [s]:
    logarithmic from TAU_MIN_S to gps_adaptive_tau_max_s."""
    step = (math.log(cfg[K_AD_TAU_MAX]) - math.log(TAU_MIN_S)) / (TAU_N - 1)
    return math.exp(math.log(TAU_MIN_S) + g * step)


@njit(cache=True, _nrt=False, error_model="numpy")
def reset(aux, cfg):
    """The preset's model in use and as the statistics' prior (first initialisation)."""
    sg = cfg[K_GM_SIGMA]
    tau = cfg[K_GM_TAU]
    sw = cfg[K_GPS_WHITE]
    aux[A_GM_SIG] = sg
    aux[A_GM_TAU] = tau
    aux[A_GW_SIG] = sw
    aux[A_AD_SH] = cfg[K_GPS_NOMINAL_SIGMA_H]
    aux[A_AD_T] = math.nan
    for i in range(AD_NMOM):
        lag = _lag(i)
        m = sg * sg * math.exp(-lag / tau)  # prior E[c(t) c(t - L)] = sigma_g^2 exp(-L / tau)
        if i == 0:
            m += sw * sw  # + sigma_w^2 at lag 0
        aux[A_AD_M + i] = m
        aux[A_AD_L + i] = lag
        aux[A_AD_W + i] = cfg[K_AD_PRIOR]
        aux[A_AD_D + i] = 0.0
        aux[A_AD_DL + i] = lag
        aux[A_AD_DW + i] = 0.0  # no prior: only standstill pairs inform it
    if cfg[K_AD_ML] != 0.0:
        ml_reset(aux, cfg)
    restart(aux)


@njit(cache=True, _nrt=False, error_model="numpy")
def ml_reset(aux, cfg):
    """The maximum-likelihood bank's prior: gps_adaptive_prior_s seconds of the preset's receiver at
    1 Hz, each point's sums their expected values (_ml_expected), as the moments start from the
    preset's with that weight."""
    sg = cfg[K_GM_SIGMA]
    tau = cfg[K_GM_TAU]
    sw = cfg[K_GPS_WHITE]
    k_prior = cfg[K_AD_PRIOR]
    aux[A_ML_T] = math.nan
    aux[A_ML_N] = k_prior
    for g in range(TAU_N):
        tau_g = grid_tau(cfg, g)
        for k in range(NR):
            j = g * NR + k
            aux[A_ML_X + j] = 0.0
            aux[A_ML_P + j] = 1.0 - AD_ML_R[k]  # the correlated error's share of the unit total variance
            e_nu2, log_s = _ml_expected(sg * sg, tau, sw * sw, tau_g, AD_ML_R[k])
            aux[A_ML_A + j] = k_prior * e_nu2
            aux[A_ML_B + j] = k_prior * log_s


@njit(cache=True, _nrt=False, error_model="numpy")
def _ml_expected(q0, tau0, w0, tau, r):
    """The steady-state filter of grid point (tau, r) (unit scale) run on fixes 1 s apart from a
    receiver with correlated variance q0 [m^2], correlation time tau0 [s] and white variance w0 [m^2]:
    E[nu^2 / S] [m^2] and log S, in closed form. The filter's predicted variance P- is the positive
    root of its Riccati equation; E[nu^2] follows from the stationary covariance of (g, x), the
    receiver's error and the filter's prediction-corrected estimate of it."""
    phi = math.exp(-1.0 / tau)
    q = (1.0 - r) * (1.0 - phi * phi)  # the filter's process noise per step
    # P- = phi^2 P- r / (P- + r) + q:  P-^2 + b P- - q r = 0, b = r (1 - phi^2) - q
    b = r * (1.0 - phi * phi) - q
    root = math.sqrt(b * b + 4.0 * q * r)
    pm = 2.0 * q * r / (b + root) if b >= 0.0 else 0.5 * (root - b)
    sv = pm + r  # S = P- + R
    kg = pm / sv  # K = P- / S
    p0 = math.exp(-1.0 / tau0)
    a = (1.0 - kg) * phi  # x' = a x + K (p0 g + eta + w): the estimate's own recursion
    # stationary E[g x] and E[x^2] (E[g^2] = q0): the Lyapunov equation of (g, x), solved
    sgx = kg * q0 / (1.0 - p0 * a)
    sxx = (kg * kg * (q0 + w0) + 2.0 * kg * p0 * a * sgx) / (1.0 - a * a)
    # nu = z - phi x_prev = p0 g_prev + eta + w - phi x_prev, with E[(p0 g + eta)^2] = q0
    e_nu2 = q0 + w0 - 2.0 * p0 * phi * sgx + phi * phi * sxx
    return e_nu2 / sv, math.log(sv)


@njit(cache=True, _nrt=False, error_model="numpy")
def restart(aux):
    """Forget the residual history (a new receiver solution after an outage: no pairs across it)."""
    aux[A_AD_HN] = 0.0
    aux[A_AD_HI] = 0.0


@njit(cache=True, inline="always", _nrt=False, error_model="numpy")
def _accumulate(aux, base, i, value, lag, h, window):
    """Weighted mean with growing, then capped, memory: W = min(W + h, window), m += (h / W)(value - m).
    ``base``: the set of moments, A_AD_M (products) or A_AD_D (standstill structure function), each
    followed by its mean lags and its weights AD_NMOM slots apart."""
    w = min(aux[base + 2 * AD_NMOM + i] + h, window)
    a = h / w
    aux[base + i] += a * (value - aux[base + i])
    aux[base + AD_NMOM + i] += a * (lag - aux[base + AD_NMOM + i])
    aux[base + 2 * AD_NMOM + i] = w


@njit(cache=True, inline="always", _nrt=False, error_model="numpy")
def _store(aux, b, t, c, ne, nn, s):
    """One residual entry at aux[b:b + AD_ENTRY]."""
    aux[b] = t
    aux[b + 1] = c
    aux[b + 2] = ne
    aux[b + 3] = nn
    aux[b + 4] = s
    aux[b + 5] = aux[A_STILL]


@njit(cache=True, inline="always", _nrt=False, error_model="numpy")
def _pair(aux, i, c, ne, nn, s, b, t, h, window, still):
    """Moment i from this residual and the entry at aux[b]: c c' / (n . n'), if the two are far enough
    apart along the track and their normals close enough; with ``still`` (gps_fit_standstill, and the
    standstill detector on now) and the entry stored at a standstill within that distance, the structure
    function (c - c')^2 / 2 instead (no prior: its weight starts at 0)."""
    if still and aux[b + 5] != 0.0 and abs(s - aux[b + 4]) < MIN_PAIR_DISTANCE_M:
        # both at one standstill: the map's offset is the same at both and cancels in the difference
        _accumulate(aux, A_AD_D, i, 0.5 * (c - aux[b + 1]) ** 2, t - aux[b], h, window)
        return
    if abs(s - aux[b + 4]) < MIN_PAIR_DISTANCE_M:
        return
    dot = ne * aux[b + 2] + nn * aux[b + 3]
    if dot > MIN_NORMAL_DOT:
        _accumulate(aux, A_AD_M, i, c * aux[b + 1] / dot, t - aux[b], h, window)


@njit(cache=True, inline="always", _nrt=False, error_model="numpy")
def variance_inflation(tau, seconds):
    """1 + one standard error of a Gauss-Markov variance estimated from ``seconds`` of data [-]: the
    estimate's relative standard deviation is sqrt(2 tau / T) (Bartlett: var(s^2) = 2 sigma^4 tau / T
    for T >> tau), taken at no fewer than one correlation time of data (T >= tau).

    The fitted model is otherwise used as if it were the receiver's: with 300 s of a 20 s process the
    correlated variance is known to +-37 %, and where it was drawn low the interval was too narrow
    (urban GNSS 88 % on held-out worlds). The white variance is not inflated: the filter averages it
    down, so its error barely reaches the interval."""
    return 1.0 + math.sqrt(2.0 * tau / max(seconds, tau))


@njit(cache=True, inline="always", _nrt=False, error_model="numpy")
def seconds_of_data(aux):
    """Seconds of data behind the best-observed lag (the prior's counted as its seconds) [s]."""
    seconds = 0.0
    for i in range(1, AD_NMOM):
        seconds = max(seconds, aux[A_AD_W + i])
    return seconds


@njit(cache=True, _nrt=False, error_model="numpy")
def score_dof(aux, cfg):
    """Degrees of freedom of the model's correlated variance, for the Student-t a fix scores the line
    hypotheses with (sfa.bank.score) [-]; 0 (the normal) when the model does not adapt.

    A fix's NIS divides by the model's variance. Where that variance is estimated from T seconds of a
    process correlated over tau, the estimate is distributed as a chi-square with T / tau degrees of
    freedom (its relative variance is 2 tau / T, as in ``variance_inflation``: Bartlett), and the fix's
    predictive density, the normal marginalised over that scale, is a t with those degrees of freedom.
    A model declared known (``gps_adaptive_window_s = 0``: the preset is the receiver) has no such
    uncertainty; nor does a bank told to score fixes by the normal (``gps_score_student_t`` off)."""
    if cfg[K_AD_WINDOW] <= 0.0 or cfg[K_GPS_SCORE_T] == 0.0:
        return 0.0
    tau = aux[A_GM_TAU]
    seconds = seconds_of_data(aux)
    return max(seconds, tau) / tau


@njit(cache=True, _nrt=False, error_model="numpy")
def fit(aux, cfg):
    """sigma_g, tau, sigma_w from the moments: tau by least squares over the grid, each moment weighted
    by its seconds of data (a lag the train never spends 25 m in keeps its prior's small weight),
    sigma_g^2 in closed form for each tau, sigma_w^2 = E[c^2] - sigma_g^2; the correlated variance in
    use is sigma_g^2 times ``variance_inflation`` (its estimate plus one standard error, from the seconds
    of data of the best-observed lag); floors at FLOOR_GM and FLOOR_WHITE times the preset's sigmas,
    ceilings at CEILING times the mean reported sigma_h. With standstill moments (``_pair``) the
    least squares at each tau has two unknowns, sigma_g^2 and the white variance u, from both sets of
    moments, ``m_i = sigma_g^2 e_i`` and ``D_i = u + sigma_g^2 (1 - e_i)``, both >= 0 (otherwise u = 0
    and sigma_g^2 from both sets); u only shapes the fit: the white variance in use stays
    E[c^2] - sigma_g^2, the map's offset counted in it, on the safe side."""
    best = math.inf
    best_tau = cfg[K_GM_TAU]
    best_s2 = 0.0
    vsum = 0.0  # seconds of standstill data (gps_fit_standstill), the same at every tau
    for i in range(1, AD_NMOM):
        vsum += aux[A_AD_DW + i]
    for g in range(TAU_N):
        tau = grid_tau(cfg, g)
        num = 0.0
        den = 0.0
        for i in range(1, AD_NMOM):
            e = math.exp(-aux[A_AD_L + i] / tau)
            num += aux[A_AD_W + i] * aux[A_AD_M + i] * e
            den += aux[A_AD_W + i] * e * e
        s2 = max(num / den, 0.0) if den > 0.0 else 0.0  # argmin over s2 of sum w_i (m_i - s2 e_i)^2
        u = 0.0
        if vsum > 0.0:
            # with standstill pairs: m_i = s2 e_i and D_i = u + s2 (1 - e_i), u the white variance
            saa = den
            sau = 0.0
            suu = 0.0
            sam = num
            sum_ = 0.0
            for i in range(1, AD_NMOM):
                v = aux[A_AD_DW + i]
                f = 1.0 - math.exp(-aux[A_AD_DL + i] / tau)
                saa += v * f * f
                sau += v * f
                suu += v
                sam += v * f * aux[A_AD_D + i]
                sum_ += v * aux[A_AD_D + i]
            det = saa * suu - sau * sau
            s2j = (sam * suu - sum_ * sau) / det if det > 0.0 else -1.0
            uj = (saa * sum_ - sau * sam) / det if det > 0.0 else -1.0
            if s2j >= 0.0 and uj >= 0.0:
                s2, u = s2j, uj
            else:  # otherwise u = 0 and s2 from both sets (the correlated part is the one kept)
                s2, u = max(sam / saa, 0.0), 0.0
        err = 0.0
        for i in range(1, AD_NMOM):
            r = aux[A_AD_M + i] - s2 * math.exp(-aux[A_AD_L + i] / tau)
            err += aux[A_AD_W + i] * r * r
        if vsum > 0.0:
            for i in range(1, AD_NMOM):
                r = aux[A_AD_D + i] - u - s2 * (1.0 - math.exp(-aux[A_AD_DL + i] / tau))
                err += aux[A_AD_DW + i] * r * r
        if err < best:
            best = err
            best_tau = tau
            best_s2 = s2
    m0 = aux[A_AD_M]
    s2 = min(best_s2, m0)
    _use(aux, cfg, s2, best_tau, max(m0 - s2, 0.0))


@njit(cache=True, inline="always", _nrt=False, error_model="numpy")
def _use(aux, cfg, s2, tau, w2):
    """The model in use from an estimate: correlated variance s2 [m^2] with correlation time tau [s],
    white variance w2 [m^2]: the correlated one plus one standard error (variance_inflation), within the
    floors (FLOOR_GM, FLOOR_WHITE times the preset's) and the ceiling (CEILING times the mean sigma_h)."""
    top = CEILING * aux[A_AD_SH]
    sg = math.sqrt(s2 * variance_inflation(tau, seconds_of_data(aux)))
    aux[A_GM_SIG] = max(min(sg, top), FLOOR_GM * cfg[K_GM_SIGMA])
    aux[A_GM_TAU] = tau
    aux[A_GW_SIG] = max(min(math.sqrt(w2), top), FLOOR_WHITE * cfg[K_GPS_WHITE])


@njit(cache=True, _nrt=False, error_model="numpy")
def ml_update(aux, cfg, t, c, h, still):
    """One cross-track residual c [m] at time t [s], standing for h seconds of data, into the
    maximum-likelihood bank (``gps_adaptive_ml``), then the model in use from its best point.

    The residual is modelled as c = sigma (g + w): g first-order Gauss-Markov with variance 1 - r and
    correlation time tau, w white with variance r, sigma the scale. Each grid point (tau, r) runs the
    scalar Kalman filter of that model with sigma = 1 and keeps the forgetting sums (memory
    gps_adaptive_window_s) of nu^2 / S and log S over its innovations nu and their variances S, and the
    count N: the scale's maximum-likelihood estimate is then sigma^2 = sum(nu^2 / S) / N, and the
    log-likelihood profiled over it -(N log sigma^2 + sum log S) / 2. Unlike the moments' least squares,
    this weighs every lag the data hold by what it says, counts the residuals' correlation, and needs no
    pair 25 m apart: a slow train informs it as well as a fast one. A residual at a standstill (``still``)
    is left out: the map's lateral offset there is constant and would pass for a GNSS error that never
    decorrelates; the filters predict across the stop. The sums start from the preset's expected
    values over gps_adaptive_prior_s fixes (ml_reset), as the moments start from the preset's."""
    window = cfg[K_AD_WINDOW]
    if still:
        return
    dt = 1.0 if math.isnan(aux[A_ML_T]) else max(t - aux[A_ML_T], 0.0)
    aux[A_ML_T] = t
    lam = math.exp(-h / window)  # forgetting: a memory of gps_adaptive_window_s seconds of data
    aux[A_ML_N] = lam * aux[A_ML_N] + 1.0
    best = -math.inf
    best_j = -1
    n = aux[A_ML_N]
    for g in range(TAU_N):
        tau = grid_tau(cfg, g)
        phi = math.exp(-dt / tau)
        for k in range(NR):
            j = g * NR + k
            r = AD_ML_R[k]
            x = phi * aux[A_ML_X + j]  # x = phi x
            p = phi * phi * aux[A_ML_P + j] + (1.0 - r) * (1.0 - phi * phi)  # P = phi^2 P + q (1 - phi^2)
            sv = p + r  # S = P + R
            nu = c - x  # innovation
            aux[A_ML_A + j] = lam * aux[A_ML_A + j] + nu * nu / sv
            aux[A_ML_B + j] = lam * aux[A_ML_B + j] + math.log(sv)
            kg = p / sv  # K = P / S
            aux[A_ML_X + j] = x + kg * nu  # x += K nu
            aux[A_ML_P + j] = p * r / sv  # P = (1 - K) P
            ll = -(n * math.log(max(aux[A_ML_A + j] / n, 1e-300)) + aux[A_ML_B + j])  # 2 x profile log-lik.
            if ll > best:
                best = ll
                best_j = j
    if best_j < 0:
        return  # no point scored (not a number): the model in use stays
    g = best_j // NR
    r = AD_ML_R[best_j - g * NR]
    tau = grid_tau(cfg, g)
    var = aux[A_ML_A + best_j] / n  # the scale's estimate: sigma^2 = sum(nu^2 / S) / N
    _use(aux, cfg, (1.0 - r) * var, tau, r * var)


@njit(cache=True, _nrt=False, error_model="numpy")
def observe(aux, cfg, t, c, ne, nn, s, sigma_h):
    """One fix's cross-track residual c [m] at time t [s], the track normal (ne, nn) and arc length s
    [m] there, and the reported sigma_h [m] (NaN or <= 0: not reported) into the statistics, then
    refit. No-op when adaptation is off (K_AD_WINDOW <= 0) or frozen (A_AD_FREEZE: several hypotheses
    are alive; they are compared under the one model they inherited)."""
    window = cfg[K_AD_WINDOW]
    if window <= 0.0 or aux[A_AD_FREEZE] != 0.0 or not (math.isfinite(c) and math.isfinite(t)):
        return
    # seconds of data this residual stands for: the time since the previous one, at most 1 s
    h = 1.0 if math.isnan(aux[A_AD_T]) else min(max(t - aux[A_AD_T], 0.0), 1.0)
    if h <= 0.0:
        return
    aux[A_AD_T] = t
    lim = CLIP_SIGMA * math.sqrt(aux[A_AD_M])
    cc = min(max(c, -lim), lim)
    _accumulate(aux, A_AD_M, 0, cc * cc, 0.0, h, window)  # E[c^2]
    still = cfg[K_AD_STILL] != 0.0 and aux[A_STILL] != 0.0
    if math.isfinite(sigma_h) and sigma_h > 0.0:
        aux[A_AD_SH] += (h / aux[A_AD_W]) * (sigma_h - aux[A_AD_SH])  # mean reported sigma_h
    # E[c(t) c(t')] / (n . n'): the cross-track components of an isotropic error, normals apart
    n_hist = int(aux[A_AD_HN])
    for i in range(1, AD_NMOM):
        lag = _lag(i)
        j_best = -1
        d_best = LAG_TOL_S
        for j in range(n_hist):
            d = abs(t - aux[A_AD_HIST + AD_ENTRY * j] - lag)
            if d <= d_best:
                d_best = d
                j_best = j
        if j_best >= 0:
            _pair(aux, i, cc, ne, nn, s, A_AD_HIST + AD_ENTRY * j_best, t, h, window, still)
    # history: one entry per AD_HIST_SPACING_S (a ring)
    newest = int(aux[A_AD_HI]) - 1
    if newest < 0:
        newest = AD_HIST - 1
    if n_hist == 0 or t - aux[A_AD_HIST + AD_ENTRY * newest] >= AD_HIST_SPACING_S:
        _store(aux, A_AD_HIST + AD_ENTRY * int(aux[A_AD_HI]), t, cc, ne, nn, s)
        aux[A_AD_HI] = float((int(aux[A_AD_HI]) + 1) % AD_HIST)
        aux[A_AD_HN] = float(min(n_hist + 1, AD_HIST))
    if cfg[K_AD_ML] != 0.0:
        ml_update(aux, cfg, t, cc, h, aux[A_STILL] != 0.0)
    else:
        fit(aux, cfg)


@njit(cache=True, _nrt=False, error_model="numpy")
def share(dst, src, learns):
    """Before a GNSS fix with several hypotheses alive: every one uses the reported hypothesis's
    model and statistics (``src``), and only that one (``learns``) learns from the fix. The model is
    the receiver's, not a branch's: a branch on a wrong track 3 m from the right one would otherwise
    widen its own model until its fixes fit, and win the comparison the one model must decide."""
    if not learns:
        for i in range(A_GM_SIG, A_WK_PHT):
            dst[i] = src[i]
    dst[A_AD_FREEZE] = 0.0 if learns else 1.0


@njit(cache=True, inline="always", _nrt=False, error_model="numpy")
def white_sigma(aux, sigma_h):
    """The white error per axis for a fix reporting sigma_h: the model's, scaled up when the receiver
    reports a worse sigma_h than its usual (the preset's nominal, or the running mean when adaptive)."""
    sw = aux[A_GW_SIG]
    ref = aux[A_AD_SH]
    if math.isfinite(sigma_h) and sigma_h > 0.0 and sigma_h > ref:
        sw *= sigma_h / ref
    return sw
