/*
 * C reference of the SFA filter step: the same state, the same equations, the same branch structure
 * as sfa/kernels.py (prediction with the held IMU force into a pending covariance block, gyro window
 * update, odometer update with slip detection / rewind / ZUPT, GNSS update with late-fix
 * back-propagation, step/ramp detection and re-acquisition, covariance conditioning, status) and the
 * loop of sfa.batch.run_packed.
 *
 * It exists to measure the physical limit of the filter step on this machine ("how fast could the
 * same arithmetic go in plain C -O2"), so sfa bench can report SFA's compiled core as a ratio to it.
 * The slot indices come from sfa_layout.h, generated from sfa/layout.py at build time
 * (benchmarks/c/cref.py), so the two cannot drift. Every function follows the Python kernel of the
 * same name line by line (same operations, same order, same association, the same aux scratch slots
 * for P h' and the gain), so the results are bit-identical to numba's: both are IEEE double without
 * fast-math or FMA contraction (-std=c99 implies -ffp-contract=off) and call the same libm. The
 * equations are documented in sfa/kernels.py and docs/filter.md.
 */
#include <math.h>
#include <string.h>
#include "sfa_layout.h"

enum { O_ACCEPTED = 0, O_GATED = 1, O_LATE = 2, O_INVALID = 3, O_NOT_INIT = 4, O_NO_FIX = 5,
       O_INITIALISED = 6, O_HELD_OFF = 7 };

#define PIJ(P, i, j) ((P)[(i) * NX + (j)])
#define BIG 1e100

static double sq(double a) { return a * a; } /* numba's x ** 2 */

/* ------------------------------------------------------------------ track geometry */
static long seg_index(const double *ts, long n, double s) {
    /* np.searchsorted(ts, s, side="right") - 1, clamped to [0, n - 2]; NaN sorts last, as in numpy */
    if (isnan(s)) return n - 2;
    long lo = 0, hi = n;
    while (lo < hi) {
        long mid = (lo + hi) >> 1;
        if (ts[mid] <= s) lo = mid + 1; else hi = mid;
    }
    long i = lo - 1;
    if (i < 0) i = 0;
    if (i > n - 2) i = n - 2;
    return i;
}

static long seg_hint(const double *ts, long n, double s, double *aux) {
    if (s >= ts[n - 1]) return n - 2;
    long i = (long)aux[A_SEG];
    if (0 <= i && i <= n - 2 && ts[i] <= s) {
        if (s < ts[i + 1]) return i;
        if (i + 1 <= n - 2 && s < ts[i + 2]) {
            aux[A_SEG] = (double)(i + 1);
            return i + 1;
        }
    }
    i = seg_index(ts, n, s);
    aux[A_SEG] = (double)i;
    return i;
}

static void geom_at(const double *ts, const double *te, const double *tn, long n, double s,
                    double *e, double *no, double *de, double *dn) {
    long i = seg_index(ts, n, s);
    double ds = ts[i + 1] - ts[i];
    if (ds <= 0.0) ds = 1e-9;
    *de = (te[i + 1] - te[i]) / ds;
    *dn = (tn[i + 1] - tn[i]) / ds;
    double u = s - ts[i];
    *e = te[i] + *de * u;
    *no = tn[i] + *dn * u;
}

/* kernels.cross_track: signed distance from the line, the normal there and the foot's arc length */
static double cross_track(const double *ts, const double *te, const double *tn, long n, double s,
                          double east, double north, double *ne, double *nn, double *s_foot) {
    double e, no, de, dn, g;
    for (int k = 0; k < 3; k++) {
        geom_at(ts, te, tn, n, s, &e, &no, &de, &dn);
        g = sqrt(de * de + dn * dn);
        s += ((east - e) * de + (north - no) * dn) / (g * g);
    }
    geom_at(ts, te, tn, n, s, &e, &no, &de, &dn);
    g = sqrt(de * de + dn * dn);
    *ne = -dn / g;
    *nn = de / g;
    *s_foot = s;
    return (east - e) * *ne + (north - no) * *nn;
}

/* ---- sfa.gnss_noise: the adaptive GNSS error model */
/* Python's min/max: the first argument unless the second is strictly smaller/larger */
static double gn_min(double a, double b) { return b < a ? b : a; }
static double gn_max(double a, double b) { return b > a ? b : a; }

/* kernels.gps_evidence_weight: the share of an independent fix's evidence a fix at t carries, t_prev
   the previous fix in use: min(1, (t - t_prev) / cusum_min_interval_s); 1 with the interval 0 or no
   previous fix */
static double gps_evidence_weight(double t, double t_prev, const double *cfg) {
    if (cfg[K_CUSUM_DT] <= 0.0 || !isfinite(t_prev)) return 1.0;
    return gn_min(1.0, gn_max(t - t_prev, 0.0) / cfg[K_CUSUM_DT]);
}

static double gn_lag(int i) { return i == 0 ? 0.0 : AD_LAGS_S[i - 1]; }

/* gnss_noise.grid_tau: correlation time g of the logarithmic grid */
static double gn_grid_tau(const double *cfg, int g) {
    double step = (log(cfg[K_AD_TAU_MAX]) - log(GN_TAU_MIN_S)) / (GN_TAU_N - 1);
    return exp(log(GN_TAU_MIN_S) + g * step);
}

static void gn_restart(double *aux) {
    aux[A_AD_HN] = 0.0;
    aux[A_AD_HI] = 0.0;
}

/* gnss_noise._ml_expected: E[nu^2 / S] and log S of grid point (tau, r) on the preset's receiver */
static void gn_ml_expected(double q0, double tau0, double w0, double tau, double r, double *e_out,
                           double *log_s) {
    double phi = exp(-1.0 / tau);
    double q = (1.0 - r) * (1.0 - phi * phi);
    double b = r * (1.0 - phi * phi) - q;
    double root = sqrt(b * b + 4.0 * q * r);
    double pm = b >= 0.0 ? 2.0 * q * r / (b + root) : 0.5 * (root - b);
    double sv = pm + r;
    double kg = pm / sv;
    double p0 = exp(-1.0 / tau0);
    double a = (1.0 - kg) * phi;
    double sgx = kg * q0 / (1.0 - p0 * a);
    double sxx = (kg * kg * (q0 + w0) + 2.0 * kg * p0 * a * sgx) / (1.0 - a * a);
    double e_nu2 = q0 + w0 - 2.0 * p0 * phi * sgx + phi * phi * sxx;
    *e_out = e_nu2 / sv;
    *log_s = log(sv);
}

static void gn_ml_reset(double *aux, const double *cfg);

static void gn_reset(double *aux, const double *cfg) {
    double sg = cfg[K_GM_SIGMA], tau = cfg[K_GM_TAU], sw = cfg[K_GPS_WHITE];
    aux[A_GM_SIG] = sg;
    aux[A_GM_TAU] = tau;
    aux[A_GW_SIG] = sw;
    aux[A_AD_SH] = cfg[K_GPS_NOMINAL_SIGMA_H];
    aux[A_AD_T] = NAN;
    for (int i = 0; i < AD_NMOM; i++) {
        double lag = gn_lag(i);
        double m = sg * sg * exp(-lag / tau);
        if (i == 0) m += sw * sw;
        aux[A_AD_M + i] = m;
        aux[A_AD_L + i] = lag;
        aux[A_AD_W + i] = cfg[K_AD_PRIOR];
        aux[A_AD_D + i] = 0.0;
        aux[A_AD_DL + i] = lag;
        aux[A_AD_DW + i] = 0.0;
    }
    if (cfg[K_AD_ML] != 0.0) gn_ml_reset(aux, cfg);
    gn_restart(aux);
}

/* gnss_noise.ml_reset: the bank starts from K seconds of the preset's receiver at 1 Hz */
static void gn_ml_reset(double *aux, const double *cfg) {
    double sg = cfg[K_GM_SIGMA], tau = cfg[K_GM_TAU], sw = cfg[K_GPS_WHITE];
    double k_prior = cfg[K_AD_PRIOR];
    aux[A_ML_T] = NAN;
    aux[A_ML_N] = k_prior;
    for (int g = 0; g < GN_TAU_N; g++) {
        double tau_g = gn_grid_tau(cfg, g);
        for (int k = 0; k < GN_NR; k++) {
            long j = (long)g * GN_NR + k;
            double e_nu2, log_s;
            aux[A_ML_X + j] = 0.0;
            aux[A_ML_P + j] = 1.0 - AD_ML_R[k];
            gn_ml_expected(sg * sg, tau, sw * sw, tau_g, AD_ML_R[k], &e_nu2, &log_s);
            aux[A_ML_A + j] = k_prior * e_nu2;
            aux[A_ML_B + j] = k_prior * log_s;
        }
    }
}

/* base: A_AD_M (products) or A_AD_D (standstill structure function), lags and weights AD_NMOM apart */
static void gn_accumulate(double *aux, long base, int i, double value, double lag, double h, double window) {
    double w = gn_min(aux[base + 2 * AD_NMOM + i] + h, window);
    double a = h / w;
    aux[base + i] += a * (value - aux[base + i]);
    aux[base + AD_NMOM + i] += a * (lag - aux[base + AD_NMOM + i]);
    aux[base + 2 * AD_NMOM + i] = w;
}

/* gnss_noise._use: the model in use from an estimate, plus one standard error, within floors and ceiling */
static void gn_use(double *aux, const double *cfg, double s2, double tau, double w2) {
    double top = GN_CEILING * aux[A_AD_SH];
    double seconds = 0.0; /* gnss_noise.seconds_of_data: the best-observed lag's */
    for (int i = 1; i < AD_NMOM; i++) seconds = gn_max(seconds, aux[A_AD_W + i]);
    double infl = 1.0 + sqrt(2.0 * tau / gn_max(seconds, tau));
    aux[A_GM_SIG] = gn_max(gn_min(sqrt(s2 * infl), top), GN_FLOOR_GM * cfg[K_GM_SIGMA]);
    aux[A_GM_TAU] = tau;
    aux[A_GW_SIG] = gn_max(gn_min(sqrt(w2), top), GN_FLOOR_WHITE * cfg[K_GPS_WHITE]);
}

