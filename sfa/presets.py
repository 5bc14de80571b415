"""Filter configurations matching the simulator's sensor presets.

Built from the very objects the simulator draws its errors from (``interface_modules.presets``), so a
scenario's sensors and the filter tuned for them cannot drift apart.
"""

from __future__ import annotations

import math

from sfa.config import FilterConfig
from sfa.errors import FilterConfigError

#: curvature-model error for simulated data whose yaw rate follows the database's own smoothed
#: curvature (what remains is the filter's 4 m linear resampling of it) [1/m]. Tracks digitised from
#: maps need more: the FilterConfig default is 1.5e-3 1/m. Before the gyro model had the cant (roll
#: compensation), the gyro scale (SG) and the roll-rate coupling (MX), this value had to stand in for
#: all three and no single value fitted both tram and regional runs (docs/filter.md, Results).
#: 8e-5 when the gyro updated at every IMU sample with this error counted as white; the gyro window
#: (5 samples) counts it once per window, as the correlated error it is: 8e-5 / sqrt(5) keeps the
#: information per 50 ms the same (measured: with 8e-5 unchanged, 6 seeds of tram-urban went from
#: 95.3 % to 97.6 % coverage, regional-tunnel from 97.7 to 99.2 %).
CURVATURE_MODEL_INV_M = 3.6e-5

#: arc-length sigma of GROUND TRUTH [m]. The simulator's control module sends the truth itself (float64)
#: and the real-data adapters the reference trajectory projected onto the line (cm class); the
#: FilterConfig default (0.1 m) assumed ten times the simulated error. At a standstill nothing observes
#: the arc length better than that prior (GNSS is metre class and correlated over 30 s), so it stayed
#: the interval's width: on standstill-creep (120 s standing after GROUND TRUTH, 20 seeds) the error
#: was 0.014 m rms against sigma_s 0.100 m (NEES 0.02) and the scenario's coverage 98.5 % (NEES 0.51).
#: A GROUND TRUTH from a less accurate source needs its own value (FilterConfig.init_sigma_s_m).
GROUND_TRUTH_SIGMA_M = 0.01


def filter_config_for(
    imu: str = "mems-train", odometer: str = "wheel-odometer", gps: str = "standalone", **overrides: object
) -> FilterConfig:
    """FilterConfig for a combination of the simulator's IMU, odometer and GPS presets.

    ``overrides`` replace individual fields afterwards (validated like any FilterConfig).
    """
    from interface_modules.presets import GPS_PRESETS, IMU_PRESETS, ODOMETER_PRESETS

    try:
        imu_spec = IMU_PRESETS[imu]
        odo_spec = ODOMETER_PRESETS[odometer]
        gps_spec = GPS_PRESETS[gps]
    except KeyError as exc:
        raise FilterConfigError(
            f"unknown sensor preset {exc.args[0]!r}; IMU {sorted(IMU_PRESETS)}, odometer "
            f"{sorted(ODOMETER_PRESETS)}, GPS {sorted(GPS_PRESETS)}"
        ) from None
    g = 9.80665
    # a constant pitch misalignment reads as an along-track bias g * sin(misalignment)
    pitch_bias = g * math.sin(imu_spec.misalignment_sigma)
    # unmodelled along-track acceleration once bias, yaw misalignment and scale are states: the
    # bias random walk between updates, roll/pitch misalignment times vertical-curve forces and
    # second-order terms, ~0.002 m/s^2 correlated over ~10 s: PSD ~ sigma^2 * 2 tau
    model_psd = (0.1 * imu_spec.accel_scale_sigma * 10.0) ** 2 * 2.0 * 10.0
    quant = imu_spec.accel_lsb / math.sqrt(12.0) / math.sqrt(imu_spec.rate_hz)
    cfg = FilterConfig(
        accel_noise_density_mps2_rthz=math.hypot(imu_spec.accel_noise_density, quant),
        accel_model_noise_mps2_rthz=max(math.sqrt(model_psd), 0.005),
        accel_bias_rw_mps2_rts=imu_spec.accel_bias_rw,
        init_sigma_accel_bias_mps2=math.hypot(imu_spec.accel_bias_sigma, pitch_bias),
        init_sigma_yaw_misalignment_rad=imu_spec.misalignment_sigma,
        init_sigma_accel_scale=imu_spec.accel_scale_sigma,
        gyro_bias_rw_radps_rts=imu_spec.gyro_bias_rw,
        # gyro white noise per sample and its quantisation; the scale error is the state SG, the
        # curvature model error enters as (v * CURVATURE_MODEL_INV_M)^2
        gyro_sigma_radps=math.hypot(imu_spec.gyro_noise_density * math.sqrt(imu_spec.rate_hz),
                                    imu_spec.gyro_lsb / math.sqrt(12.0)),
        init_sigma_gyro_scale=max(imu_spec.gyro_scale_sigma, 1e-4),
        init_sigma_gyro_roll_coupling_rad=max(imu_spec.misalignment_sigma, 1e-4),
        # a noise-free IMU repeats its samples legitimately: the stuck detector needs sensor noise
        imu_stuck_samples=10 if min(imu_spec.accel_noise_density, imu_spec.gyro_noise_density) > 0.0 else 0,
        curvature_sigma_inv_m=CURVATURE_MODEL_INV_M,
        init_sigma_gyro_bias_radps=imu_spec.gyro_bias_sigma,
        init_sigma_odo_scale=odo_spec.scale_sigma,
        odo_quant_mps=odo_spec.lsb_mps,
        gps_white_sigma_m=gps_spec.white_sigma_m,
        gps_gm_sigma_m=gps_spec.gm_sigma_m,
        gps_gm_tau_s=gps_spec.gm_tau_s,
        gps_nominal_sigma_h_m=gps_spec.reported_sigma_h_m,
        gps_timeout_s=max(3.0, 3.0 / gps_spec.rate_hz),
        odo_timeout_s=max(0.5, 10.0 / odo_spec.rate_hz),
        imu_timeout_s=max(0.2, 20.0 / imu_spec.rate_hz),
        track_lateral_sigma_m=min(0.3, 3.0 * gps_spec.white_sigma_m),
        init_sigma_s_m=GROUND_TRUTH_SIGMA_M,
    )
    return cfg.replace(**overrides) if overrides else cfg
