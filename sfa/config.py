"""Typed configuration of the SFA filter: every noise parameter with its unit.

Gates are given as probabilities (the probability that a fault-free measurement passes); they are
turned into chi-square thresholds on the normalised innovation squared (NIS, dimensionless) with the
measurement's degrees of freedom: odometer, gyro and ZUPT 1, GNSS 2.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

from sfa.errors import FilterConfigError


@dataclass(frozen=True)
class FilterConfig:
    """Noise model, integrity thresholds and policies of ``TrackFilter``. Defaults: mems-train IMU,
    wheel odometer, standalone GNSS (see ``sfa.presets.filter_config_for``)."""

    # --- IMU (prediction)
    accel_noise_density_mps2_rthz: float = 5.88e-4  #: accelerometer white noise [m/s^2/sqrt(Hz)]
    accel_model_noise_mps2_rthz: float = 0.05  #: unmodelled acceleration [m/s^2/sqrt(Hz)]
    accel_bias_rw_mps2_rts: float = 2.0e-4  #: accelerometer bias random walk [m/s^2/sqrt(s)]
    init_sigma_accel_bias_mps2: float = 0.088  #: initial bias sigma incl. pitch misalignment [m/s^2]
    init_sigma_yaw_misalignment_rad: float = 0.0087  #: initial IMU yaw misalignment sigma [rad]
    init_sigma_accel_scale: float = 0.002  #: initial accelerometer scale-factor sigma [-]
    no_imu_accel_psd_m2ps3: float = 0.5  #: acceleration PSD while the IMU is timed out [m^2/s^3]
    gravity_mps2: float = 9.80665  #: gravity [m/s^2]
    max_predict_dt_s: float = 0.1  #: longest single prediction step [s]
    #: map registration: the database's arc length is the digitised polyline's, not the distance the
    #: train travels on the track as built (corners cut or not, vertices off the track), so the two
    #: drift apart by a random walk in the distance travelled: Q[S,S] += this |v| h. 1e-3 m^2/m is a
    #: 0.5 % length error correlated over 50 m ((0.005 * 50)^2 / 50 = 1.25e-3, the value of
    #: sfa.presets.datasheet_config_for); 0 (the default here): model-matched [m^2/m]
    registration_psd_m2pm: float = 0.0
    # --- gyro (optional update gz = v * curvature(s) + b_g)
    use_gyro: bool = True  #: apply the gyro update gz = v curvature(s) + b_g (see docs/filter.md)
    gyro_sigma_radps: float = 0.005  #: gyro white noise and scale error per sample [rad/s]
    #: curvature-model error of the database, counted once per gyro window [1/m] (R += (v sigma)^2);
    #: 1.5e-3 / sqrt(5) = 6.7e-4: the information of the per-sample value 1.5e-3 before the gyro window
    curvature_sigma_inv_m: float = 6.7e-4
    #: the rest of the curvature-model error comes from the geometry (docs/filter.md, "Curvature error"):
    #: sigma_k^2 = curvature_sigma^2 + (rel k)^2 + (registration dk/ds)^2, correlated along the track
    #: over curvature_corr_length_m, so that the gyro windows inside one correlation length share it
    #: (each window's R is inflated by the number of windows in that length) instead of each counting
    #: it as new information. Defaults: a digitised map smoothed with the import's 20 m Gaussian
    #: (track_db BuildConfig.smoothing_sigma_m): the onset of a curve is uncertain by about that
    #: sigma, the error is correlated over the kernel's width (2 sigma), and a short curve's peak is
    #: off by a quarter of its value (smoothing lowers it, an as-built path differs from the map).
    #: rel = registration = corr = 0 (the defaults here) is the model-matched form (the database is the
    #: true path); sfa.presets.datasheet_config_for sets the digitised-map values 0.25, 20 m and 40 m.
    curvature_rel_sigma: float = 0.0  #: curvature error as a fraction of the curvature [-]
    curvature_registration_m: float = 0.0  #: along-track uncertainty of the curvature profile [m]
    curvature_corr_length_m: float = 0.0  #: correlation length of the curvature error [m]
    #: compensate the body roll in curves (cant) before the gyro update: the roll angle comes from the
    #: accelerometer's lateral/vertical specific force against the expected (v^2 k(s), -g), and the yaw
    #: rate about the vertical is gy sin(roll) + gz cos(roll) (see docs/filter.md) [-]
    gyro_tilt_compensation: bool = True
    gyro_bias_rw_radps_rts: float = 2.0e-5  #: gyro bias random walk [rad/s/sqrt(s)]
    init_sigma_gyro_scale: float = 0.005  #: initial gyro scale-factor sigma (state SG) [fraction]
    #: gyro scale-factor random walk: lets SG follow what the roll compensation leaves of the cant from
    #: curve to curve [1/sqrt(s)]
    gyro_scale_rw_per_rts: float = 1.0e-4
    #: initial sigma of the yaw gyro's roll-rate coupling (state MX: the z gyro's tilt towards x, which
    #: makes it read MX times the roll rate while the cant ramps up or down in curve transitions) [rad]
    init_sigma_gyro_roll_coupling_rad: float = 0.0175
    init_sigma_gyro_bias_radps: float = 0.0175  #: initial gyro bias sigma [rad/s]
    gyro_min_speed_mps: float = 2.0  #: smallest speed for the gyro update [m/s]
    #: consecutive IMU samples whose gyro residuals are averaged into one gyro update (R = sigma^2 / n
    #: for the white noise; 1: an update per sample) [samples]
    gyro_average_samples: int = 5
    gyro_average_max_s: float = 0.1  #: longest time a gyro window spans; a longer one is applied as it is [s]
    #: learn how far the database's curvature is from the path's: the gyro windows' innovations estimate
    #: a scale (>= 1) of the curvature-model variance above (weighted least squares, with this memory
    #: in metres travelled; docs/filter.md); 0 keeps the scale at 1 (the model-matched form).
    #: sfa.presets.datasheet_config_for sets 200 m: five curvature correlation lengths
    gyro_curvature_adaptive_m: float = 0.0
    # --- odometer
    odo_scale_rw_per_rts: float = 1.0e-5  #: odometer scale-factor random walk [1/sqrt(s)]
    init_sigma_odo_scale: float = 0.01  #: initial odometer scale-factor sigma [fraction]
    odo_quant_mps: float = 0.01  #: odometer quantisation step [m/s]
    odo_sigma_min_mps: float = 0.005  #: floor applied to each sample's reported sigma [m/s]
    # --- GNSS
    gps_white_sigma_m: float = 0.5  #: white position noise per horizontal axis at nominal sigma_h [m]
    gps_gm_sigma_m: float = 1.0  #: correlated (Gauss-Markov) error per axis, steady sigma [m]
    gps_gm_tau_s: float = 30.0  #: Gauss-Markov correlation time [s]
    gps_nominal_sigma_h_m: float = 1.5  #: sigma_h the receiver reports in nominal conditions [m]
    track_lateral_sigma_m: float = 0.3  #: cross-track uncertainty of the digitised centre line [m]
    gps_late_max_s: float = 0.5  #: oldest GNSS fix still applied by back-propagation [s]
    #: memory of the adaptive GNSS error model: sigma_g, tau and sigma_w estimated from the fixes'
    #: cross-track residuals (sfa.gnss_noise); 0 keeps the three values above fixed [s]
    gps_adaptive_window_s: float = 0.0
    #: weight of the values above in those estimates, as seconds of data [s]
    gps_adaptive_prior_s: float = 30.0
    # --- gates (probability that a fault-free measurement passes)
    gate_prob_odo: float = 0.9999  #: odometer gate, chi-square 1 dof [probability]
    gate_prob_gps: float = 0.9999  #: GNSS gate, chi-square 2 dof [probability]
    gate_prob_gyro: float = 0.999  #: gyro gate, chi-square 1 dof [probability]
    gate_prob_zupt: float = 0.9999  #: zero-velocity gate, chi-square 1 dof [probability]
    # --- standstill / ZUPT
    zupt_sigma_mps: float = 0.005  #: zero-velocity pseudo-measurement sigma [m/s]
    still_speed_mps: float = 0.02  #: odometer |speed| below which standstill may be declared [m/s]
    still_fx_std_mps2: float = 0.02  #: IMU forward specific-force std below which standstill holds [m/s^2]
    fx_ewma_tau_s: float = 0.5  #: time constant of the standstill mean/variance estimator [s]
    # --- odometer slip / slide
    slip_confirm_n: int = 3  #: consecutive gated odometer samples that declare a slip [samples]
    slip_release_n: int = 10  #: consecutive in-gate samples that end it [samples]
    slip_max_s: float = 20.0  #: longest slip before the odometer is trusted again [s]
    #: a slip that outlasts slip_max_s is the accelerometer's fault, not the wheels': the speed is
    #: re-anchored on the odometer, this sigma is added to the accelerometer bias and the arc-length
    #: variance grows by the distance the odometer travelled beyond the estimate during the slip [m/s^2]
    slip_accel_bias_sigma_mps2: float = 0.2
    imu_fault_hold_s: float = 10.0  #: how long a declared accelerometer fault stays reported [s]
    #: GNSS arbitration of a declared slip: the fixes' log-likelihood ratio between "the accelerometer
    #: is faulty" (the train is where the odometer says, estimate + distance the odometer travelled
    #: beyond it) and "the odometer slips" (the IMU-bridged estimate). At +this value the accelerometer
    #: is declared faulty and the estimate moves to the odometer's position; at -this value the slip is
    #: confirmed. Until then the reported interval covers both positions (9.2 = 1e4:1) [-]
    slip_arbitration_log_ratio: float = 9.2
    #: consecutive bit-identical IMU samples (all six axes) that declare the IMU stuck; a real sensor's
    #: noise never repeats exactly. 0 disables (noise-free simulated IMUs repeat legitimately) [samples]
    imu_stuck_samples: int = 10
    slip_rewind: bool = True  #: on a declared slip, rewind ~1-2 s and re-propagate with the IMU alone
    snapshot_period_s: float = 1.0  #: period of the rewind snapshots [s]
    # --- GNSS step / ramp
    step_min_m: float = 5.0  #: smallest gated GNSS innovation classified as a step [m]
    cusum_k_sigma: float = 0.5  #: CUSUM drift allowance [sigma of the along-track innovation]
    cusum_h_sigma: float = 8.0  #: CUSUM decision threshold [sigma]
    #: k and h are per independent fix: fixes closer than this count as the fraction dt / this of one (a
    #: receiver's errors are correlated over about a second, so 10 Hz fixes are not 10x the evidence) [s]
    cusum_min_interval_s: float = 1.0
    gps_holdoff_s: float = 20.0  #: GNSS fixes ignored after a ramp detection [s]
    reacquire_s: float = 30.0  #: duration of self-consistent GNSS rejections that re-anchor the position [s]
    reacquire_consistency_m: float = 3.0  #: largest drift of the rejected along-track residual [m]
    # --- time-outs
    imu_timeout_s: float = 0.5  #: IMU silent longer than this: timed out [s]
    odo_timeout_s: float = 1.0  #: odometer silent longer than this: timed out [s]
    gps_timeout_s: float = 3.0  #: GNSS without an accepted fix longer than this: timed out [s]
    late_tolerance_s: float = 1e-6  #: IMU/odometer older than the state by more than this are dropped [s]
    max_time_jump_s: float = 10.0  #: a measurement further ahead of the state needs confirming [s]
    # --- interval and status
    confidence: float = 0.95  #: two-sided confidence of the arc-length interval [probability]
    #: while a sensor is declared faulty (GNSS step or ramp, odometer slip, accelerometer fault, IMU
    #: stuck) or missing (IMU, odometer or GNSS timeout) the reported sigma is multiplied by
    #: z(fault_confidence) / z(confidence), so the reported interval spans the filter's own
    #: fault_confidence interval: a fault is detected late and what it did before detection is not in
    #: the covariance, and without a sensor the filter rests on the models that sensor would check
    #: (dead reckoning, the gyro's map matching). Equal to confidence: no widening [probability]
    fault_confidence: float = 0.99
    degraded_sigma_m: float = 5.0  #: sigma_s above which the status is DEGRADED [m]
    lost_sigma_m: float = 100.0  #: sigma_s above which the status is LOST [m]
    min_variance: float = 1e-12  #: smallest variance kept on the covariance diagonal [unit^2]
    # --- initialisation (GROUND TRUTH)
    init_sigma_s_m: float = 0.1  #: arc-length sigma after GROUND TRUTH [m]
    init_sigma_v_mps: float = 0.05  #: speed sigma after GROUND TRUTH [m/s]
    # --- lines and junctions
    junction_window_m: float = 30.0  #: distance before a junction at which branch hypotheses are spawned [m]
    prune_log_ratio: float = 9.2  #: log-likelihood lead that prunes a hypothesis (9.2 = 1e4:1) [-]
    switch_log_ratio: float = 4.6  #: lead another hypothesis needs to become the reported one (100:1) [-]
    max_hypotheses: int = 6  #: most line / direction hypotheses kept at once [-]
    reversal_hypotheses: bool = True  #: at standstill also keep the reversed sense of travel
    #: prior log odds against the train reversing at a standstill once its sense of travel is known: the
    #: mirrored copy starts this far behind its source (4.6 = 1:100). With switch_log_ratio it must then
    #: gather 9.2 of evidence to be reported: a real reversal gives that within a GNSS fix or two, while
    #: gyro-vs-curvature evidence alone in a GNSS outage gave the wrong sense 5.6 (docs/filter.md)
    reversal_log_prior: float = 4.6
    loglik_nis_cap: float = 50.0  #: NIS cap in the hypothesis likelihood (robust to outliers) [NIS]
    # --- solution separation (sfa.separation; docs/filter.md, "Solution separation")
    #: life of each sub-filter (one aid left out) between re-anchorings to the reported hypothesis; two
    #: per aid, half a window apart (0: no sub-filters, no separation test) [s]
    separation_window_s: float = 0.0
    #: probability that a fault-free separation passes its chi-square test (1 dof) [-]
    separation_probability: float = 0.99999
    separation_hold_s: float = 30.0  #: how long a detected aid stays excluded and the interval widened [s]
    #: added in quadrature to the separation's sigma: what a fault-free filter and sub-filter differ by
    #: beyond their covariances (linearisation, the reset gyro window and rewind memory, rounding; with
    #: the 4.4-sigma gate, no separation below about 0.44 m is a detection) [m]
    separation_floor_m: float = 0.1

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.type in ("bool",) or isinstance(value, bool):
                if not isinstance(value, bool):
                    raise FilterConfigError(f"{f.name} must be a bool, got {value!r}")
                continue
            if not isinstance(value, int | float) or not math.isfinite(float(value)):
                raise FilterConfigError(f"{f.name} must be a finite number, got {value!r}")
            if f.name != "min_variance" and value < 0:
                raise FilterConfigError(f"{f.name} must be >= 0, got {value!r}")
        for name in ("gate_prob_odo", "gate_prob_gps", "gate_prob_gyro", "gate_prob_zupt", "confidence",
                     "fault_confidence", "separation_probability"):
            p = getattr(self, name)
            if not 0.0 < p < 1.0:
                raise FilterConfigError(f"{name} must be a probability in (0, 1), got {p!r}")
        for name in ("gps_gm_tau_s", "max_predict_dt_s", "fx_ewma_tau_s", "gps_white_sigma_m",
                     "gps_nominal_sigma_h_m", "min_variance", "zupt_sigma_mps", "init_sigma_s_m",
                     "init_sigma_v_mps"):
            if not getattr(self, name) > 0:
                raise FilterConfigError(f"{name} must be > 0, got {getattr(self, name)!r}")
        if self.gps_adaptive_window_s > 0 and not self.gps_adaptive_prior_s > 0:
            raise FilterConfigError(
                "gps_adaptive_prior_s must be > 0 when the GNSS model adapts, "
                f"got {self.gps_adaptive_prior_s!r}")
        if self.gyro_average_samples < 1 or self.gyro_average_samples != int(self.gyro_average_samples):
            raise FilterConfigError(
                f"gyro_average_samples must be an integer >= 1, got {self.gyro_average_samples!r}")
        if self.fault_confidence < self.confidence:
            raise FilterConfigError(
                f"fault_confidence ({self.fault_confidence!r}) must be >= confidence ({self.confidence!r})")
        if self.max_hypotheses < 1:
            raise FilterConfigError("max_hypotheses must be >= 1")
        if self.reversal_log_prior >= self.prune_log_ratio:
            raise FilterConfigError(
                f"reversal_log_prior ({self.reversal_log_prior!r}) must be < prune_log_ratio "
                f"({self.prune_log_ratio!r}): a mirrored copy further behind is pruned as it is made")

    def replace(self, **changes: object) -> FilterConfig:
        """A copy with some fields changed (validated)."""
        unknown = set(changes) - {f.name for f in fields(self)}
        if unknown:
            raise FilterConfigError(f"unknown FilterConfig field(s): {', '.join(sorted(unknown))}")
        return FilterConfig(**{**asdict(self), **changes})

    def gate_nis(self, probability: float, dof: int) -> float:
        """Chi-square threshold on the NIS that a fault-free measurement passes with ``probability``.

        ``scipy.stats.chi2.ppf(probability, dof)`` is ``2 * gammaincinv(dof / 2, probability)``: that
        function, called directly (the same bits; importing scipy.stats costs the listener about 0.9 s
        and 50 MB of start-up, docs/performance.md)."""
        from scipy.special import gammaincinv

        return float(2 * gammaincinv(dof / 2, probability))

    def interval_z(self, confidence: float | None = None) -> float:
        """Two-sided standard-normal quantile of ``confidence`` (default: the config's; 1.96 for 95 %)."""
        from scipy.special import ndtri  # what scipy.stats.norm.ppf computes (see gate_nis)

        p = self.confidence if confidence is None else confidence
        return float(ndtri(0.5 + 0.5 * p))

    def to_array(self):
        """The flat float64 vector the compiled kernels read (slots named in ``sfa.layout``)."""
        import numpy as np

        from sfa import layout as L

        c = np.zeros(L.NCFG)
        c[L.K_Q_ACC] = self.accel_noise_density_mps2_rthz ** 2 + self.accel_model_noise_mps2_rthz ** 2
        c[L.K_Q_BA] = self.accel_bias_rw_mps2_rts ** 2
        c[L.K_Q_KO] = self.odo_scale_rw_per_rts ** 2
        c[L.K_GM_SIGMA] = self.gps_gm_sigma_m
        c[L.K_GM_TAU] = self.gps_gm_tau_s
        c[L.K_Q_BG] = self.gyro_bias_rw_radps_rts ** 2
        c[L.K_GPS_WHITE] = self.gps_white_sigma_m
        c[L.K_GPS_NOMINAL_SIGMA_H] = self.gps_nominal_sigma_h_m
        c[L.K_TRACK_LAT] = self.track_lateral_sigma_m
        c[L.K_ODO_QUANT] = self.odo_quant_mps
        c[L.K_ODO_SIGMA_MIN] = self.odo_sigma_min_mps
        c[L.K_GATE_ODO] = self.gate_nis(self.gate_prob_odo, 1)
        c[L.K_GATE_GPS] = self.gate_nis(self.gate_prob_gps, 2)
        c[L.K_GATE_GYRO] = self.gate_nis(self.gate_prob_gyro, 1)
        c[L.K_GATE_ZUPT] = self.gate_nis(self.gate_prob_zupt, 1)
        c[L.K_GRAVITY] = self.gravity_mps2
        c[L.K_MAX_DT] = self.max_predict_dt_s
        c[L.K_IMU_TIMEOUT] = self.imu_timeout_s
        c[L.K_ODO_TIMEOUT] = self.odo_timeout_s
        c[L.K_GPS_TIMEOUT] = self.gps_timeout_s
        c[L.K_Q_NO_IMU] = self.no_imu_accel_psd_m2ps3
        c[L.K_ZUPT_SIGMA] = self.zupt_sigma_mps
        c[L.K_STILL_SPEED] = self.still_speed_mps
        c[L.K_STILL_FX_STD] = self.still_fx_std_mps2
        c[L.K_FX_EWMA_TAU] = self.fx_ewma_tau_s
        c[L.K_SLIP_CONFIRM_N] = self.slip_confirm_n
        c[L.K_SLIP_RELEASE_N] = self.slip_release_n
        c[L.K_SLIP_MAX_S] = self.slip_max_s
        c[L.K_STEP_MIN_M] = self.step_min_m
        c[L.K_CUSUM_K] = self.cusum_k_sigma
        c[L.K_CUSUM_H] = self.cusum_h_sigma
        c[L.K_CUSUM_DT] = self.cusum_min_interval_s
        c[L.K_GPS_HOLDOFF_S] = self.gps_holdoff_s
        c[L.K_REACQ_S] = self.reacquire_s
        c[L.K_REACQ_CONSIST_M] = self.reacquire_consistency_m
        c[L.K_GPS_LATE_MAX] = self.gps_late_max_s
        c[L.K_USE_GYRO] = 1.0 if self.use_gyro else 0.0
        c[L.K_GYRO_SIGMA] = self.gyro_sigma_radps
        c[L.K_GYRO_MIN_SPEED] = self.gyro_min_speed_mps
        c[L.K_Z_INTERVAL] = self.interval_z()
        c[L.K_FAULT_SIGMA_SCALE] = self.interval_z(self.fault_confidence) / self.interval_z()
        c[L.K_DEGRADED_SIGMA] = self.degraded_sigma_m
        c[L.K_LOST_SIGMA] = self.lost_sigma_m
        c[L.K_P_MIN_VAR] = self.min_variance
        c[L.K_INIT_SIGMA_S] = self.init_sigma_s_m
        c[L.K_INIT_SIGMA_V] = self.init_sigma_v_mps
        c[L.K_INIT_SIGMA_BA] = self.init_sigma_accel_bias_mps2
        c[L.K_INIT_SIGMA_KO] = self.init_sigma_odo_scale
        c[L.K_INIT_SIGMA_BG] = self.init_sigma_gyro_bias_radps
        c[L.K_LATE_TOL] = self.late_tolerance_s
        c[L.K_GPS_MAX_LOGLIK_NIS] = self.loglik_nis_cap
        c[L.K_JUNCTION_WINDOW] = self.junction_window_m
        c[L.K_PRUNE_LOG_RATIO] = self.prune_log_ratio
        c[L.K_SWITCH_LOG_RATIO] = self.switch_log_ratio
        c[L.K_MAX_HYPOTHESES] = self.max_hypotheses
        c[L.K_REVERSAL] = 1.0 if self.reversal_hypotheses else 0.0
        c[L.K_REVERSAL_PRIOR] = self.reversal_log_prior
        c[L.K_MAX_TIME_JUMP] = self.max_time_jump_s
        c[L.K_SNAP_PERIOD] = self.snapshot_period_s if self.slip_rewind else -1.0
        c[L.K_INIT_SIGMA_MY] = self.init_sigma_yaw_misalignment_rad
        c[L.K_INIT_SIGMA_SF] = self.init_sigma_accel_scale
        c[L.K_CURV_SIGMA] = self.curvature_sigma_inv_m
        c[L.K_CURV_REL] = self.curvature_rel_sigma
        c[L.K_CURV_REG_M] = self.curvature_registration_m
        c[L.K_CURV_CORR_M] = self.curvature_corr_length_m
        c[L.K_Q_REG] = self.registration_psd_m2pm
        c[L.K_AD_WINDOW] = self.gps_adaptive_window_s
        c[L.K_AD_PRIOR] = self.gps_adaptive_prior_s
        c[L.K_GYRO_TILT] = 1.0 if self.gyro_tilt_compensation else 0.0
        c[L.K_INIT_SIGMA_SG] = self.init_sigma_gyro_scale
        c[L.K_Q_SG] = self.gyro_scale_rw_per_rts ** 2
        c[L.K_INIT_SIGMA_MX] = self.init_sigma_gyro_roll_coupling_rad
        c[L.K_GYRO_AVG_N] = self.gyro_average_samples
        c[L.K_GYRO_AVG_MAX_S] = self.gyro_average_max_s
        c[L.K_GYRO_AD_M] = self.gyro_curvature_adaptive_m
        c[L.K_IMU_STUCK_N] = self.imu_stuck_samples
        c[L.K_SLIP_BA_SIGMA] = self.slip_accel_bias_sigma_mps2
        c[L.K_IMU_FAULT_HOLD] = self.imu_fault_hold_s
        c[L.K_SLIP_ARB_LLR] = self.slip_arbitration_log_ratio
        c[L.K_SEP_WINDOW] = self.separation_window_s
        c[L.K_SEP_GATE] = self.gate_nis(self.separation_probability, 1)
        c[L.K_SEP_HOLD] = self.separation_hold_s
        c[L.K_SEP_FLOOR_VAR] = self.separation_floor_m ** 2
        return c