static void gn_fit(double *aux, const double *cfg) {
    double best = INFINITY, best_tau = cfg[K_GM_TAU], best_s2 = 0.0;
    double vsum = 0.0; /* seconds of standstill data, the same at every tau */
    for (int i = 1; i < AD_NMOM; i++) vsum += aux[A_AD_DW + i];
    for (int g = 0; g < GN_TAU_N; g++) {
        double tau = gn_grid_tau(cfg, g);
        double num = 0.0, den = 0.0;
        for (int i = 1; i < AD_NMOM; i++) {
            double e = exp(-aux[A_AD_L + i] / tau);
            num += aux[A_AD_W + i] * aux[A_AD_M + i] * e;
            den += aux[A_AD_W + i] * e * e;
        }
        double s2 = den > 0.0 ? gn_max(num / den, 0.0) : 0.0;
        /* gnss_noise.fit: with standstill pairs, m_i = s2 e_i and D_i = u + s2 (1 - e_i) together */
        double u = 0.0;
        if (vsum > 0.0) {
            double saa = den, sau = 0.0, suu = 0.0, sam = num, sum_ = 0.0;
            for (int i = 1; i < AD_NMOM; i++) {
                double v = aux[A_AD_DW + i];
                double f = 1.0 - exp(-aux[A_AD_DL + i] / tau);
                saa += v * f * f;
                sau += v * f;
                suu += v;
                sam += v * f * aux[A_AD_D + i];
                sum_ += v * aux[A_AD_D + i];
            }
            double det = saa * suu - sau * sau;
            double s2j = det > 0.0 ? (sam * suu - sum_ * sau) / det : -1.0;
            double uj = det > 0.0 ? (saa * sum_ - sau * sam) / det : -1.0;
            if (s2j >= 0.0 && uj >= 0.0) {
                s2 = s2j;
                u = uj;
            } else { /* otherwise u = 0 and s2 from both sets */
                s2 = gn_max(sam / saa, 0.0);
                u = 0.0;
            }
        }
        double err = 0.0;
        for (int i = 1; i < AD_NMOM; i++) {
            double r = aux[A_AD_M + i] - s2 * exp(-aux[A_AD_L + i] / tau);
            err += aux[A_AD_W + i] * r * r;
        }
        if (vsum > 0.0) {
            for (int i = 1; i < AD_NMOM; i++) {
                double r = aux[A_AD_D + i] - u - s2 * (1.0 - exp(-aux[A_AD_DL + i] / tau));
                err += aux[A_AD_DW + i] * r * r;
            }
        }
        if (err < best) {
            best = err;
            best_tau = tau;
            best_s2 = s2;
        }
    }
    double m0 = aux[A_AD_M];
    double s2 = gn_min(best_s2, m0);
    gn_use(aux, cfg, s2, best_tau, gn_max(m0 - s2, 0.0));
}

/* gnss_noise.ml_update: the maximum-likelihood bank (gps_adaptive_ml) */
static void gn_ml_update(double *aux, const double *cfg, double t, double c, double h, int still) {
    double window = cfg[K_AD_WINDOW];
    if (still) return;
    double dt = isnan(aux[A_ML_T]) ? 1.0 : gn_max(t - aux[A_ML_T], 0.0);
    aux[A_ML_T] = t;
    double lam = exp(-h / window);
    aux[A_ML_N] = lam * aux[A_ML_N] + 1.0;
    double best = -INFINITY, n = aux[A_ML_N];
    long best_j = -1;
    for (int g = 0; g < GN_TAU_N; g++) {
        double tau = gn_grid_tau(cfg, g);
        double phi = exp(-dt / tau);
        for (int k = 0; k < GN_NR; k++) {
            long j = (long)g * GN_NR + k;
            double r = AD_ML_R[k];
            double x = phi * aux[A_ML_X + j];
            double p = phi * phi * aux[A_ML_P + j] + (1.0 - r) * (1.0 - phi * phi);
            double sv = p + r;
            double nu = c - x;
            aux[A_ML_A + j] = lam * aux[A_ML_A + j] + nu * nu / sv;
            aux[A_ML_B + j] = lam * aux[A_ML_B + j] + log(sv);
            double kg = p / sv;
            aux[A_ML_X + j] = x + kg * nu;
            aux[A_ML_P + j] = p * r / sv;
            double ll = -(n * log(gn_max(aux[A_ML_A + j] / n, 1e-300)) + aux[A_ML_B + j]);
            if (ll > best) {
                best = ll;
                best_j = j;
            }
        }
    }
    if (best_j < 0) return;
    long g = best_j / GN_NR;
    double r = AD_ML_R[best_j - g * GN_NR];
    double tau = gn_grid_tau(cfg, (int)g);
    double var = aux[A_ML_A + best_j] / n;
    gn_use(aux, cfg, (1.0 - r) * var, tau, r * var);
}

static void gn_store(double *aux, long b, double t, double c, double ne, double nn, double s) {
    aux[b] = t;
    aux[b + 1] = c;
    aux[b + 2] = ne;
    aux[b + 3] = nn;
    aux[b + 4] = s;
    aux[b + 5] = aux[A_STILL];
}

static void gn_pair(double *aux, int i, double c, double ne, double nn, double s, long b, double t, double h,
                    double window, int still) {
    if (still && aux[b + 5] != 0.0 && fabs(s - aux[b + 4]) < GN_MIN_PAIR_DISTANCE_M) {
        /* both at one standstill: the structure function, the map's offset cancelling */
        double dc = c - aux[b + 1];
        gn_accumulate(aux, A_AD_D, i, 0.5 * (dc * dc), t - aux[b], h, window);
        return;
    }
    if (fabs(s - aux[b + 4]) < GN_MIN_PAIR_DISTANCE_M) return;
    double dot = ne * aux[b + 2] + nn * aux[b + 3];
    if (dot > GN_MIN_NORMAL_DOT) gn_accumulate(aux, A_AD_M, i, c * aux[b + 1] / dot, t - aux[b], h, window);
}

static void gn_observe(double *aux, const double *cfg, double t, double c, double ne, double nn, double s,
                       double sigma_h) {
    double window = cfg[K_AD_WINDOW];
    if (window <= 0.0 || aux[A_AD_FREEZE] != 0.0 || !(isfinite(c) && isfinite(t))) return;
    double h = isnan(aux[A_AD_T]) ? 1.0 : gn_min(gn_max(t - aux[A_AD_T], 0.0), 1.0);
    if (h <= 0.0) return;
    aux[A_AD_T] = t;
    double lim = GN_CLIP_SIGMA * sqrt(aux[A_AD_M]);
    double cc = gn_min(gn_max(c, -lim), lim);
    gn_accumulate(aux, A_AD_M, 0, cc * cc, 0.0, h, window);
    int still = cfg[K_AD_STILL] != 0.0 && aux[A_STILL] != 0.0;
    if (isfinite(sigma_h) && sigma_h > 0.0) aux[A_AD_SH] += (h / aux[A_AD_W]) * (sigma_h - aux[A_AD_SH]);
    long n_hist = (long)aux[A_AD_HN];
    for (int i = 1; i < AD_NMOM; i++) {
        double lag = gn_lag(i);
        long j_best = -1;
        double d_best = GN_LAG_TOL_S;
        for (long j = 0; j < n_hist; j++) {
            double d = fabs(t - aux[A_AD_HIST + AD_ENTRY * j] - lag);
            if (d <= d_best) {
                d_best = d;
                j_best = j;
            }
        }
        if (j_best >= 0) gn_pair(aux, i, cc, ne, nn, s, A_AD_HIST + AD_ENTRY * j_best, t, h, window, still);
    }
    long newest = (long)aux[A_AD_HI] - 1;
    if (newest < 0) newest = AD_HIST - 1;
    if (n_hist == 0 || t - aux[A_AD_HIST + AD_ENTRY * newest] >= AD_HIST_SPACING_S) {
        gn_store(aux, A_AD_HIST + AD_ENTRY * (long)aux[A_AD_HI], t, cc, ne, nn, s);
        aux[A_AD_HI] = (double)(((long)aux[A_AD_HI] + 1) % AD_HIST);
        aux[A_AD_HN] = (double)(n_hist + 1 < AD_HIST ? n_hist + 1 : AD_HIST);
    }
    if (cfg[K_AD_ML] != 0.0)
        gn_ml_update(aux, cfg, t, cc, h, aux[A_STILL] != 0.0);
    else
        gn_fit(aux, cfg);
}

static double gn_white_sigma(const double *aux, double sigma_h) {
    double sw = aux[A_GW_SIG], ref = aux[A_AD_SH];
    if (isfinite(sigma_h) && sigma_h > 0.0 && sigma_h > ref) sw *= sigma_h / ref;
    return sw;
}

static double interp_seg(const double *ts, const double *arr, long n, double s, long i) {
    if (s <= ts[0]) return arr[0];
    if (s >= ts[n - 1]) return arr[n - 1];
    double ds = ts[i + 1] - ts[i];
    if (ds <= 0.0) return arr[i];
    return arr[i] + (arr[i + 1] - arr[i]) * (s - ts[i]) / ds;
}

static double interp_at(const double *ts, const double *arr, long n, double s) {
    return interp_seg(ts, arr, n, s, seg_index(ts, n, s));
}

static double interp_slope_at(const double *ts, const double *arr, long n, double s, long i, double *slope) {
    *slope = 0.0;
    if (s <= ts[0]) return arr[0];
    if (s >= ts[n - 1]) return arr[n - 1];
    double ds = ts[i + 1] - ts[i];
    if (ds <= 0.0) return arr[i];
    *slope = (arr[i + 1] - arr[i]) / ds;
    return arr[i] + (arr[i + 1] - arr[i]) * (s - ts[i]) / ds;
}

