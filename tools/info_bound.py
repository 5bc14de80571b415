"""The information bound: how small an along-track error any filter can reach from GNSS and odometer.

A filter's accuracy target means something only beside what the data allow. This module computes,
for one simulated run, the error covariance of the *optimal* estimator of a relaxed problem that
knows strictly more than any real filter:

- the train starts exactly where the GROUND TRUTH puts it (as the benchmark's filters do);
- the odometer's errors are its scale factor ``k``, constant, drawn from the world's own
  distribution ``N(0, scale_sigma^2)``, and (``scenario_sigma``) its white speed noise and quantisation
  with the world's figures, which integrate to a random walk of the position (no slip, no dropout);
- the GNSS error is exactly the world's model and the filter knows its parameters: per axis a
  first-order Gauss-Markov error (sigma_g, tau) plus white noise sigma_w, at the fix times the
  receiver really delivered (outages included);
- the map is exact (no as-built offset) and the heading along the path is known.

State ``[ds, dk, g_e, g_n]``: position error along the track [m], odometer scale error [-], the GNSS
correlated error east and north [m]. Between fixes ``ds += v dt dk`` plus the odometer's integrated
white noise (variance ``sigma_v^2 dt / rate``); the Gauss-Markov states decay by
``exp(-dt / tau)``. A fix measures ``t ds + g + w`` (t: the unit tangent in east/north). The model is
linear and Gaussian, so the Kalman filter's covariance is the minimum mean-square error of every
causal estimator of it (the Bayesian Cramer-Rao bound is attained); a real filter, which must also
learn the parameters and live with odometer noise and a wrong map, can only do worse. Only the
covariance is propagated: no data are drawn.

What the bound leaves out: the map's shape as a position source (the gyro against the track's
curvature or heading), and the IMU as an odometer calibrator. Both are outside GNSS and odometer; a
filter that beats the bound must be getting position from them.

``expected_p95`` turns the per-sample sigmas into the p95 of the pooled |error| an estimator at the
bound would show: the x with mean_j P(|N(0, sigma_j^2)| > x) = 5 %.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import erfc

DS, DK, GE, GN = 0, 1, 2, 3  #: state indices: along-track error, odometer scale error, GNSS GM east, north


@dataclass(frozen=True)
class OdometerNoise:
    """The odometer's white error per sample: ``sigma_v(v)^2 = floor^2 + (fraction v)^2`` plus the
    quantisation's ``lsb^2 / 12``, at ``rate_hz`` samples a second."""

    sigma_floor_mps: float  #: white speed noise at low speed [m/s]
    sigma_fraction: float  #: white speed noise proportional to speed [fraction of |v|]
    lsb_mps: float  #: quantisation step [m/s]
    rate_hz: float  #: samples per second [Hz]

    def psd_m2ps(self, speed_mps: np.ndarray) -> np.ndarray:
        """Power spectral density of the position random walk the noise integrates to [m^2/s]: a
        sample's variance times its duration, ``sigma_v^2 / rate``."""
        v = np.abs(np.asarray(speed_mps, dtype=float))
        var = self.sigma_floor_mps ** 2 + (self.sigma_fraction * v) ** 2 + self.lsb_mps ** 2 / 12.0
        return var / self.rate_hz


@dataclass(frozen=True)
class GnssErrorModel:
    """The world's GNSS error, per horizontal axis."""

    gm_sigma_m: float  #: correlated (Gauss-Markov) error, steady sigma [m]
    gm_tau_s: float  #: its correlation time [s]
    white_sigma_m: float  #: white error sigma [m]


