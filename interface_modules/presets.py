"""Sensor error presets shared by the simulator (truth -> noisy samples) and the filter (noise model).

Every number carries its unit in the field name or docstring. The simulator draws its errors from
these specifications; ``sfa.presets`` builds the filter's noise model from the *same* objects, so a
scenario's sensors and the filter tuned for them never drift apart.

Sources:
- ``mems-train``: ST ASM330LHH automotive IMU as mounted on a Trenitalia/TPER ETR103 train
  (ETH-PBL Railway-Precise-Localization samples, MIT): datasheet noise densities (accel 60 ug/sqrt(Hz),
  gyro 5 mdps/sqrt(Hz)), LSB sizes 0.061 mg and 4.37 mdps at +-2 g / +-125 dps; the measured
  at-rest gyro biases of 0.5-1.8 deg/s set the turn-on gyro bias sigma. Measured on the 12 real
  samples (train standing, 1.69 kHz, white noise from first differences: std(diff) / sqrt(2) / sqrt(fs)):
  gyro 4.2-5.1 mdps/sqrt(Hz) (datasheet: 5), accelerometer 38-50 ug/sqrt(Hz) on quiet runs and up to
  137 ug/sqrt(Hz) on the vertical axis with the train's auxiliaries running; the preset keeps 60.
  Discrete noise per sample is ``density * sqrt(rate)`` (the simulator and the filter both use this).
- ``tactical``: a FOG/tactical-grade unit class (e.g. KVH 1750-like): 1 deg/h bias, 0.7 deg/sqrt(h) ARW is
  not needed here; 1 mg accel bias.
- ``wheel-odometer``: tachometer on a wheelset, 1 % diameter uncertainty (wear), slip/slide on traction.
- ``doppler-radar``: ground-speed Doppler radar (e.g. Deuta DRS05 class): 0.2 % scale, noise ~0.5 % of speed.
- GPS: ``standalone`` (u-blox M8/F9 standalone with SBAS, ~1.5 m CEP), ``dgps``, ``rtk`` (ZED-F9P RTK
  fixed: 0.01 m + 1 ppm CEP, 2-3 cm per axis in practice).
"""

from __future__ import annotations

from dataclasses import dataclass

G_MPS2 = 9.80665  #: standard gravity [m/s^2]
DEG = 0.017453292519943295  #: one degree [rad]


@dataclass(frozen=True)
class ImuSpec:
    """Error model of a 6-axis IMU (per axis, FRD body frame)."""

    rate_hz: float  #: output rate [Hz]
    accel_noise_density: float  #: accelerometer white noise [m/s^2/sqrt(Hz)]
    accel_bias_sigma: float  #: turn-on constant accelerometer bias, 1-sigma [m/s^2]
    accel_bias_rw: float  #: accelerometer bias random walk [m/s^2/sqrt(s)]
    accel_scale_sigma: float  #: accelerometer scale error, 1-sigma [fraction]
    accel_lsb: float  #: accelerometer quantisation step [m/s^2]
    gyro_noise_density: float  #: gyro white noise (angle random walk) [rad/s/sqrt(Hz)]
    gyro_bias_sigma: float  #: turn-on constant gyro bias, 1-sigma [rad/s]
    gyro_bias_rw: float  #: gyro bias random walk [rad/s/sqrt(s)]
    gyro_scale_sigma: float  #: gyro scale error, 1-sigma [fraction]
    gyro_lsb: float  #: gyro quantisation step [rad/s]
    misalignment_sigma: float  #: mounting misalignment per axis, 1-sigma [rad]


@dataclass(frozen=True)
class OdometerSpec:
    """Error model of an odometer or Doppler radar speed sensor."""

    rate_hz: float  #: output rate [Hz]
    sigma_floor_mps: float  #: white speed noise at low speed, 1-sigma [m/s]
    sigma_fraction: float  #: white speed noise proportional to speed, 1-sigma [fraction of |v|]
    scale_sigma: float  #: constant scale-factor error, 1-sigma [fraction]
    lsb_mps: float  #: quantisation step [m/s]
    slip_prone: bool  #: wheel-based (slips in traction, slides in braking) or not (radar)
    slip_rate_per_h: float = (
        0.0  #: rate of spontaneous slip/slide episodes while accelerating or braking [1/h]
    )
    slip_max_fraction: float = 0.0  #: largest spontaneous slip/slide speed error [fraction of speed]
    dropout_prob: float = 0.0  #: probability that a sample is not sent [-]


@dataclass(frozen=True)
class GpsSpec:
    """Error model of a GNSS receiver (horizontal per axis unless stated)."""

    rate_hz: float  #: fix rate [Hz]
    white_sigma_m: float  #: white position noise per horizontal axis, 1-sigma [m]
    gm_sigma_m: float  #: first-order Gauss-Markov position error per horizontal axis, steady 1-sigma [m]
    gm_tau_s: float  #: Gauss-Markov correlation time [s]
    vertical_sigma_m: float  #: total vertical error, 1-sigma [m]
    reported_sigma_h_m: float  #: sigma_h the receiver reports in the datagram [m]
    fix_quality: int  #: NMEA GGA quality when a fix is available (1 GPS, 2 DGPS, 4 RTK fixed)
    num_sv_mean: int  #: typical satellites used
    reacquire_s: float = 3.0  #: time without a fix after an outage ends (hot start) [s]
    num_sv_sigma: float = 2.0  #: variation of the satellite count, 1-sigma [-]