/* ------------------------------------------------------------------ covariance hygiene */
static int cholesky_ok(double *P) {
    /* in place as the Python: the factor's strict lower triangle in P's, restored from the upper */
    int ok = 1;
    for (int j = 0; j < NX; j++) {
        double d = PIJ(P, j, j);
        for (int k = 0; k < j; k++) d -= PIJ(P, j, k) * PIJ(P, j, k);
        if (!(d > 0.0) || !isfinite(d)) {
            ok = 0;
            break;
        }
        double ljj = sqrt(d);
        for (int i = j + 1; i < NX; i++) {
            double v = PIJ(P, j, i);
            for (int k = 0; k < j; k++) v -= PIJ(P, i, k) * PIJ(P, j, k);
            PIJ(P, i, j) = v / ljj;
        }
    }
    for (int i = 0; i < NX; i++)
        for (int j = 0; j < i; j++) PIJ(P, i, j) = PIJ(P, j, i);
    return ok;
}

static int symmetrise_floor(double *P, const double *cfg) {
    double pmin = cfg[K_P_MIN_VAR];
    int repaired = 0;
    for (int i = 0; i < NX; i++) {
        for (int j = i + 1; j < NX; j++) {
            double m = 0.5 * (PIJ(P, i, j) + PIJ(P, j, i));
            PIJ(P, i, j) = m;
            PIJ(P, j, i) = m;
        }
        if (!(PIJ(P, i, i) >= pmin)) {
            PIJ(P, i, i) = pmin;
            repaired = 1;
        }
    }
    return repaired;
}

static int floor_diag(double *P, const double *cfg) {
    double pmin = cfg[K_P_MIN_VAR];
    int repaired = 0;
    for (int i = 0; i < NX; i++) {
        if (!(PIJ(P, i, i) >= pmin)) {
            PIJ(P, i, i) = pmin;
            repaired = 1;
        }
    }
    return repaired;
}

static void condition_cov(double *P, const double *cfg, long *cnt) {
    int repaired = symmetrise_floor(P, cfg);
    if (!cholesky_ok(P)) {
        for (int i = 0; i < NX; i++)
            for (int j = 0; j < NX; j++)
                if (i != j) PIJ(P, i, j) = 0.0;
        repaired = 1;
    }
    if (repaired) cnt[C_COV_REPAIR] += 1;
}

/* ------------------------------------------------------------------ prediction (lazy covariance) */
static void predict_step(double *x, double *aux, const double *cfg, const double *ts, const double *tg,
                         long nv, double h, int imu_ok) {
    double g = cfg[K_GRAVITY];
    double grade = interp_seg(ts, tg, nv, x[S], seg_hint(ts, nv, x[S], aux));
    double sin_th = grade / sqrt(1.0 + grade * grade);
    double d = aux[A_DIR], fx = aux[A_FX], fy = aux[A_FY];
    double a, q, fsb, fvb;
    if (imu_ok) {
        a = d * (fx - x[BA] - x[MY] * fy - x[SF] * fx) - g * sin_th;
        q = cfg[K_Q_ACC];
        fsb = -0.5 * d * h * h;
        fvb = -d * h;
    } else {
        a = 0.0;
        q = cfg[K_Q_NO_IMU];
        fsb = 0.0;
        fvb = 0.0;
    }
    x[S] += x[V] * h + 0.5 * a * h * h;
    x[V] += a * h;
    /* F_B <- F_h F_B (row S first: it reads row V before) */
    aux[A_PB_SB] += h * aux[A_PB_VB] + fsb;
    aux[A_PB_VB] += fvb;
    aux[A_PB_SM] += h * aux[A_PB_VM] + fsb * fy;
    aux[A_PB_VM] += fvb * fy;
    aux[A_PB_SF] += h * aux[A_PB_VF] + fsb * fx;
    aux[A_PB_VF] += fvb * fx;
    aux[A_PB_H] += h;
    /* Q_B <- F_h Q_B F_h' + Q_h on the (s, v, b_a) block */
    double qss = aux[A_QB_SS], qsv = aux[A_QB_SV], qsb = aux[A_QB_SB];
    double qvv = aux[A_QB_VV], qvb = aux[A_QB_VB], qbb = aux[A_QB_BB];
    double rs_s = qss + h * qsv + fsb * qsb;
    double rs_v = qsv + h * qvv + fsb * qvb;
    double rs_b = qsb + h * qvb + fsb * qbb;
    double rv_v = qvv + fvb * qvb;
    double rv_b = qvb + fvb * qbb;
    aux[A_QB_SS] = rs_s + h * rs_v + fsb * rs_b + q * h * h * h / 3.0 + cfg[K_Q_REG] * fabs(x[V]) * h;
    aux[A_QB_SV] = rs_v + fvb * rs_b + q * h * h / 2.0;
    aux[A_QB_SB] = rs_b;
    aux[A_QB_VV] = rv_v + fvb * rv_b + q * h;
    aux[A_QB_VB] = rv_b;
    aux[A_QB_BB] = qbb + cfg[K_Q_BA] * h;
}

static void block_clear(double *aux) {
    for (int k = A_PB_H; k <= A_QB_BB; k++) aux[k] = 0.0;
}

static void sync_block(double *x, double *P, double *aux, const double *cfg, long *cnt) {
    double hb = aux[A_PB_H];
    if (hb == 0.0) return;
    double phi = exp(-hb / aux[A_GM_TAU]);
    x[GE] *= phi;
    x[GN] *= phi;
    double fsb = aux[A_PB_SB], fvb = aux[A_PB_VB];
    double fsm = aux[A_PB_SM], fvm = aux[A_PB_VM];
    double fss = aux[A_PB_SF], fvs = aux[A_PB_VF];
    for (int j = 0; j < NX; j++) {
        double ps = PIJ(P, S, j), pv = PIJ(P, V, j);
        PIJ(P, S, j) = ps + hb * pv + fsb * PIJ(P, BA, j) + fsm * PIJ(P, MY, j) + fss * PIJ(P, SF, j);
        PIJ(P, V, j) = pv + fvb * PIJ(P, BA, j) + fvm * PIJ(P, MY, j) + fvs * PIJ(P, SF, j);
        PIJ(P, GE, j) *= phi;
        PIJ(P, GN, j) *= phi;
    }
    for (int i = 0; i < NX; i++) {
        double as = PIJ(P, i, S), av = PIJ(P, i, V);
        PIJ(P, i, S) = as + hb * av + fsb * PIJ(P, i, BA) + fsm * PIJ(P, i, MY) + fss * PIJ(P, i, SF);
        PIJ(P, i, V) = av + fvb * PIJ(P, i, BA) + fvm * PIJ(P, i, MY) + fvs * PIJ(P, i, SF);
        PIJ(P, i, GE) *= phi;
        PIJ(P, i, GN) *= phi;
    }
    PIJ(P, S, S) += aux[A_QB_SS];
    PIJ(P, S, V) += aux[A_QB_SV];
    PIJ(P, V, S) += aux[A_QB_SV];
    PIJ(P, S, BA) += aux[A_QB_SB];
    PIJ(P, BA, S) += aux[A_QB_SB];
    PIJ(P, V, V) += aux[A_QB_VV];
    PIJ(P, V, BA) += aux[A_QB_VB];
    PIJ(P, BA, V) += aux[A_QB_VB];
    PIJ(P, BA, BA) += aux[A_QB_BB];
    PIJ(P, KO, KO) += cfg[K_Q_KO] * hb;
    double gm = aux[A_GM_SIG];
    PIJ(P, GE, GE) += gm * gm * (1.0 - phi * phi);
    PIJ(P, GN, GN) += gm * gm * (1.0 - phi * phi);
    PIJ(P, BG, BG) += cfg[K_Q_BG] * hb;
    PIJ(P, SG, SG) += cfg[K_Q_SG] * hb;
    block_clear(aux);
    /* (P + P')/2 on the pairs the two passes round differently: within (S, V, GE, GN) (sfa.kernels.
       _symmetrise_moved_floor), then the diagonal floor */
    static const int moved[4] = {S, V, GE, GN};
    for (int a = 0; a < 4; a++)
        for (int b = a + 1; b < 4; b++) {
            double m = 0.5 * (PIJ(P, moved[a], moved[b]) + PIJ(P, moved[b], moved[a]));
            PIJ(P, moved[a], moved[b]) = m;
            PIJ(P, moved[b], moved[a]) = m;
        }
    if (floor_diag(P, cfg)) cnt[C_COV_REPAIR] += 1;
}

/* (F_B P F_B' + Q_B)[S, S] without changing anything (sfa.kernels.pending_var_s) */
static double pending_var_s(const double *P, const double *aux) {
    double hb = aux[A_PB_H];
    if (hb == 0.0) return PIJ(P, S, S);
    double sb = aux[A_PB_SB], sm_ = aux[A_PB_SM], sf = aux[A_PB_SF];
    double ps = PIJ(P, S, S) + hb * PIJ(P, V, S) + sb * PIJ(P, BA, S) + sm_ * PIJ(P, MY, S) + sf * PIJ(P, SF, S);
    double pv = PIJ(P, S, V) + hb * PIJ(P, V, V) + sb * PIJ(P, BA, V) + sm_ * PIJ(P, MY, V) + sf * PIJ(P, SF, V);
    double pb = PIJ(P, S, BA) + hb * PIJ(P, V, BA) + sb * PIJ(P, BA, BA) + sm_ * PIJ(P, MY, BA)
                + sf * PIJ(P, SF, BA);
    double pm = PIJ(P, S, MY) + hb * PIJ(P, V, MY) + sb * PIJ(P, BA, MY) + sm_ * PIJ(P, MY, MY)
                + sf * PIJ(P, SF, MY);
    double pf = PIJ(P, S, SF) + hb * PIJ(P, V, SF) + sb * PIJ(P, BA, SF) + sm_ * PIJ(P, MY, SF)
                + sf * PIJ(P, SF, SF);
    return ps + hb * pv + sb * pb + sm_ * pm + sf * pf + aux[A_QB_SS];
}