def along_track_sigma(
    t_s: np.ndarray,
    speed_mps: np.ndarray,
    tangent_en: np.ndarray,
    fix_t_s: np.ndarray,
    gnss: GnssErrorModel,
    odo_scale_sigma: float,
    init_sigma_m: float = 0.0,
    fix_z_en: np.ndarray | None = None,
    odo_psd_m2ps: np.ndarray | float = 0.0,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Sigma of the optimal along-track error at each time ``t_s`` (sorted) [m].

    ``speed_mps`` and ``tangent_en`` (n x 2, unit east/north) are the truth's at ``t_s``; from one
    sample to the next the earlier sample's speed and tangent hold. ``fix_t_s``: times of the usable
    fixes (sorted). A fix at a sample time is applied before that sample's sigma is taken.
    ``odo_psd_m2ps`` (scalar, or one value per sample, held like the speed): the odometer's white
    speed noise as the power spectral density of the position random walk it integrates to,
    ``sigma_v^2 / rate`` [m^2/s] (0: the odometer's only error is its scale).

    With ``fix_z_en`` (one east/north row per fix: the fix minus the odometer's track point) the
    filter also runs on those data and the estimate of ``ds`` at each time is returned beside the
    sigma (``(sigma, ds_hat)``): the check that the covariance is the error the model really makes.
    """
    t_s = np.asarray(t_s, dtype=float)
    fix_t_s = np.asarray(fix_t_s, dtype=float)
    sg2 = gnss.gm_sigma_m ** 2
    p = np.diag([init_sigma_m ** 2, odo_scale_sigma ** 2, sg2, sg2])
    x = np.zeros(4)
    r = np.eye(2) * gnss.white_sigma_m ** 2
    sigma = np.empty(t_s.size)
    ds_hat = np.empty(t_s.size)
    psd = np.broadcast_to(np.asarray(odo_psd_m2ps, dtype=float), t_s.shape)
    t_now = float(t_s[0]) if t_s.size else 0.0
    j = int(np.searchsorted(fix_t_s, t_now, side="left"))

    def predict(to: float, k_seg: int) -> None:
        nonlocal p, x, t_now
        dt = to - t_now
        if dt <= 0.0:
            return
        f = np.eye(4)
        f[DS, DK] = speed_mps[k_seg] * dt  # ds += v dt dk: the odometer's scale error integrates
        phi = math.exp(-dt / gnss.gm_tau_s)
        f[GE, GE] = f[GN, GN] = phi  # g <- exp(-dt / tau) g
        q = np.zeros((4, 4))
        q[GE, GE] = q[GN, GN] = sg2 * (1.0 - phi * phi)  # keeps the GM error's steady variance
        q[DS, DS] = psd[k_seg] * dt  # the odometer's white speed noise, integrated: a random walk
        x = f @ x
        p = f @ p @ f.T + q
        t_now = to

    for i in range(t_s.size):
        seg = max(i - 1, 0)  # a fix in (t_s[i-1], t_s[i]] lies on sample i-1's segment
        while j < fix_t_s.size and fix_t_s[j] <= t_s[i]:
            predict(float(fix_t_s[j]), seg)
            h = np.zeros((2, 4))
            h[:, DS] = tangent_en[seg]  # the along-track error moves the fix
            h[0, GE] = h[1, GN] = 1.0  # plus the correlated error
            s = h @ p @ h.T + r
            k = p @ h.T @ np.linalg.inv(s)
            if fix_z_en is not None:
                x = x + k @ (fix_z_en[j] - h @ x)
            ikh = np.eye(4) - k @ h
            p = ikh @ p @ ikh.T + k @ r @ k.T  # Joseph form
            j += 1
        predict(float(t_s[i]), seg)
        sigma[i] = math.sqrt(max(p[DS, DS], 0.0))
        ds_hat[i] = x[DS]
    return sigma if fix_z_en is None else (sigma, ds_hat)


def sigma_on_line(line, t_s, truth_t_s, truth_s_m, truth_speed_mps, fix_t_s, gnss: GnssErrorModel,
                  odo_scale_sigma: float, odo_noise: OdometerNoise | None = None) -> np.ndarray:
    """:func:`along_track_sigma` at the times ``t_s`` of a truth (times, arc lengths on ``line`` of
    track_db, speeds) sampled there: the speed's magnitude, the line's tangent at the truth's arc length;
    with ``odo_noise``, the odometer's white noise at that speed (None: a noise-free odometer)."""
    s = np.clip(np.interp(t_s, truth_t_s, truth_s_m), 0.0, line.length_m)
    speed = np.abs(np.interp(t_s, truth_t_s, truth_speed_mps))
    tangent = np.column_stack(line.tangent_at(s))
    psd = 0.0 if odo_noise is None else odo_noise.psd_m2ps(speed)
    return along_track_sigma(t_s, speed, tangent, np.sort(np.asarray(fix_t_s, dtype=float)), gnss,
                             odo_scale_sigma, odo_psd_m2ps=psd)


def scenario_sigma(sc, run, track, meas, grid) -> np.ndarray:
    """The bound's along-track sigma at the ``grid`` times of one simulated run: the world's actual
    GNSS error model, odometer scale distribution and odometer white noise
    (``interface_modules.scenario.actual_spec``: the preset's figures with the scenario's ``actual``
    values), at the fixes the receiver delivered (``meas``: fix quality > 0, finite position), on the
    truth's line of ``track``."""
    from interface_modules.scenario import actual_spec, rate_of
    from sfa.measurements import GpsMeas

    fixes = [m.t_s for m in meas if isinstance(m, GpsMeas) and m.fix_quality != 0
             and math.isfinite(m.lat_deg + m.lon_deg)]
    gps, odo = actual_spec(sc.gps), actual_spec(sc.odometer)
    model = GnssErrorModel(float(gps.gm_sigma_m), float(gps.gm_tau_s), float(gps.white_sigma_m))
    rate = rate_of(sc, sc.odometer)
    noise = OdometerNoise(float(odo.sigma_floor_mps), float(odo.sigma_fraction), float(odo.lsb_mps), rate)
    return sigma_on_line(track.line(int(run.truth["line_id"][0])), grid, run.truth["epoch"],
                         run.truth["arc_length"], run.truth["speed"], fixes, model, float(odo.scale_sigma),
                         noise)


def expected_p95(sigmas: np.ndarray, q: float = 0.95) -> float:
    """p95 of the pooled |error| of zero-mean Gaussian errors with these sigmas [m] (bisection)."""
    sig = np.asarray(sigmas, dtype=float)
    sig = sig[np.isfinite(sig)]
    if sig.size == 0:
        return math.nan
    top = float(sig.max())
    if top <= 0.0:
        return 0.0
    safe = np.where(sig > 0.0, sig, 1.0)
    lo, hi = 0.0, 10.0 * top
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        tail = np.where(sig > 0.0, erfc(mid / (math.sqrt(2.0) * safe)), 0.0).mean()  # P(|e| > x)
        if tail > 1.0 - q:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)
