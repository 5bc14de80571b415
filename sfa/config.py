"""Typed configuration of the SFA filter: every noise parameter with its unit.

Gates are given as probabilities (the probability that a fault-free measurement passes); they are
turned into chi-square thresholds on the normalised innovation squared (NIS, dimensionless) with the
measurement's degrees of freedom: odometer, gyro and ZUPT 1, GNSS 2.

The compiled kernels read the configuration as a flat float64 vector (``FilterConfig.to_array``),
by slot name (``sfa.layout.K_*``). Each field that reaches them declares its slot here, with
:func:`slot`: the slot's name and, where the kernels read something other than the field itself, how
it is computed from the configuration (and what it is, with its unit). ``sfa.layout`` numbers the
slots in the order they are declared (:data:`CFG_SLOTS`), so a new parameter is one field below with
its ``slot(...)`` and its ``#:`` documentation; the kernels then read it as ``cfg[K_<NAME>]``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from typing import Any

from sfa.errors import FilterConfigError


def slot(default: Any, name: str, value: Callable[[Any], float] | None = None, doc: str = "") -> Any:
    """A :class:`FilterConfig` field that reaches the kernels: its ``default``, and the configuration
    slot ``name`` (``K_*`` in ``sfa.layout``) that ``to_array`` fills with ``value(config)``, or with
    the field itself when ``value`` is None (as a float: a bool is 1.0 or 0.0, an int exact).
    ``doc``: what the slot holds and its unit, where that is not the field itself. A slot computed
    from several fields is declared by one of them, with a ``value`` that reads the others."""
    return field(default=default, metadata={"slot": name, "value": value, "doc": doc})


@dataclass(frozen=True)
class FilterConfig:
    """Noise model, integrity thresholds and policies of ``TrackFilter``. Defaults: mems-train IMU,
    wheel odometer, standalone GNSS (see ``sfa.presets.filter_config_for``)."""

    # --- IMU (prediction)
    #: accelerometer white noise [m/s^2/sqrt(Hz)]
    accel_noise_density_mps2_rthz: float = slot(
        5.88e-4, "K_Q_ACC",
        lambda c: c.accel_noise_density_mps2_rthz ** 2 + c.accel_model_noise_mps2_rthz ** 2,
        doc="accelerometer white noise PSD incl. model noise [m^2/s^3]")
    #: unmodelled acceleration (in K_Q_ACC with the white noise above) [m/s^2/sqrt(Hz)]
    accel_model_noise_mps2_rthz: float = 0.05
    #: accelerometer bias random walk [m/s^2/sqrt(s)]
    accel_bias_rw_mps2_rts: float = slot(2.0e-4, "K_Q_BA", lambda c: c.accel_bias_rw_mps2_rts ** 2,
                                         doc="accelerometer bias random walk PSD [m^2/s^5]")
    #: initial bias sigma incl. pitch misalignment [m/s^2]
    init_sigma_accel_bias_mps2: float = slot(0.088, "K_INIT_SIGMA_BA")
    #: initial IMU yaw misalignment sigma [rad]
    init_sigma_yaw_misalignment_rad: float = slot(0.0087, "K_INIT_SIGMA_MY")
    #: initial accelerometer scale-factor sigma [-]
    init_sigma_accel_scale: float = slot(0.002, "K_INIT_SIGMA_SF")
    #: acceleration PSD while the IMU is timed out [m^2/s^3]
    no_imu_accel_psd_m2ps3: float = slot(0.5, "K_Q_NO_IMU")
    gravity_mps2: float = slot(9.80665, "K_GRAVITY")  #: gravity [m/s^2]
    max_predict_dt_s: float = slot(0.1, "K_MAX_DT")  #: longest single prediction step [s]
    #: map registration: the database's arc length is the digitised polyline's, not the distance the
    #: train travels on the track as built (corners cut or not, vertices off the track), so the two
    #: drift apart by a random walk in the distance travelled: Q[S,S] += this |v| h. 1e-3 m^2/m is a
    #: 0.5 % length error correlated over 50 m ((0.005 * 50)^2 / 50 = 1.25e-3, the value of
    #: sfa.presets.datasheet_config_for); 0 (the default here): model-matched [m^2/m]
    registration_psd_m2pm: float = slot(0.0, "K_Q_REG")
    # --- gyro (optional update gz = v * curvature(s) + b_g)
    #: apply the gyro update gz = v curvature(s) + b_g (see docs/filter.md)
    use_gyro: bool = slot(True, "K_USE_GYRO")
    #: gyro white noise and scale error per sample [rad/s]
    gyro_sigma_radps: float = slot(0.005, "K_GYRO_SIGMA")
    #: curvature-model error of the database, counted once per gyro window [1/m] (R += (v sigma)^2);
    #: 1.5e-3 / sqrt(5) = 6.7e-4: the information of the per-sample value 1.5e-3 before the gyro window
    curvature_sigma_inv_m: float = slot(6.7e-4, "K_CURV_SIGMA")
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
    #: curvature error as a fraction of the curvature [-]
    curvature_rel_sigma: float = slot(0.0, "K_CURV_REL")
    #: along-track uncertainty of the curvature profile [m]
    curvature_registration_m: float = slot(0.0, "K_CURV_REG_M")
    #: correlation length of the curvature error [m]
    curvature_corr_length_m: float = slot(0.0, "K_CURV_CORR_M")
    #: compensate the body roll in curves (cant) before the gyro update: the roll angle comes from the
    #: accelerometer's lateral/vertical specific force against the expected (v^2 k(s), -g), and the yaw
    #: rate about the vertical is gy sin(roll) + gz cos(roll) (see docs/filter.md) [-]
    gyro_tilt_compensation: bool = slot(True, "K_GYRO_TILT")
    #: gyro bias random walk [rad/s/sqrt(s)]
    gyro_bias_rw_radps_rts: float = slot(2.0e-5, "K_Q_BG", lambda c: c.gyro_bias_rw_radps_rts ** 2,
                                         doc="gyro bias random walk PSD [rad^2/s^3]")
    #: initial gyro scale-factor sigma (state SG) [fraction]
    init_sigma_gyro_scale: float = slot(0.005, "K_INIT_SIGMA_SG")
    #: gyro scale-factor random walk: lets SG follow what the roll compensation leaves of the cant from
    #: curve to curve [1/sqrt(s)]
    gyro_scale_rw_per_rts: float = slot(1.0e-4, "K_Q_SG", lambda c: c.gyro_scale_rw_per_rts ** 2,
                                        doc="gyro scale-factor random walk PSD [1/s]")
    #: initial sigma of the yaw gyro's roll-rate coupling (state MX: the z gyro's tilt towards x, which
    #: makes it read MX times the roll rate while the cant ramps up or down in curve transitions) [rad]
    init_sigma_gyro_roll_coupling_rad: float = slot(0.0175, "K_INIT_SIGMA_MX")
    init_sigma_gyro_bias_radps: float = slot(0.0175, "K_INIT_SIGMA_BG")  #: initial gyro bias sigma [rad/s]
    gyro_min_speed_mps: float = slot(2.0, "K_GYRO_MIN_SPEED")  #: smallest speed for the gyro update [m/s]
    #: consecutive IMU samples whose gyro residuals are averaged into one gyro update (R = sigma^2 / n
    #: for the white noise; 1: an update per sample) [samples]
    gyro_average_samples: int = slot(5, "K_GYRO_AVG_N")
    #: longest time a gyro window spans; a longer one is applied as it is [s]
    gyro_average_max_s: float = slot(0.1, "K_GYRO_AVG_MAX_S")
    #: learn how far the database's curvature is from the path's: the gyro windows' innovations estimate
    #: a scale (>= 1) of the curvature-model variance above (weighted least squares, with this memory
    #: in metres travelled; docs/filter.md); 0 keeps the scale at 1 (the model-matched form).
    #: sfa.presets.datasheet_config_for sets 200 m: five curvature correlation lengths
    gyro_curvature_adaptive_m: float = slot(0.0, "K_GYRO_AD_M")
    #: learn two scales (sfa.kernels.gyro_window_update): one of the floor s0 and one of the curve terms
    #: (r k, l dk/ds), each by the same least squares, instead of one for the whole variance. An
    #: as-built path's lateral offsets raise the floor (its scale 10-37 on long-outage seed 162); one
    #: scale then multiplied a curve's terms by as much (their own scale stays 1 there), and a mirrored
    #: hypothesis on a curve explained the residual by them (docs/filter.md, "Session 30")
    gyro_two_scales: bool = slot(True, "K_GYRO_TWO_SCALES")
    # --- odometer
    #: odometer scale-factor random walk [1/sqrt(s)]
    odo_scale_rw_per_rts: float = slot(1.0e-5, "K_Q_KO", lambda c: c.odo_scale_rw_per_rts ** 2,
                                       doc="odometer scale random walk PSD [1/s]")
    #: initial odometer scale-factor sigma [fraction]
    init_sigma_odo_scale: float = slot(0.01, "K_INIT_SIGMA_KO")
    odo_quant_mps: float = slot(0.01, "K_ODO_QUANT")  #: odometer quantisation step [m/s]
    #: floor applied to each sample's reported sigma [m/s]
    odo_sigma_min_mps: float = slot(0.005, "K_ODO_SIGMA_MIN")
    # --- GNSS
    #: white position noise per horizontal axis at nominal sigma_h [m]
    gps_white_sigma_m: float = slot(0.5, "K_GPS_WHITE")
    #: correlated (Gauss-Markov) error per axis, steady sigma [m]
    gps_gm_sigma_m: float = slot(1.0, "K_GM_SIGMA")
    gps_gm_tau_s: float = slot(30.0, "K_GM_TAU")  #: Gauss-Markov correlation time [s]
    #: sigma_h the receiver reports in nominal conditions [m]
    gps_nominal_sigma_h_m: float = slot(1.5, "K_GPS_NOMINAL_SIGMA_H")
    #: cross-track uncertainty of the digitised centre line [m]
    track_lateral_sigma_m: float = slot(0.3, "K_TRACK_LAT")
    #: correlation length of that lateral error along the track: the fixes inside one length share one
    #: draw of it, so each fix's lateral term is multiplied by n_c = L / (|v| dt) (>= 1; dt since the
    #: last fix in use) instead of counting it as new information n_c times, as the gyro windows'
    #: curvature term (curvature_corr_length_m). 0 (the default here): independent per fix [m]
    track_lateral_corr_length_m: float = slot(0.0, "K_TRACK_LAT_CORR_M")
    #: oldest GNSS fix still applied by back-propagation [s]
    gps_late_max_s: float = slot(0.5, "K_GPS_LATE_MAX")
    #: memory of the adaptive GNSS error model: sigma_g, tau and sigma_w estimated from the fixes'
    #: cross-track residuals (sfa.gnss_noise); 0 keeps the three values above fixed [s]
    gps_adaptive_window_s: float = slot(0.0, "K_AD_WINDOW")
    #: weight of the values above in those estimates, as seconds of data [s]
    gps_adaptive_prior_s: float = slot(30.0, "K_AD_PRIOR")
    #: longest correlation time the adaptive model may fit (the top of its logarithmic grid from
    #: sfa.layout.AD_TAU_MIN_S). An ablation knob: a lower top (20 s) was better on the generalisation
    #: benchmark's seeds 0-7 and refuted on seeds 8-19 (docs/filter.md, session 14), so every preset
    #: keeps 1000 s [s]
    gps_adaptive_tau_max_s: float = slot(1000.0, "K_AD_TAU_MAX")
    #: the GNSS error fit also takes the residuals' structure function at a standstill, E[(c(t) -
    #: c(t - L))^2] / 2 = sigma_w^2 + sigma_g^2 (1 - exp(-L / tau)) over pairs both at one stop, where the
    #: map's lateral offset is the same and cancels (gnss_noise.fit). The product moments need pairs 25 m
    #: apart, which a tram below 12.5 m/s never gives at the 2 s lag: that lag kept its prior for the whole
    #: run, and the fitted sigma_g was about twice the receiver's. Off in both preset families: on held-out
    #: worlds it lowers p95 by at most 2 % and widens the interval, most families above 98 % coverage
    #: (docs/filter.md, "Session 31")
    gps_fit_standstill: bool = slot(False, "K_AD_STILL")
    #: estimate the GNSS error model by maximum likelihood instead of the lag moments' least squares: a
    #: bank of scalar Kalman filters of the cross-track residual, one per (tau, white share) of a grid
    #: (sfa.gnss_noise.ml_update), the scale profiled out, each with the memory gps_adaptive_window_s and
    #: the preset's expected statistics as its prior. On in the datasheet presets since session 35 (off
    #: here, so a FilterConfig built by hand keeps the moment fit): better on both held-out seed sets, on
    #: Dresden and the campaign's ramp, level on smartLoc's real GNSS judged from many start times
    #: (docs/filter.md, "Session 34" and "Session 35")
    gps_adaptive_ml: bool = slot(False, "K_AD_ML")
    # --- gates (probability that a fault-free measurement passes)
    #: odometer gate, chi-square 1 dof [probability]
    gate_prob_odo: float = slot(0.9999, "K_GATE_ODO", lambda c: c.gate_nis(c.gate_prob_odo, 1),
                                doc="chi-square gate, 1 dof [NIS]")
    #: GNSS gate, chi-square 2 dof [probability]
    gate_prob_gps: float = slot(0.9999, "K_GATE_GPS", lambda c: c.gate_nis(c.gate_prob_gps, 2),
                                doc="chi-square gate, 2 dof [NIS]")
    #: gyro gate, chi-square 1 dof [probability]
    gate_prob_gyro: float = slot(0.999, "K_GATE_GYRO", lambda c: c.gate_nis(c.gate_prob_gyro, 1),
                                 doc="chi-square gate, 1 dof [NIS]")
    #: zero-velocity gate, chi-square 1 dof [probability]
    gate_prob_zupt: float = slot(0.9999, "K_GATE_ZUPT", lambda c: c.gate_nis(c.gate_prob_zupt, 1),
                                 doc="chi-square gate, 1 dof [NIS]")
    # --- standstill / ZUPT
    zupt_sigma_mps: float = slot(0.005, "K_ZUPT_SIGMA")  #: zero-velocity pseudo-measurement sigma [m/s]
    #: odometer |speed| below which standstill may be declared [m/s]
    still_speed_mps: float = slot(0.02, "K_STILL_SPEED")
    #: IMU forward specific-force std below which standstill holds [m/s^2]
    still_fx_std_mps2: float = slot(0.02, "K_STILL_FX_STD")
    #: time constant of the standstill mean/variance estimator [s]
    fx_ewma_tau_s: float = slot(0.5, "K_FX_EWMA_TAU")
    # --- odometer slip / slide
    #: consecutive gated odometer samples that declare a slip [samples]
    slip_confirm_n: int = slot(3, "K_SLIP_CONFIRM_N")
    slip_release_n: int = slot(10, "K_SLIP_RELEASE_N")  #: consecutive in-gate samples that end it [samples]
    slip_max_s: float = slot(20.0, "K_SLIP_MAX_S")  #: longest slip before the odometer is trusted again [s]
    #: a slip that outlasts slip_max_s is the accelerometer's fault, not the wheels': the speed is
    #: re-anchored on the odometer, this sigma is added to the accelerometer bias and the arc-length
    #: variance grows by the distance the odometer travelled beyond the estimate during the slip [m/s^2]
    slip_accel_bias_sigma_mps2: float = slot(0.2, "K_SLIP_BA_SIGMA")
    #: how long a declared accelerometer fault stays reported [s]
    imu_fault_hold_s: float = slot(10.0, "K_IMU_FAULT_HOLD")
    #: GNSS arbitration of a declared slip: the fixes' log-likelihood ratio between "the accelerometer
    #: is faulty" (the train is where the odometer says, estimate + distance the odometer travelled
    #: beyond it) and "the odometer slips" (the IMU-bridged estimate). At +this value the accelerometer
    #: is declared faulty and the estimate moves to the odometer's position; at -this value the slip is
    #: confirmed. Until then the reported interval covers both positions (9.2 = 1e4:1) [-]
    slip_arbitration_log_ratio: float = slot(9.2, "K_SLIP_ARB_LLR")
    #: consecutive bit-identical IMU samples (all six axes) that declare the IMU stuck; a real sensor's
    #: noise never repeats exactly. 0 disables (noise-free simulated IMUs repeat legitimately) [samples]
    imu_stuck_samples: int = slot(10, "K_IMU_STUCK_N")
    #: on a declared slip, rewind ~1-2 s and re-propagate with the IMU alone (off: K_SNAP_PERIOD is -1)
    slip_rewind: bool = True
    #: period of the rewind snapshots [s]
    snapshot_period_s: float = slot(
        1.0, "K_SNAP_PERIOD", lambda c: c.snapshot_period_s if c.slip_rewind else -1.0,
        doc="period of the rewind snapshots, -1 when slip_rewind is off [s]")
    # --- GNSS step / ramp
    step_min_m: float = slot(5.0, "K_STEP_MIN_M")  #: smallest gated GNSS innovation classified as a step [m]
    #: CUSUM drift allowance [sigma of the along-track innovation]
    cusum_k_sigma: float = slot(0.5, "K_CUSUM_K")
    cusum_h_sigma: float = slot(8.0, "K_CUSUM_H")  #: CUSUM decision threshold [sigma]
    #: k and h are per independent fix: fixes closer than this count as the fraction dt / this of one (a
    #: receiver's errors are correlated over about a second, so 10 Hz fixes are not 10x the evidence);
    #: the line hypotheses' GNSS score weights fixes the same way (sfa.kernels.gps_evidence_weight) [s]
    cusum_min_interval_s: float = slot(1.0, "K_CUSUM_DT")
    gps_holdoff_s: float = slot(20.0, "K_GPS_HOLDOFF_S")  #: GNSS fixes ignored after a ramp detection [s]
    #: duration of self-consistent GNSS rejections that re-anchor the position [s]
    reacquire_s: float = slot(30.0, "K_REACQ_S")
    #: largest drift of the rejected along-track residual [m]
    reacquire_consistency_m: float = slot(3.0, "K_REACQ_CONSIST_M")
    #: when such a run does not agree along the line (the estimate may be on the wrong line), add a
    #: hypothesis on every line the run's fixes move along as the train did (within the GNSS gate, and
    #: reacquire_consistency_m), and let the GNSS score choose (TrackFilter._relocalise)
    relocalise: bool = slot(True, "K_RELOC")
    # --- time-outs
    imu_timeout_s: float = slot(0.5, "K_IMU_TIMEOUT")  #: IMU silent longer than this: timed out [s]
    odo_timeout_s: float = slot(1.0, "K_ODO_TIMEOUT")  #: odometer silent longer than this: timed out [s]
    #: GNSS without an accepted fix longer than this: timed out [s]
    gps_timeout_s: float = slot(3.0, "K_GPS_TIMEOUT")
    #: IMU/odometer older than the state by more than this are dropped [s]
    late_tolerance_s: float = slot(1e-6, "K_LATE_TOL")
    #: a measurement further ahead of the state needs confirming [s]
    max_time_jump_s: float = slot(10.0, "K_MAX_TIME_JUMP")
    # --- interval and status
    #: two-sided confidence of the arc-length interval [probability]
    confidence: float = slot(0.95, "K_Z_INTERVAL", lambda c: c.interval_z(),
                             doc="two-sided normal quantile of the confidence interval [-]")
    #: while a sensor is declared faulty (GNSS step or ramp, odometer slip, accelerometer fault, IMU
    #: stuck) or missing (IMU, odometer or GNSS timeout) the reported sigma is multiplied by
    #: z(fault_confidence) / z(confidence), so the reported interval spans the filter's own
    #: fault_confidence interval: a fault is detected late and what it did before detection is not in
    #: the covariance, and without a sensor the filter rests on the models that sensor would check
    #: (dead reckoning, the gyro's map matching). Equal to confidence: no widening [probability]
    fault_confidence: float = slot(
        0.99, "K_FAULT_SIGMA_SCALE", lambda c: c.interval_z(c.fault_confidence) / c.interval_z(),
        doc="factor on the reported sigma while a sensor is faulty or missing [-]")
    degraded_sigma_m: float = slot(5.0, "K_DEGRADED_SIGMA")  #: sigma_s above which the status is DEGRADED [m]
    lost_sigma_m: float = slot(100.0, "K_LOST_SIGMA")  #: sigma_s above which the status is LOST [m]
    #: smallest variance kept on the covariance diagonal [unit^2]
    min_variance: float = slot(1e-12, "K_P_MIN_VAR")
    # --- initialisation (GROUND TRUTH)
    init_sigma_s_m: float = slot(0.1, "K_INIT_SIGMA_S")  #: arc-length sigma after GROUND TRUTH [m]
    init_sigma_v_mps: float = slot(0.05, "K_INIT_SIGMA_V")  #: speed sigma after GROUND TRUTH [m/s]
    # --- lines and junctions
    #: distance before a junction at which branch hypotheses are spawned [m]
    junction_window_m: float = slot(30.0, "K_JUNCTION_WINDOW")
    #: log-likelihood lead that prunes a hypothesis (9.2 = 1e4:1) [-]
    prune_log_ratio: float = slot(9.2, "K_PRUNE_LOG_RATIO")
    #: lead another hypothesis needs to become the reported one (100:1) [-]
    switch_log_ratio: float = slot(4.6, "K_SWITCH_LOG_RATIO")
    max_hypotheses: int = slot(6, "K_MAX_HYPOTHESES")  #: most line / direction hypotheses kept at once [-]
    #: at standstill also keep the reversed sense of travel
    reversal_hypotheses: bool = slot(True, "K_REVERSAL")
    #: prior log odds against the train reversing at a standstill once its sense of travel is known: the
    #: mirrored copy starts this far behind its source (4.6 = 1:100). With switch_log_ratio it must then
    #: gather 9.2 of evidence to be reported: a real reversal gives that within a GNSS fix or two, while
    #: gyro-vs-curvature evidence alone in a GNSS outage gave the wrong sense 5.6 (docs/filter.md)
    reversal_log_prior: float = slot(4.6, "K_REVERSAL_PRIOR")
    #: NIS cap in the hypothesis likelihood (robust to outliers) [NIS]
    loglik_nis_cap: float = slot(50.0, "K_GPS_MAX_LOGLIK_NIS")
    #: score a fix against the line hypotheses by the Student-t of its 2-d NIS when the GNSS model is
    #: learned (gps_adaptive_window_s > 0): -(dof + 2) / 2 log(1 + NIS / dof), dof the learned
    #: variance's own (seconds of data / tau, sfa.gnss_noise.score_dof), instead of -NIS / 2. With R's
    #: scale an estimate, the fix's likelihood is a t, not a normal: one fix of urban-gnss seed 185 at
    #: a NIS of 12.3 (a 1.7-sigma error of the world, 3.5 of the model) moved the normal score by 6.1
    #: and reported the wrong sense of travel, 6.8 m off (docs/filter.md, "Session 27"). A known
    #: model (no adaptation) keeps the normal
    gps_score_student_t: bool = slot(True, "K_GPS_SCORE_T")
    #: score a gyro window against the line hypotheses by the normal's log-density, -(NIS + log S) / 2,
    #: its log S weighted by the window's share of an independent measurement (sfa.bank.score_log_s),
    #: instead of -NIS / 2. The curvature error, so S, depends on where a hypothesis is: scored by its
    #: NIS alone, a mirrored hypothesis along a curve of the database gained on the true one on a
    #: straight whatever the residual, and ran the estimate backwards in 16 of 140 long-outage seeds
    #: without the reversal prior, in 1 with log S (docs/filter.md, "Session 30")
    gyro_score_log_det: bool = slot(True, "K_GYRO_LOGDET")
    #: the line hypotheses' odometer score counts samples closer than this as the fraction dt / this of
    #: one independent sample, as cusum_min_interval_s does for fixes: a hypothesis's speed error at a
    #: departure persists for seconds, so 20 Hz samples are not 20x the evidence (urban-gnss seed 23's
    #: right sense of travel pruned in 0.5 s; docs/filter.md). 0: every sample in full [s]
    odo_evidence_interval_s: float = slot(1.0, "K_ODO_EVIDENCE_DT")
    # --- solution separation (sfa.separation; docs/filter.md, "Solution separation")
    #: life of each sub-filter (one aid left out) between re-anchorings to the reported hypothesis; two
    #: per aid, half a window apart (0: no sub-filters, no separation test) [s]
    separation_window_s: float = slot(0.0, "K_SEP_WINDOW")
    #: probability that a fault-free separation passes its chi-square test (1 dof) [-]
    separation_probability: float = slot(
        0.99999, "K_SEP_GATE", lambda c: c.gate_nis(c.separation_probability, 1),
        doc="chi-square gate on (main - sub)^2 / (P_sub - P_main), 1 dof [NIS]")
    #: how long a detected aid stays excluded and the interval widened [s]
    separation_hold_s: float = slot(30.0, "K_SEP_HOLD")
    #: added in quadrature to the separation's sigma: what a fault-free filter and sub-filter differ by
    #: beyond their covariances (linearisation, the reset gyro window and rewind memory, rounding; with
    #: the 4.4-sigma gate, no separation below about 0.44 m is a detection) [m]
    separation_floor_m: float = slot(
        0.1, "K_SEP_FLOOR_VAR", lambda c: c.separation_floor_m ** 2,
        doc="variance added to sigma_ss^2: separations no covariance carries [m^2]")

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
        from sfa.layout import AD_TAU_MIN_S  # (sfa.layout imports this module: not at the top)

        if not self.gps_adaptive_tau_max_s > AD_TAU_MIN_S:
            raise FilterConfigError(
                f"gps_adaptive_tau_max_s must be > {AD_TAU_MIN_S} s (the start of the correlation-time "
                f"grid), got {self.gps_adaptive_tau_max_s!r}")
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
        """The flat float64 vector the compiled kernels read: in slot ``sfa.layout.K_*`` the value that
        field's :func:`slot` declares (:data:`CFG_SLOTS` gives the order)."""
        import numpy as np

        return np.array([float(getattr(self, name)) if value is None else value(self)
                         for name, value in _SLOT_VALUES], dtype=np.float64)


def _declared_slots(cls: type) -> tuple[tuple[str, str, Callable[[Any], float] | None], ...]:
    """(slot name, field name, value) of every field of ``cls`` with a :func:`slot`, in declaration
    order; a slot declared twice, or not named ``K_<UPPER>``, is an error at import."""
    out = tuple((f.metadata["slot"], f.name, f.metadata["value"])
                for f in fields(cls) if "slot" in f.metadata)
    names = [s for s, _, _ in out]
    bad = [s for s in names if not (s.startswith("K_") and s.isidentifier() and s.isupper())]
    dup = sorted({s for s in names if names.count(s) > 1})
    if bad or dup:
        raise RuntimeError(f"FilterConfig slots: not K_<UPPER> {bad}, declared twice {dup}")
    return out


_SLOTS = _declared_slots(FilterConfig)
_SLOT_VALUES = tuple((name, value) for _, name, value in _SLOTS)
#: the configuration vector's slot names in order: ``sfa.layout`` defines ``K_<NAME> = index`` for each
#: and ``NCFG = len(CFG_SLOTS)``
CFG_SLOTS: tuple[str, ...] = tuple(s for s, _, _ in _SLOTS)