static void predict_to(double *x, double *P, double *aux, long *cnt, const double *cfg, const double *ts,
                       const double *tg, long nv, double t) {
    double dt_total = t - aux[A_T_STATE];
    if (dt_total <= 0.0) return;
    int imu_ok = (t - aux[A_T_IMU]) <= cfg[K_IMU_TIMEOUT];
    if (dt_total <= cfg[K_MAX_DT]) { /* one step (every IMU sample) */
        predict_step(x, aux, cfg, ts, tg, nv, dt_total, imu_ok);
        aux[A_T_STATE] = t;
        return;
    }
    long n = (long)ceil(dt_total / cfg[K_MAX_DT]);
    if (n < 1) n = 1;
    if (n > 10000) n = 10000; /* a long confirmed gap: keep the cost bounded */
    double h = dt_total / (double)n;
    for (long k = 0; k < n; k++) predict_step(x, aux, cfg, ts, tg, nv, h, imu_ok);
    aux[A_T_STATE] = t;
    if (n > 10) {
        sync_block(x, P, aux, cfg, cnt);
        condition_cov(P, cfg, cnt);
    }
}

/* ------------------------------------------------------------------ updates (as sfa/kernels.py) */
/* scalar measurement: h has nonzeros h0 .. h4 at i0 .. i4 (index < 0: unused); P h' into aux scratch */
static double innovation1(const double *P, double *aux, int i0, double h0, int i1, double h1, int i2,
                          double h2, int i3, double h3, int i4, double h4, double r, double y, double *nis) {
    for (int i = 0; i < NX; i++) {
        double v = 0.0;
        if (i0 >= 0) v += PIJ(P, i, i0) * h0;
        if (i1 >= 0) v += PIJ(P, i, i1) * h1;
        if (i2 >= 0) v += PIJ(P, i, i2) * h2;
        if (i3 >= 0) v += PIJ(P, i, i3) * h3;
        if (i4 >= 0) v += PIJ(P, i, i4) * h4;
        aux[A_WK_PHT + i] = v;
    }
    double sm = r;
    if (i0 >= 0) sm += h0 * aux[A_WK_PHT + i0];
    if (i1 >= 0) sm += h1 * aux[A_WK_PHT + i1];
    if (i2 >= 0) sm += h2 * aux[A_WK_PHT + i2];
    if (i3 >= 0) sm += h3 * aux[A_WK_PHT + i3];
    if (i4 >= 0) sm += h4 * aux[A_WK_PHT + i4];
    *nis = y * y / sm;
    return sm;
}

static void gyro_window_shift(double *aux, double d_s, double d_v, double d_bg, double d_sg, double d_mx) {
    if (aux[A_GY_N] > 0.0)
        aux[A_GY_Y] -= (aux[A_GY_HS] * d_s + aux[A_GY_HV] * d_v + aux[A_GY_N] * d_bg + aux[A_GY_HSG] * d_sg
                        + aux[A_GY_HMX] * d_mx);
}

static int apply_update1(double *x, double *P, double *aux, double sm, double y, const double *cfg, long *cnt) {
    if (!(isfinite(sm) && 0.0 < sm && sm <= BIG)) return 0;
    for (int i = 0; i < NX; i++) {
        double p = aux[A_WK_PHT + i];
        double k = p / sm;
        aux[A_WK_K + i] = k;
        if (!(fabs(p) <= BIG && fabs(k) <= BIG && fabs(k * y) <= BIG)) return 0;
    }
    gyro_window_shift(aux, aux[A_WK_K + S] * y, aux[A_WK_K + V] * y, aux[A_WK_K + BG] * y,
                      aux[A_WK_K + SG] * y, aux[A_WK_K + MX] * y);
    for (int i = 0; i < NX; i++) {
        x[i] += aux[A_WK_K + i] * y;
        double ki = aux[A_WK_K + i], pi = aux[A_WK_PHT + i];
        for (int j = i; j < NX; j++) {
            double kj = aux[A_WK_K + j], pj = aux[A_WK_PHT + j];
            double v = PIJ(P, i, j) - (ki * pj + pi * kj) + sm * (ki * kj);
            PIJ(P, i, j) = v;
            PIJ(P, j, i) = v;
        }
    }
    if (floor_diag(P, cfg)) cnt[C_COV_REPAIR] += 1;
    return 1;
}

/* two rows (GNSS): H is 2 x NX row-major, R 2 x 2; P H' into aux scratch */
typedef struct {
    double s00, s01, s11, si00, si01, si11, nis;
} Innov2;

static void innovation2(const double *P, double *aux, const double *H, const double *R, const double *y,
                        Innov2 *o) {
    for (int i = 0; i < NX; i++) {
        double a = 0.0, b = 0.0;
        for (int k = 0; k < NX; k++) {
            a += PIJ(P, i, k) * H[k];
            b += PIJ(P, i, k) * H[NX + k];
        }
        aux[A_WK_PHT + i] = a;
        aux[A_WK_PHT + NX + i] = b;
    }
    double s00 = R[0], s01 = R[1], s11 = R[3];
    for (int k = 0; k < NX; k++) {
        s00 += H[k] * aux[A_WK_PHT + k];
        s01 += H[k] * aux[A_WK_PHT + NX + k];
        s11 += H[NX + k] * aux[A_WK_PHT + NX + k];
    }
    double det = s00 * s11 - s01 * s01;
    o->s00 = s00;
    o->s01 = s01;
    o->s11 = s11;
    o->si00 = s11 / det;
    o->si11 = s00 / det;
    o->si01 = -s01 / det;
    o->nis = y[0] * (o->si00 * y[0] + o->si01 * y[1]) + y[1] * (o->si01 * y[0] + o->si11 * y[1]);
}

static int apply_update2(double *x, double *P, double *aux, const double *y, const Innov2 *in,
                         const double *cfg, long *cnt) {
    for (int i = 0; i < NX; i++) {
        double p0 = aux[A_WK_PHT + i], p1 = aux[A_WK_PHT + NX + i];
        double k0 = p0 * in->si00 + p1 * in->si01;
        double k1 = p0 * in->si01 + p1 * in->si11;
        aux[A_WK_K + i] = k0;
        aux[A_WK_K + NX + i] = k1;
        if (!(isfinite(k0) && isfinite(k1) && isfinite(x[i] + k0 * y[0] + k1 * y[1]))) return 0;
    }
    for (int rep = 0; rep < 2; rep++)
        for (int i = 0; i < NX; i++) {
            double ki0 = aux[A_WK_K + i], ki1 = aux[A_WK_K + NX + i];
            double pi0 = aux[A_WK_PHT + i], pi1 = aux[A_WK_PHT + NX + i];
            double a0 = ki0 * in->s00 + ki1 * in->s01;
            double a1 = ki0 * in->s01 + ki1 * in->s11;
            for (int j = 0; j < NX; j++) {
                double kj0 = aux[A_WK_K + j], kj1 = aux[A_WK_K + NX + j];
                double pj0 = aux[A_WK_PHT + j], pj1 = aux[A_WK_PHT + NX + j];
                double v = PIJ(P, i, j) - (ki0 * pj0 + ki1 * pj1) - (pi0 * kj0 + pi1 * kj1) + (a0 * kj0 + a1 * kj1);
                if (rep == 0) {
                    if (!isfinite(v)) return 0;
                } else {
                    PIJ(P, i, j) = v;
                }
            }
        }
    gyro_window_shift(aux, aux[A_WK_K + S] * y[0] + aux[A_WK_K + NX + S] * y[1],
                      aux[A_WK_K + V] * y[0] + aux[A_WK_K + NX + V] * y[1],
                      aux[A_WK_K + BG] * y[0] + aux[A_WK_K + NX + BG] * y[1],
                      aux[A_WK_K + SG] * y[0] + aux[A_WK_K + NX + SG] * y[1],
                      aux[A_WK_K + MX] * y[0] + aux[A_WK_K + NX + MX] * y[1]);
    for (int i = 0; i < NX; i++) x[i] += aux[A_WK_K + i] * y[0] + aux[A_WK_K + NX + i] * y[1];
    condition_cov(P, cfg, cnt);
    return 1;
}

/* ------------------------------------------------------------------ timeouts and status */
static void check_timeouts(double *aux, long *cnt, const double *cfg, double t) {
    const int flags[3][4] = {{A_IMU_TO, A_T_IMU, K_IMU_TIMEOUT, C_IMU_TIMEOUT},
                             {A_ODO_TO, A_T_ODO, K_ODO_TIMEOUT, C_ODO_TIMEOUT},
                             {A_GPS_TO, A_T_GPS, K_GPS_TIMEOUT, C_GPS_TIMEOUT}};
    for (int k = 0; k < 3; k++) {
        int out = (t - aux[flags[k][1]]) > cfg[flags[k][2]];
        if (out && aux[flags[k][0]] == 0.0) cnt[flags[k][3]] += 1;
        aux[flags[k][0]] = out ? 1.0 : 0.0;
    }
}

static long status_of(const double *x, const double *P, const double *aux, const double *cfg, double t,
                      long *bits_out, double *sigma_out) {
    (void)x;
    if (aux[A_INIT] == 0.0) {
        *bits_out = R_NOT_INIT;
        *sigma_out = INFINITY;
        return 0;
    }
    long bits = 0;
    int imu_to = (t - aux[A_T_IMU]) > cfg[K_IMU_TIMEOUT];
    int odo_to = (t - aux[A_T_ODO]) > cfg[K_ODO_TIMEOUT];
    int gps_to = (t - aux[A_T_GPS]) > cfg[K_GPS_TIMEOUT];
    if (imu_to) bits |= R_IMU_TIMEOUT;
    if (odo_to) bits |= R_ODO_TIMEOUT;
    if (gps_to) bits |= R_GPS_TIMEOUT;
    if (imu_to && odo_to) bits |= R_NO_MOTION_SENSOR;
    if (aux[A_SLIP] != 0.0) bits |= R_SLIP;
    if (aux[A_GPS_REJ] > 0.0) {
        bits |= R_GNSS_REJECTING;
        if (aux[A_STEP_FLAG] != 0.0) bits |= R_GNSS_STEP;
    }
    if (t < aux[A_GPS_HOLD]) bits |= R_GNSS_RAMP;
    if (aux[A_STILL] != 0.0) bits |= R_STANDSTILL;
    if (cfg[K_IMU_STUCK_N] > 0.0 && aux[A_IMU_SAME] >= cfg[K_IMU_STUCK_N]) bits |= R_IMU_STUCK;
    if (t - aux[A_IMU_FAULT_T] <= cfg[K_IMU_FAULT_HOLD]) bits |= R_IMU_FAULT;
    double var = pending_var_s(P, aux);
    double sigma = var > 0.0 ? sqrt(var) : 0.0;
    if (aux[A_SLIP] != 0.0 && aux[A_SLIP_LLR] > -cfg[K_SLIP_ARB_LLR])
        sigma += fabs(aux[A_SLIP_DS]) / cfg[K_Z_INTERVAL];
    if (bits & FAULT_REASONS) sigma *= cfg[K_FAULT_SIGMA_SCALE];
    if (sigma > cfg[K_LOST_SIGMA]) bits |= R_SIGMA_LOST;
    else if (sigma > cfg[K_DEGRADED_SIGMA]) bits |= R_SIGMA_HIGH;
    *bits_out = bits;
    *sigma_out = sigma;
    if (bits & (R_SIGMA_LOST | R_NO_MOTION_SENSOR)) return 3;
    if (bits & ~(long)R_STANDSTILL) return 2;
    return 1;
}