IMU_PRESETS: dict[str, ImuSpec] = {
    "mems-train": ImuSpec(
        rate_hz=100.0,
        accel_noise_density=60e-6 * G_MPS2,
        accel_bias_sigma=0.02 * G_MPS2 / 10.0,  # 2 mg turn-on after factory calibration
        accel_bias_rw=2.0e-4,
        accel_scale_sigma=0.002,
        accel_lsb=0.061e-3 * G_MPS2,
        gyro_noise_density=5e-3 * DEG,
        gyro_bias_sigma=1.0 * DEG,
        gyro_bias_rw=2.0e-5,
        gyro_scale_sigma=0.003,
        gyro_lsb=4.37e-3 * DEG,
        misalignment_sigma=0.5 * DEG,
    ),
    "tactical": ImuSpec(
        rate_hz=100.0,
        accel_noise_density=25e-6 * G_MPS2,
        accel_bias_sigma=1e-3 * G_MPS2,
        accel_bias_rw=1.0e-5,
        accel_scale_sigma=3e-4,
        accel_lsb=1e-5 * G_MPS2,
        gyro_noise_density=0.15 * DEG / 60.0,
        gyro_bias_sigma=1.0 * DEG / 3600.0,
        gyro_bias_rw=1e-7,
        gyro_scale_sigma=1e-4,
        gyro_lsb=1e-6,
        misalignment_sigma=0.1 * DEG,
    ),
}

#: error-free sensors (tests, debugging, the "integrate the IMU back to the truth" check)
IMU_PRESETS["ideal"] = ImuSpec(
    rate_hz=100.0,
    accel_noise_density=0.0,
    accel_bias_sigma=0.0,
    accel_bias_rw=0.0,
    accel_scale_sigma=0.0,
    accel_lsb=0.0,
    gyro_noise_density=0.0,
    gyro_bias_sigma=0.0,
    gyro_bias_rw=0.0,
    gyro_scale_sigma=0.0,
    gyro_lsb=0.0,
    misalignment_sigma=0.0,
)

ODOMETER_PRESETS: dict[str, OdometerSpec] = {
    "wheel-odometer": OdometerSpec(
        rate_hz=20.0,
        sigma_floor_mps=0.03,
        sigma_fraction=0.005,
        scale_sigma=0.01,
        lsb_mps=0.01,
        slip_prone=True,
        # low-adhesion episodes: a few per hour of traction/braking in autumn conditions (RSSB
        # "Adhesion" research programme); wheel slide protection limits them to ~10-20 % creep
        slip_rate_per_h=6.0,
        slip_max_fraction=0.15,
        dropout_prob=1e-4,
    ),
    "doppler-radar": OdometerSpec(
        rate_hz=20.0,
        sigma_floor_mps=0.02,
        sigma_fraction=0.005,
        scale_sigma=0.002,
        lsb_mps=0.005,
        slip_prone=False,
        # radars lose the ground echo occasionally (standing water, snow, ballast-free track)
        dropout_prob=1e-3,
    ),
}

ODOMETER_PRESETS["ideal"] = OdometerSpec(
    rate_hz=20.0,
    sigma_floor_mps=0.0,
    sigma_fraction=0.0,
    scale_sigma=0.0,
    lsb_mps=0.0,
    slip_prone=False,
)

GPS_PRESETS: dict[str, GpsSpec] = {
    "standalone": GpsSpec(
        rate_hz=1.0,
        white_sigma_m=0.5,
        gm_sigma_m=1.0,
        gm_tau_s=30.0,
        vertical_sigma_m=3.0,
        reported_sigma_h_m=1.5,
        fix_quality=1,
        num_sv_mean=12,
    ),
    "dgps": GpsSpec(
        rate_hz=1.0,
        white_sigma_m=0.3,
        gm_sigma_m=0.4,
        gm_tau_s=60.0,
        vertical_sigma_m=1.0,
        reported_sigma_h_m=0.6,
        fix_quality=2,
        num_sv_mean=14,
    ),
    "rtk": GpsSpec(
        rate_hz=10.0,
        white_sigma_m=0.01,
        gm_sigma_m=0.015,
        gm_tau_s=60.0,
        vertical_sigma_m=0.04,
        reported_sigma_h_m=0.02,
        fix_quality=4,
        num_sv_mean=20,
    ),
}
#: error-free GNSS (the reported sigma_h must be > 0 on the wire: 1 mm)
GPS_PRESETS["ideal"] = GpsSpec(
    rate_hz=1.0,
    white_sigma_m=0.0,
    gm_sigma_m=0.0,
    gm_tau_s=60.0,
    vertical_sigma_m=0.0,
    reported_sigma_h_m=0.001,
    fix_quality=4,
    num_sv_mean=20,
    num_sv_sigma=0.0,
)