/* ------------------------------------------------------------------ rewind memory */
static void mem_reset(double *mem) {
    memset(mem, 0, sizeof(double) * NMEM);
    mem[MEM_T_ROT] = -INFINITY;
}

static void mem_save(const double *x, const double *P, const double *aux, double *mem, long off) {
    memcpy(mem + off, x, sizeof(double) * NX);
    memcpy(mem + off + NX, P, sizeof(double) * NX * NX);
    long k = off + NX + NX * NX;
    mem[k] = aux[A_T_STATE];
    mem[k + 1] = aux[A_FX];
    mem[k + 2] = aux[A_FY];
    mem[k + 3] = 1.0;
}

static void mem_push_imu(double *mem, double t, double fx, double fy) {
    long n = (long)mem[MEM_HN], head = (long)mem[MEM_HH], i;
    if (n < NH) {
        i = (head + n) % NH;
        mem[MEM_HN] = (double)(n + 1);
    } else {
        i = head;
        mem[MEM_HH] = (double)((head + 1) % NH);
    }
    mem[MEM_H0 + 3 * i] = t;
    mem[MEM_H0 + 3 * i + 1] = fx;
    mem[MEM_H0 + 3 * i + 2] = fy;
}

static void mem_rotate(const double *x, double *P, const double *aux, long *cnt, double *mem,
                       const double *cfg, double t) {
    if (cfg[K_SNAP_PERIOD] <= 0.0 || t - mem[MEM_T_ROT] < cfg[K_SNAP_PERIOD]) return;
    condition_cov(P, cfg, cnt);
    memmove(mem + MEM_A, mem + MEM_B, sizeof(double) * SNAP);
    mem_save(x, P, aux, mem, MEM_B);
    mem[MEM_T_ROT] = t;
}

static int rewind_imu_only(double *x, double *P, double *aux, long *cnt, const double *cfg, const double *ts,
                           const double *tg, long nv, double *mem, double ba_var_add) {
    if (cfg[K_SNAP_PERIOD] <= 0.0 || mem[MEM_A + SNAP - 1] != 1.0) return 0;
    long k = MEM_A + NX + NX * NX;
    double t_snap = mem[k];
    long n = (long)mem[MEM_HN], head = (long)mem[MEM_HH];
    if (n == 0 || mem[MEM_H0 + 3 * head] > t_snap + 0.05) return 0;
    double t_now = aux[A_T_STATE], fx_now = aux[A_FX], fy_now = aux[A_FY];
    memcpy(x, mem + MEM_A, sizeof(double) * NX);
    memcpy(P, mem + MEM_A + NX, sizeof(double) * NX * NX);
    aux[A_T_STATE] = t_snap;
    block_clear(aux); /* the snapshot's P is at its own time; the re-propagation starts a block */
    aux[A_GY_N] = 0.0; /* the window's residuals belong to the abandoned trajectory */
    aux[A_FX] = mem[k + 1];
    aux[A_FY] = mem[k + 2];
    PIJ(P, BA, BA) += ba_var_add;
    for (long m = 0; m < n; m++) {
        long i = (head + m) % NH;
        double ti = mem[MEM_H0 + 3 * i];
        if (ti <= t_snap || ti > t_now) continue;
        predict_to(x, P, aux, cnt, cfg, ts, tg, nv, ti);
        aux[A_FX] = mem[MEM_H0 + 3 * i + 1];
        aux[A_FY] = mem[MEM_H0 + 3 * i + 2];
    }
    predict_to(x, P, aux, cnt, cfg, ts, tg, nv, t_now);
    aux[A_FX] = fx_now;
    aux[A_FY] = fy_now;
    aux[A_T_STATE] = t_now;
    mem[MEM_A + SNAP - 1] = 0.0;
    mem[MEM_B + SNAP - 1] = 0.0;
    cnt[C_SLIP_REWIND] += 1;
    return 1;
}

/* ------------------------------------------------------------------ initialisation */
static long step_init(double *x, double *P, double *aux, long *cnt, double *mem, const double *cfg,
                      const double *ts, const double *tg, long nv, double t, double s, double v,
                      double direction) {
    if (!(isfinite(t) && isfinite(s) && isfinite(v)) || fabs(v) > 1000.0 || fabs(direction) != 1.0)
        return O_INVALID;
    if (aux[A_INIT] != 0.0) {
        sync_block(x, P, aux, cfg, cnt); /* the kept error states' covariance, up to the old state time */
    } else {
        block_clear(aux);
        gn_reset(aux, cfg);
        memset(x, 0, sizeof(double) * NX);
        memset(P, 0, sizeof(double) * NX * NX);
        PIJ(P, BA, BA) = sq(cfg[K_INIT_SIGMA_BA]);
        PIJ(P, KO, KO) = sq(cfg[K_INIT_SIGMA_KO]);
        PIJ(P, GE, GE) = sq(aux[A_GM_SIG]);
        PIJ(P, GN, GN) = sq(aux[A_GM_SIG]);
        PIJ(P, BG, BG) = sq(cfg[K_INIT_SIGMA_BG]);
        PIJ(P, MY, MY) = sq(cfg[K_INIT_SIGMA_MY]);
        PIJ(P, SF, SF) = sq(cfg[K_INIT_SIGMA_SF]);
        PIJ(P, SG, SG) = sq(cfg[K_INIT_SIGMA_SG]);
        PIJ(P, MX, MX) = sq(cfg[K_INIT_SIGMA_MX]);
    }
    for (int i = 0; i < NX; i++) {
        PIJ(P, S, i) = 0.0;
        PIJ(P, i, S) = 0.0;
        PIJ(P, V, i) = 0.0;
        PIJ(P, i, V) = 0.0;
    }
    x[S] = s;
    x[V] = direction * v;
    aux[A_DIR] = direction;
    PIJ(P, S, S) = sq(cfg[K_INIT_SIGMA_S]);
    PIJ(P, V, V) = sq(cfg[K_INIT_SIGMA_V]);
    double grade = interp_at(ts, tg, nv, s);
    aux[A_FX] = x[BA] + direction * cfg[K_GRAVITY] * grade / sqrt(1.0 + grade * grade);
    aux[A_FY] = 0.0;
    aux[A_T_STATE] = t;
    aux[A_T_IMU] = t;
    aux[A_T_ODO] = t;
    aux[A_T_GPS] = t;
    aux[A_T_INIT] = t;
    aux[A_INIT] = 1.0;
    aux[A_SLIP] = 0.0;
    aux[A_SLIP_BAD] = 0.0;
    aux[A_SLIP_GOOD] = 0.0;
    aux[A_CUSUM_P] = 0.0;
    aux[A_CUSUM_N] = 0.0;
    aux[A_GPS_HOLD] = -INFINITY;
    aux[A_GPS_REJ] = 0.0;
    aux[A_STEP_FLAG] = 0.0;
    aux[A_LOGLIK] = 0.0;
    aux[A_STILL] = 0.0;
    aux[A_IMU_TO] = 0.0;
    aux[A_ODO_TO] = 0.0;
    aux[A_GPS_TO] = 0.0;
    aux[A_IMU_SAME] = 0.0;
    aux[A_IMU_FAULT_T] = -INFINITY;
    aux[A_SLIP_DS] = 0.0;
    aux[A_SLIP_LLR] = 0.0;
    aux[A_SLIP_S_ODO] = s;
    aux[A_SLIP_V_ODO] = x[V];
    aux[A_T_ODO_SEEN] = t;
    aux[A_GY_N] = 0.0;
    mem_reset(mem);
    cnt[C_INIT] += 1;
    condition_cov(P, cfg, cnt);
    return O_INITIALISED;
}

/* ------------------------------------------------------------------ IMU */
static double roll_cos(double f_lat, double f_up, double fy, double fz) {
    double nb = sqrt(fy * fy + fz * fz);
    double nl = sqrt(f_lat * f_lat + f_up * f_up);
    if (!(0.8 * nl <= nb && nb <= 1.25 * nl)) return 1.0;
    double c = (f_lat * fy + f_up * fz) / (nl * nb); /* cos(phi) = <f_level, f_body> / (|.| |.|) */
    if (!(c >= COS_MAX_ROLL)) return 1.0;
    if (f_lat < 0.0 && fy < 0.0 && copysign(1.0, f_up) != copysign(1.0, fz)) return 1.0; /* branch cut */
    return c;
}

/* one gyro update from the window's n samples (mean residual, mean Jacobian, R = sigma_g^2 / n + mean
   (v sigma_k)^2); empties the window first, so its own correction does not shift it */
static void gyro_window_update(double *x, double *P, double *aux, long *cnt, const double *cfg) {
    double n = aux[A_GY_N];
    aux[A_GY_N] = 0.0;
    sync_block(x, P, aux, cfg, cnt);
    int two = cfg[K_GYRO_TWO_SCALES] != 0.0;
    double lam = aux[A_GY_LAM] >= 1.0 ? aux[A_GY_LAM] : 1.0; /* learned curvature-error scale */
    double lamc = two ? (aux[A_GY_LAMC] >= 1.0 ? aux[A_GY_LAMC] : 1.0) : lam; /* the curve terms' */
    double rw = sq(cfg[K_GYRO_SIGMA]) / n;
    double rc0 = aux[A_GY_RC0] / n;
    double rcf0 = aux[A_GY_RCF0] / n;
    double rcc0 = fmax(rc0 - rcf0, 0.0);
    double rcf = aux[A_GY_RCF] / n;
    double r = rw + lam * aux[A_GY_RC] / n + (lamc - lam) * fmax(aux[A_GY_RC] / n - rcf, 0.0);
    double y = aux[A_GY_Y] / n;
    double nis;
    double sm = innovation1(P, aux, S, aux[A_GY_HS] / n, V, aux[A_GY_HV] / n, BG, 1.0, SG, aux[A_GY_HSG] / n,
                            MX, aux[A_GY_HMX] / n, r, y, &nis);
    aux[A_LAST_NIS_GYRO] = nis;
    double s0 = (sm - r) + rw + lam * rc0 + (lamc - lam) * rcc0; /* the residual's variance (no n_c) */
    aux[A_LAST_S_GYRO] = sm;
    aux[A_LAST_SHARE_GYRO] = s0 / sm;
    if (cfg[K_GYRO_AD_M] > 0.0 && rc0 > 0.0) { /* weighted least-squares lam, EWMAs over metres */
        double w = fmin(fabs(x[V]) * fmax(aux[A_T_IMU] - aux[A_GY_T0], 1e-3) / cfg[K_GYRO_AD_M], 1.0);
        double a = y * y - (sm - r) - rw;
        double i2 = 1.0 / (s0 * s0);
        if (aux[A_GY_LAM_DEN] == 0.0) {
            aux[A_GY_LAM_NUM] = GYRO_LAM_PRIOR;
            aux[A_GY_LAM_DEN] = GYRO_LAM_PRIOR;
            aux[A_GY_LAMC_NUM] = GYRO_LAM_PRIOR;
            aux[A_GY_LAM_DCC] = GYRO_LAM_PRIOR;
            aux[A_GY_LAM_DFC] = 0.0;
        }
        if (two) { /* a = lam rc0_f + lam_c rc0_c: the same least squares in two unknowns */
            aux[A_GY_LAM_NUM] += w * (rcf0 * a * i2 - aux[A_GY_LAM_NUM]);
            aux[A_GY_LAM_DEN] += w * (rcf0 * rcf0 * i2 - aux[A_GY_LAM_DEN]);
            aux[A_GY_LAMC_NUM] += w * (rcc0 * a * i2 - aux[A_GY_LAMC_NUM]);
            aux[A_GY_LAM_DCC] += w * (rcc0 * rcc0 * i2 - aux[A_GY_LAM_DCC]);
            aux[A_GY_LAM_DFC] += w * (rcf0 * rcc0 * i2 - aux[A_GY_LAM_DFC]);
            double nf = aux[A_GY_LAM_NUM], nc = aux[A_GY_LAMC_NUM], dff = aux[A_GY_LAM_DEN];
            double dcc = aux[A_GY_LAM_DCC], dfc = aux[A_GY_LAM_DFC];
            double det = dff * dcc - dfc * dfc;
            double lf = det > 0.0 ? (nf * dcc - nc * dfc) / det : 1.0;
            double lc = det > 0.0 ? (nc * dff - nf * dfc) / det : 1.0;
            if (lf < 1.0) {
                lf = 1.0;
                lc = (nc - dfc) / dcc;
            } else if (lc < 1.0) {
                lc = 1.0;
                lf = (nf - dfc) / dff;
            }
            aux[A_GY_LAM] = fmin(fmax(lf, 1.0), GYRO_LAM_MAX);
            aux[A_GY_LAMC] = fmin(fmax(lc, 1.0), GYRO_LAM_MAX);
        } else {
            aux[A_GY_LAM_NUM] += w * (rc0 * a * i2 - aux[A_GY_LAM_NUM]);
            aux[A_GY_LAM_DEN] += w * (rc0 * rc0 * i2 - aux[A_GY_LAM_DEN]);
            aux[A_GY_LAM] = fmin(fmax(aux[A_GY_LAM_NUM] / aux[A_GY_LAM_DEN], 1.0), GYRO_LAM_MAX);
        }
    }
    if (nis <= cfg[K_GATE_GYRO]) {
        if (apply_update1(x, P, aux, sm, y, cfg, cnt)) {
            cnt[C_GYRO_OK] += 1;
            aux[A_GYRO_OK] = 1.0;
        }
    } else {
        cnt[C_GYRO_GATED] += 1;
    }
}

static long step_imu(double *x, double *P, double *aux, long *cnt, double *mem, const double *cfg,
                     const double *ts, const double *tg, const double *tk, long nv, double t, double fx,
                     double fy, double fz, double wx, double wy, double wz) {
    if (!(isfinite(t) && isfinite(fx) && isfinite(fy) && isfinite(fz) && isfinite(wx) && isfinite(wy)
          && isfinite(wz)) || fabs(fx) > 300.0 || fabs(fy) > 300.0 || fabs(fz) > 300.0 || fabs(wz) > 100.0) {
        cnt[C_IMU_BAD] += 1;
        return O_INVALID;
    }
    if (aux[A_INIT] == 0.0) {
        cnt[C_NOT_INIT] += 1;
        return O_NOT_INIT;
    }
    if (aux[A_T_STATE] - t > cfg[K_LATE_TOL]) {
        cnt[C_IMU_LATE] += 1;
        return O_LATE;
    }
    if (cfg[K_IMU_STUCK_N] > 0.0) {
        if (fx == aux[A_FX] && fy == aux[A_FY] && fz == aux[A_FZ] && wx == aux[A_WX] && wy == aux[A_WY] &&
            wz == aux[A_GZ])
            aux[A_IMU_SAME] += 1.0;
        else
            aux[A_IMU_SAME] = 0.0;
        if (aux[A_IMU_SAME] >= cfg[K_IMU_STUCK_N]) {
            cnt[C_IMU_STUCK] += 1;
            predict_to(x, P, aux, cnt, cfg, ts, tg, nv, t);
            check_timeouts(aux, cnt, cfg, t);
            return O_INVALID;
        }
    }
    predict_to(x, P, aux, cnt, cfg, ts, tg, nv, t);
    double dt_imu = t - aux[A_T_IMU];
    double alpha = dt_imu / cfg[K_FX_EWMA_TAU];
    if (alpha > 1.0 || cnt[C_IMU_OK] == 0) alpha = 1.0;
    if (alpha < 0.0) alpha = 0.0;
    double d = fx - aux[A_FX_MEAN];
    aux[A_FX_MEAN] += alpha * d;
    aux[A_FX_VAR] = (1.0 - alpha) * (aux[A_FX_VAR] + alpha * d * d);
    aux[A_FX] = fx;
    aux[A_FY] = fy;
    aux[A_FZ] = fz;
    aux[A_WX] = wx;
    aux[A_WY] = wy;
    aux[A_GZ] = wz;
    aux[A_T_IMU] = t;
    mem_push_imu(mem, t, fx, fy);
    cnt[C_IMU_OK] += 1;
    check_timeouts(aux, cnt, cfg, t);
    aux[A_LAST_NIS_GYRO] = -1.0;
    aux[A_GYRO_OK] = 0.0;
    if (cfg[K_USE_GYRO] != 0.0 && fabs(x[V]) >= cfg[K_GYRO_MIN_SPEED]) {
        /* the window spans too long: apply what it holds, before this sample's residual */
        if (aux[A_GY_N] > 0.0 && t - aux[A_GY_T0] > cfg[K_GYRO_AVG_MAX_S]) gyro_window_update(x, P, aux, cnt, cfg);
        double dk_ds;
        double k = interp_slope_at(ts, tk, nv, x[S], seg_hint(ts, nv, x[S], aux), &dk_ds);
        double c = 1.0;
        if (cfg[K_GYRO_TILT] != 0.0) c = roll_cos(x[V] * x[V] * aux[A_DIR] * k, -cfg[K_GRAVITY], fy, fz);
        double g1 = c * (1.0 + x[SG]);
        double y = wz - (g1 * x[V] * k + x[BG] + x[MX] * wx);
        if (aux[A_GY_N] == 0.0) {
            aux[A_GY_T0] = t;
            aux[A_GY_Y] = 0.0;
            aux[A_GY_HS] = 0.0;
            aux[A_GY_HV] = 0.0;
            aux[A_GY_HSG] = 0.0;
            aux[A_GY_HMX] = 0.0;
            aux[A_GY_RC] = 0.0;
            aux[A_GY_RC0] = 0.0;
            aux[A_GY_RCF] = 0.0;
            aux[A_GY_RCF0] = 0.0;
        }
        aux[A_GY_N] += 1.0;
        aux[A_GY_Y] += y;
        aux[A_GY_HS] += g1 * x[V] * dk_ds;
        aux[A_GY_HV] += g1 * k;
        aux[A_GY_HSG] += c * x[V] * k;
        aux[A_GY_HMX] += wx;
        /* curvature-model error from the geometry: sigma_k^2 = s0^2 + (r k)^2 + (l dk/ds)^2 */
        double rcf = sq(x[V] * cfg[K_CURV_SIGMA]);
        double rc = rcf + sq(x[V] * (cfg[K_CURV_REL] * k)) + sq(x[V] * (cfg[K_CURV_REG_M] * dk_ds));
        aux[A_GY_RC0] += rc;
        aux[A_GY_RCF0] += rcf;
        /* correlated over K_CURV_CORR_M: the windows inside that length share it (n_c >= 1) */
        if (cfg[K_CURV_CORR_M] > 0.0) {
            double dtc = dt_imu > 1e-3 ? dt_imu : 1e-3;
            if (dtc > cfg[K_GYRO_AVG_MAX_S]) dtc = cfg[K_GYRO_AVG_MAX_S];
            double dw = fabs(x[V]) * cfg[K_GYRO_AVG_N] * dtc;
            double nc = dw > 0.0 ? cfg[K_CURV_CORR_M] / dw : 1.0;
            if (nc > 1.0) {
                rc *= nc;
                rcf *= nc;
            }
        }
        aux[A_GY_RC] += rc; /* (v sigma_k)^2 n_c: does not average out */
        aux[A_GY_RCF] += rcf;
        if (aux[A_GY_N] >= cfg[K_GYRO_AVG_N]) gyro_window_update(x, P, aux, cnt, cfg);
    } else {
        aux[A_GY_N] = 0.0; /* a window holds consecutive samples that all qualify */
    }
    return O_ACCEPTED;
}

/* ------------------------------------------------------------------ odometer (+ slip, ZUPT) */
static long step_odo(double *x, double *P, double *aux, long *cnt, double *mem, const double *cfg,
                     const double *ts, const double *tg, long nv, double t, double speed, double sigma) {
    if (!(isfinite(t) && isfinite(speed) && isfinite(sigma)) || sigma <= 0.0 || fabs(speed) > 300.0) {
        cnt[C_ODO_BAD] += 1;
        return O_INVALID;
    }
    if (aux[A_INIT] == 0.0) {
        cnt[C_NOT_INIT] += 1;
        return O_NOT_INIT;
    }
    if (aux[A_T_STATE] - t > cfg[K_LATE_TOL]) {
        cnt[C_ODO_LATE] += 1;
        return O_LATE;
    }
    predict_to(x, P, aux, cnt, cfg, ts, tg, nv, t);
    sync_block(x, P, aux, cfg, cnt);
    check_timeouts(aux, cnt, cfg, t);
    double sig = sigma > cfg[K_ODO_SIGMA_MIN] ? sigma : cfg[K_ODO_SIGMA_MIN];
    double d = aux[A_DIR];
    double h_v = d * (1.0 + x[KO]), h_ko = d * x[V];
    double r = sig * sig + sq(cfg[K_ODO_QUANT]) / 12.0;
    double y = speed - d * x[V] * (1.0 + x[KO]);
    double nis;
    double sm = innovation1(P, aux, V, h_v, KO, h_ko, -1, 0.0, -1, 0.0, -1, 0.0, r, y, &nis);
    aux[A_LAST_NIS_ODO] = nis;
    double v_odo = h_v != 0.0 ? speed / h_v : x[V];
    if (aux[A_SLIP] != 0.0) {
        double dt = t - aux[A_T_ODO_SEEN];
        dt = dt > 0.0 ? dt : 0.0;
        dt = dt < 1.0 ? dt : 1.0;
        aux[A_SLIP_S_ODO] += 0.5 * (aux[A_SLIP_V_ODO] + v_odo) * dt;
        aux[A_SLIP_DS] = aux[A_SLIP_S_ODO] - x[S];
    }
    aux[A_SLIP_V_ODO] = v_odo;
    aux[A_T_ODO_SEEN] = t;
    int imu_timely = (t - aux[A_T_IMU]) <= cfg[K_IMU_TIMEOUT];
    double fxv = aux[A_FX_VAR] > 0.0 ? aux[A_FX_VAR] : 0.0;
    int still = fabs(speed) < cfg[K_STILL_SPEED] && imu_timely && sqrt(fxv) < cfg[K_STILL_FX_STD];
    aux[A_STILL] = still ? 1.0 : 0.0;
    int use = 0;
    long outcome = O_GATED;
    int by_gnss = aux[A_SLIP] != 0.0 && aux[A_SLIP_LLR] >= cfg[K_SLIP_ARB_LLR];
    if (by_gnss || (nis > cfg[K_GATE_ODO] && aux[A_SLIP] != 0.0 && t - aux[A_SLIP_T0] > cfg[K_SLIP_MAX_S])) {
        PIJ(P, V, V) += y * y;
        PIJ(P, BA, BA) += sq(cfg[K_SLIP_BA_SIGMA]);
        double vabs = fabs(x[V]) > 1.0 ? fabs(x[V]) : 1.0;
        PIJ(P, SG, SG) += sq(y / vabs);
        if (by_gnss) {
            gyro_window_shift(aux, aux[A_SLIP_DS], 0.0, 0.0, 0.0, 0.0);
            x[S] += aux[A_SLIP_DS];
            for (int i = 0; i < NX; i++) {
                if (i != S) {
                    PIJ(P, S, i) = 0.0;
                    PIJ(P, i, S) = 0.0;
                }
            }
        } else {
            PIJ(P, S, S) += sq(aux[A_SLIP_DS]);
        }
        aux[A_IMU_FAULT_T] = t;
        cnt[C_IMU_FAULT] += 1;
        sm = innovation1(P, aux, V, h_v, KO, h_ko, -1, 0.0, -1, 0.0, -1, 0.0, r, y, &nis);
        use = 1;
        aux[A_SLIP] = 0.0;
        aux[A_SLIP_BAD] = 0.0;
        cnt[C_ODO_REANCHOR] += 1;
    } else if (nis > cfg[K_GATE_ODO]) {
        aux[A_SLIP_BAD] += 1.0;
        aux[A_SLIP_GOOD] = 0.0;
        cnt[C_ODO_GATED] += 1;
        if (aux[A_SLIP] == 0.0 && aux[A_SLIP_BAD] >= cfg[K_SLIP_CONFIRM_N]) {
            aux[A_SLIP] = 1.0;
            aux[A_SLIP_T0] = t;
            aux[A_SLIP_LLR] = 0.0;
            aux[A_GPS_HOLD] = -INFINITY;
            cnt[C_SLIP] += 1;
            double s_odo = x[S];
            rewind_imu_only(x, P, aux, cnt, cfg, ts, tg, nv, mem, 0.0);
            aux[A_SLIP_S_ODO] = s_odo;
            aux[A_SLIP_DS] = s_odo - x[S];
        }
    } else if (aux[A_SLIP] != 0.0) {
        aux[A_SLIP_GOOD] += 1.0;
        if (aux[A_SLIP_GOOD] >= cfg[K_SLIP_RELEASE_N]) {
            aux[A_SLIP] = 0.0;
            aux[A_SLIP_BAD] = 0.0;
            use = 1;
        } else {
            cnt[C_ODO_GATED] += 1;
        }
    } else {
        aux[A_SLIP_BAD] = 0.0;
        use = 1;
    }
    if (use) {
        if (apply_update1(x, P, aux, sm, y, cfg, cnt)) {
            cnt[C_ODO_OK] += 1;
            aux[A_T_ODO] = t;
            outcome = O_ACCEPTED;
            if (aux[A_SLIP] == 0.0 && aux[A_SLIP_BAD] == 0.0 && nis <= cfg[K_GATE_ODO] / 4.0)
                mem_rotate(x, P, aux, cnt, mem, cfg, t);
        }
    }
    if (still) {
        sync_block(x, P, aux, cfg, cnt); /* (a rewind above re-propagated P into a new block) */
        double yz = -x[V];
        double rz = sq(cfg[K_ZUPT_SIGMA]);
        sm = innovation1(P, aux, V, 1.0, -1, 0.0, -1, 0.0, -1, 0.0, -1, 0.0, rz, yz, &nis);
        if (nis <= cfg[K_GATE_ZUPT])
            if (apply_update1(x, P, aux, sm, yz, cfg, cnt)) cnt[C_ZUPT] += 1;
    }
    return outcome;
}

/* ------------------------------------------------------------------ GNSS */
static long step_gps(double *x, double *P, double *aux, long *cnt, const double *cfg, const double *ts,
                     const double *te, const double *tn, const double *tg, long nv, double t, double east,
                     double north, double sigma_h, long fix_quality) {
    if (fix_quality == 0) {
        cnt[C_GPS_NOFIX] += 1;
        return O_NO_FIX;
    }
    if (!(isfinite(t) && isfinite(east) && isfinite(north)) || fabs(east) > 1e7 || fabs(north) > 1e7
        || (isfinite(sigma_h) && sigma_h > 1e4) || isinf(sigma_h)) {
        cnt[C_GPS_BAD] += 1;
        return O_INVALID;
    }
    if (aux[A_INIT] == 0.0) {
        cnt[C_NOT_INIT] += 1;
        return O_NOT_INIT;
    }
    double dl = aux[A_T_STATE] - t;
    if (dl > cfg[K_GPS_LATE_MAX]) {
        cnt[C_GPS_LATE] += 1;
        return O_LATE;
    }
    if (dl <= 0.0) {
        predict_to(x, P, aux, cnt, cfg, ts, tg, nv, t);
        dl = 0.0;
    }
    sync_block(x, P, aux, cfg, cnt);
    if (t - aux[A_T_GPS] > cfg[K_GPS_TIMEOUT] && aux[A_GPS_REJ] == 0.0) {
        gn_restart(aux);
        double gm = aux[A_GM_SIG];
        for (int i = 0; i < NX; i++) {
            PIJ(P, GE, i) = 0.0;
            PIJ(P, i, GE) = 0.0;
            PIJ(P, GN, i) = 0.0;
            PIJ(P, i, GN) = 0.0;
        }
        x[GE] = 0.0;
        x[GN] = 0.0;
        PIJ(P, GE, GE) = gm * gm;
        PIJ(P, GN, GN) = gm * gm;
    }
    check_timeouts(aux, cnt, cfg, t > aux[A_T_STATE] ? t : aux[A_T_STATE]);
    if (cfg[K_AD_WINDOW] > 0.0) { /* the fix's distance from the line into the GNSS statistics */
        double n_e, n_n, s_foot;
        double c_x = cross_track(ts, te, tn, nv, x[S] - x[V] * dl, east, north, &n_e, &n_n, &s_foot);
        gn_observe(aux, cfg, t, c_x, n_e, n_n, s_foot, sigma_h);
    }
    double sw = gn_white_sigma(aux, sigma_h);
    double sl2 = sq(cfg[K_TRACK_LAT]);
    if (cfg[K_TRACK_LAT_CORR_M] > 0.0) { /* lateral_variance: the fixes in one length share the map's offset */
        double step = fabs(x[V]) * gn_max(t - aux[A_T_GPS], 0.0);
        double nc = step * LAT_NC_MAX > cfg[K_TRACK_LAT_CORR_M] ? cfg[K_TRACK_LAT_CORR_M] / step : LAT_NC_MAX;
        if (nc > 1.0)
            sl2 *= nc;
    }
    /* iterated EKF in the arc length: gps_model linearised at s_lin, Gauss-Newton steps from x[S] */
    double e, n, de = 0.0, dn = 0.0, ue = 0.0, un = 0.0;
    double H[2 * NX] = {0}, R[4] = {0}, y[2];
    Innov2 in;
    double s_lin = x[S];
    double s_reach = sqrt(cfg[K_GATE_GPS] * PIJ(P, S, S)); /* the linearisation point stays within the gate */
    for (int it = 0; it <= GPS_IEKF_ITERATIONS; it++) {
        double s_eval = s_lin - x[V] * dl;
        geom_at(ts, te, tn, nv, s_eval, &e, &n, &de, &dn);
        H[S] = de;
        H[NX + S] = dn;
        H[V] = -dl * de;
        H[NX + V] = -dl * dn;
        H[GE] = 1.0;
        H[NX + GN] = 1.0;
        double he = e + x[GE], hn = n + x[GN];
        y[0] = east - he - de * (x[S] - s_lin);
        y[1] = north - hn - dn * (x[S] - s_lin);
        double tnorm = sqrt(de * de + dn * dn);
        ue = de / tnorm;
        un = dn / tnorm;
        /* gps_noise_matrix */
        R[0] = sw * sw + sl2 * un * un;
        R[3] = sw * sw + sl2 * ue * ue;
        R[1] = -sl2 * ue * un;
        R[2] = R[1];
        if (dl > 0.0) {
            double qa = cfg[K_Q_ACC] * dl * dl * dl / 3.0;
            R[0] += qa * ue * ue;
            R[3] += qa * un * un;
            R[1] += qa * ue * un;
            R[2] += qa * ue * un;
        }
        innovation2(P, aux, H, R, y, &in);
        if (it == GPS_IEKF_ITERATIONS)
            break;
        double w0 = in.si00 * y[0] + in.si01 * y[1];
        double w1 = in.si01 * y[0] + in.si11 * y[1];
        double s_next = x[S] + aux[A_WK_PHT + S] * w0 + aux[A_WK_PHT + NX + S] * w1;
        s_next = gn_min(gn_max(s_next, x[S] - s_reach), x[S] + s_reach);
        if (fabs(s_next - s_lin) < GPS_IEKF_TOL_M)
            break;
        s_lin = s_next;
    }
    aux[A_LAST_NIS_GPS] = in.nis;
    double along = y[0] * ue + y[1] * un;
    if (aux[A_SLIP] != 0.0 && (aux[A_SLIP_LLR] > -cfg[K_SLIP_ARB_LLR] || in.nis > cfg[K_GATE_GPS])) {
        double ds = aux[A_SLIP_DS];
        double y0 = y[0] - de * ds, y1 = y[1] - dn * ds;
        double nis_odo = y0 * (in.si00 * y0 + in.si01 * y1) + y1 * (in.si01 * y0 + in.si11 * y1);
        double nmin = nis_odo < in.nis ? nis_odo : in.nis; /* Python's min(nis, nis_odo) */
        if (nmin <= cfg[K_GATE_GPS]) {
            double cap = cfg[K_GPS_MAX_LOGLIK_NIS];
            double a = cap < in.nis ? cap : in.nis, b = cap < nis_odo ? cap : nis_odo;
            double wt = gps_evidence_weight(t, aux[A_T_GPS], cfg);
            double llr = aux[A_SLIP_LLR] + wt * 0.5 * (a - b);
            aux[A_SLIP_LLR] = -cfg[K_SLIP_ARB_LLR] > llr ? -cfg[K_SLIP_ARB_LLR] : llr;
            aux[A_T_GPS] = t;
        }
        cnt[C_GPS_HELD] += 1;
        return O_HELD_OFF;
    }
    if (t < aux[A_GPS_HOLD]) {
        cnt[C_GPS_HELD] += 1;
        return O_HELD_OFF;
    }
    if (in.nis > cfg[K_GATE_GPS]) {
        cnt[C_GPS_GATED] += 1;
        aux[A_GPS_REJ] += 1.0;
        if (aux[A_GPS_REJ] == 1.0) {
            aux[A_T_FIRST_GPS_REJ] = t;
            aux[A_REJ_DS] = along;
            aux[A_REJ_MAXDEV] = 0.0;
            aux[A_REJ_E] = east;
            aux[A_REJ_N] = north;
            aux[A_REJ_S] = x[S];
            if (sqrt(y[0] * y[0] + y[1] * y[1]) >= cfg[K_STEP_MIN_M]) {
                aux[A_STEP_FLAG] = 1.0;
                cnt[C_STEP] += 1;
            }
        } else {
            double dev = fabs(along - aux[A_REJ_DS]);
            aux[A_REJ_MAXDEV] = aux[A_REJ_MAXDEV] > dev ? aux[A_REJ_MAXDEV] : dev;
        }
        if (t - aux[A_T_FIRST_GPS_REJ] >= cfg[K_REACQ_S] && aux[A_REJ_MAXDEV] <= cfg[K_REACQ_CONSIST_M]) {
            PIJ(P, S, S) += along * along + y[0] * y[0] + y[1] * y[1];
            innovation2(P, aux, H, R, y, &in);
            if (apply_update2(x, P, aux, y, &in, cfg, cnt)) {
                cnt[C_GPS_REACQ] += 1;
                aux[A_GPS_REJ] = 0.0;
                aux[A_STEP_FLAG] = 0.0;
                aux[A_T_GPS] = t;
                aux[A_GPS_E] = east;
                aux[A_GPS_N] = north;
                return O_ACCEPTED;
            }
        } else if (t - aux[A_T_FIRST_GPS_REJ] >= cfg[K_REACQ_S]) {
            if (cfg[K_RELOC] != 0.0) { /* a relocalisation request (the Python side spawns) */
                aux[A_RELOC] = 1.0;
                aux[A_RELOC_E] = east;
                aux[A_RELOC_N] = north;
                aux[A_RELOC_E0] = aux[A_REJ_E];
                aux[A_RELOC_N0] = aux[A_REJ_N];
                aux[A_RELOC_DS] = aux[A_DIR] * (x[S] - aux[A_REJ_S]);
            }
            aux[A_GPS_REJ] = 1.0;
            aux[A_T_FIRST_GPS_REJ] = t;
            aux[A_REJ_DS] = along;
            aux[A_REJ_MAXDEV] = 0.0;
            aux[A_REJ_E] = east;
            aux[A_REJ_N] = north;
            aux[A_REJ_S] = x[S];
        }
        return O_GATED;
    }
    double s_along = ue * (in.s00 * ue + in.s01 * un) + un * (in.s01 * ue + in.s11 * un);
    double r = along / sqrt(s_along);
    double kk = cfg[K_CUSUM_K];
    double wt = gps_evidence_weight(t, aux[A_T_GPS], cfg);
    if (aux[A_SLIP] != 0.0) {
        wt = 0.0;
        aux[A_CUSUM_P] = 0.0;
        aux[A_CUSUM_N] = 0.0;
    }
    double cp = aux[A_CUSUM_P] + wt * (r - kk), cn = aux[A_CUSUM_N] + wt * (-r - kk);
    aux[A_CUSUM_P] = cp > 0.0 ? cp : 0.0;
    aux[A_CUSUM_N] = cn > 0.0 ? cn : 0.0;
    if (aux[A_CUSUM_P] > cfg[K_CUSUM_H] || aux[A_CUSUM_N] > cfg[K_CUSUM_H]) {
        cnt[C_RAMP] += 1;
        aux[A_RAMP_T] = t;
        aux[A_GPS_HOLD] = t + cfg[K_GPS_HOLDOFF_S];
        aux[A_CUSUM_P] = 0.0;
        aux[A_CUSUM_N] = 0.0;
        cnt[C_GPS_GATED] += 1;
        return O_GATED;
    }
    if (!apply_update2(x, P, aux, y, &in, cfg, cnt)) {
        cnt[C_GPS_BAD] += 1;
        return O_INVALID;
    }
    aux[A_GPS_REJ] = 0.0;
    aux[A_STEP_FLAG] = 0.0;
    aux[A_T_GPS] = t;
    aux[A_GPS_E] = east;
    aux[A_GPS_N] = north;
    cnt[C_GPS_OK] += 1;
    if (dl > 0.0) cnt[C_GPS_LATE_USED] += 1;
    return O_ACCEPTED;
}

/* ------------------------------------------------------------------ the loop of sfa.batch.run_packed */
long sfa_run_packed(long n, const long *kind, const double *t, const double *vals, double *x, double *P,
                    double *aux, long *cnt, double *mem, const double *cfg, long nv, const double *ts,
                    const double *te, const double *tn, const double *tg, const double *tk, double *out_f,
                    long *out_i) {
    for (long i = 0; i < n; i++) {
        long k = kind[i];
        double ti = t[i];
        const double *v = vals + i * NVALS;
        long o;
        if (k == 1) {
            o = step_imu(x, P, aux, cnt, mem, cfg, ts, tg, tk, nv, ti, v[0], v[1], v[2], v[3], v[4], v[5]);
        } else if (k == 2) {
            o = step_odo(x, P, aux, cnt, mem, cfg, ts, tg, nv, ti, v[0], v[1]);
        } else if (k == 3) {
            long fq = !isfinite(v[3]) ? -1 : (long)v[3];
            o = step_gps(x, P, aux, cnt, cfg, ts, te, tn, tg, nv, ti, v[0], v[1], v[2], fq);
        } else if (k == 8) {
            o = step_init(x, P, aux, cnt, mem, cfg, ts, tg, nv, ti, v[0], v[1], v[3]);
        } else {
            o = O_INVALID;
        }
        long bits;
        double sig;
        long st = status_of(x, P, aux, cfg, aux[A_T_STATE], &bits, &sig);
        out_f[i * 4 + 0] = aux[A_T_STATE];
        out_f[i * 4 + 1] = x[S];
        out_f[i * 4 + 2] = x[V];
        out_f[i * 4 + 3] = sig;
        out_i[i * 3 + 0] = o;
        out_i[i * 3 + 1] = st;
        out_i[i * 3 + 2] = bits;
    }
    return n;
}
