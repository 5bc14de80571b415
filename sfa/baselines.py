"""Baselines the SFA filter is compared against, on the same measurements, with the same output.

- ``odometer_dead_reckoning``: s(t) = s0 + d * integral of the odometer speed (sample held until the
  next one), restarted by each GROUND TRUTH. No IMU, no GNSS, no scale-factor estimation.
- ``gnss_projection``: each usable GNSS fix projected onto the line near the previous position (the
  nearest pass of the line within reach since the previous fix), held until the next fix. No motion
  sensor.
- ``plain_filterpy_ekf``: a textbook per-message FilterPy ``ExtendedKalmanFilter`` of the same sensors
  *without* track-aware GNSS handling. State [s, v, b_a, k_o]; the IMU drives the prediction exactly
  as in the SFA filter (f_x - b_a - g sin(theta)); the odometer updates v (1 + k_o) with its sigma;
  each GNSS fix is first projected onto the line (near the predicted position) and used as a scalar
  arc-length measurement with the receiver's reported sigma_h. No GNSS error state, no lateral
  handling, no gating, no integrity.

Each returns a ``BaselineResult`` with one row per input measurement (the estimate after it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sfa.config import FilterConfig
from sfa.measurements import GpsMeas, ImuMeas, InitMeas, OdoMeas


@dataclass(frozen=True)
class BaselineResult:
    """Estimates after each input measurement (NaN before the first initialisation)."""

    name: str
    epoch_s: np.ndarray  #: time of the estimate [s]
    arc_length_m: np.ndarray  #: [m]


def _direction(m: InitMeas) -> float:
    return 1.0 if m.direction is None else float(m.direction)


def odometer_dead_reckoning(measurements) -> BaselineResult:
    """Integrate the odometer speed from the last GROUND TRUTH (see module doc)."""
    n = len(measurements)
    t_out = np.full(n, math.nan)
    s_out = np.full(n, math.nan)
    s = t = v = math.nan
    d = 1.0
    for i, m in enumerate(measurements):
        if isinstance(m, InitMeas):
            s, t, v, d = m.arc_length_m, m.t_s, m.speed_mps, _direction(m)
        elif math.isfinite(t) and m.t_s >= t:
            s += d * v * (m.t_s - t)  # s += d v dt (previous sample held)
            t = m.t_s
            if isinstance(m, OdoMeas) and math.isfinite(m.speed_mps):
                v = m.speed_mps
        t_out[i], s_out[i] = t, s
    return BaselineResult("odometer dead reckoning", t_out, s_out)


def _project_near(line, east_m: float, north_m: float, s_ref_m: float, window_m: float) -> float:
    """Arc length of the nearest point of ``line`` among its segments within ``window_m`` of ``s_ref_m``.

    A route that passes the same place twice (out and back, loops) has two nearest points; the fix
    belongs to the pass the train is on, so the search is local to where the track position was.
    """
    s_v, e_v, n_v = line.s_m, line.east_m, line.north_m
    i0 = max(int(np.searchsorted(s_v, s_ref_m - window_m)) - 1, 0)
    i1 = min(int(np.searchsorted(s_v, s_ref_m + window_m)) + 1, s_v.size - 1)
    if i1 <= i0:
        return float(s_ref_m)
    ax, ay = e_v[i0:i1], n_v[i0:i1]
    dx, dy = e_v[i0 + 1 : i1 + 1] - ax, n_v[i0 + 1 : i1 + 1] - ay
    seg2 = dx * dx + dy * dy
    u = np.clip(((east_m - ax) * dx + (north_m - ay) * dy) / np.where(seg2 > 0, seg2, 1.0), 0.0, 1.0)
    d2 = (ax + u * dx - east_m) ** 2 + (ay + u * dy - north_m) ** 2
    k = int(np.argmin(d2))
    # arc length maps linearly onto each local segment (track_db convention)
    return float(s_v[i0 + k] + u[k] * (s_v[i0 + k + 1] - s_v[i0 + k]))


def gnss_projection(
    track, measurements, line_id: int | None = None, window_m: float = 300.0, max_speed_mps: float = 100.0
) -> BaselineResult:
    """Project each usable fix onto the line (of the first GROUND TRUTH unless given) and hold it.

    Each fix is projected onto the part of the line within ``window_m + max_speed_mps * dt`` of the
    previous position (the GROUND TRUTH, then the previous fix, ``dt`` seconds earlier), so a route
    that passes a place twice is not confused, and an outage of any length is bridged.
    """
    if line_id is None:
        line_id = next((m.line_id for m in measurements if isinstance(m, InitMeas)), None)
    line = track.line(line_id)
    n = len(measurements)
    t_out = np.full(n, math.nan)
    s_out = np.full(n, math.nan)
    s = t = math.nan
    for i, m in enumerate(measurements):
        if isinstance(m, InitMeas) and not math.isfinite(s):
            s, t = m.arc_length_m, m.t_s
        elif isinstance(m, GpsMeas) and m.fix_quality != 0 and math.isfinite(m.lat_deg + m.lon_deg):
            e, nn = track.to_local(m.lat_deg, m.lon_deg)
            if math.isfinite(s):
                s_fix = _project_near(line, float(e), float(nn), s, window_m + max_speed_mps * (m.t_s - t))
            else:
                s_fix, _ = line.project(float(e), float(nn))
            s, t = float(s_fix), m.t_s
        t_out[i], s_out[i] = (m.t_s if math.isfinite(t) else math.nan), s
    return BaselineResult("GNSS projection", t_out, s_out)


def plain_filterpy_ekf(track, measurements, config: FilterConfig | None = None) -> BaselineResult:
    """The plain FilterPy EKF described in the module doc, one message at a time."""
    from filterpy.kalman import ExtendedKalmanFilter

    c = config or FilterConfig()
    line = None
    ekf = ExtendedKalmanFilter(dim_x=4, dim_z=1)
    q = c.accel_noise_density_mps2_rthz ** 2 + c.accel_model_noise_mps2_rthz ** 2
    n = len(measurements)
    t_out = np.full(n, math.nan)
    s_out = np.full(n, math.nan)
    t = math.nan
    fx = 0.0
    d = 1.0

    def predict(t_new: float) -> None:
        nonlocal t
        h = t_new - t
        if not h > 0:
            return
        grade = float(line.grade_at(float(np.clip(ekf.x[0, 0], 0.0, line.length_m))))
        u = d * fx - c.gravity_mps2 * grade / math.sqrt(1.0 + grade * grade)
        ekf.F = np.array([[1, h, -0.5 * d * h * h, 0], [0, 1, -d * h, 0], [0, 0, 1, 0], [0, 0, 0, 1]], float)
        ekf.B = np.array([[0.5 * h * h], [h], [0.0], [0.0]])
        ekf.Q = np.array([[q * h ** 3 / 3, q * h * h / 2, 0, 0], [q * h * h / 2, q * h, 0, 0],
                          [0, 0, c.accel_bias_rw_mps2_rts ** 2 * h, 0],
                          [0, 0, 0, c.odo_scale_rw_per_rts ** 2 * h]])
        ekf.predict(u=np.array([[u]]))
        t = t_new

    def odo_h(x):
        return np.array([[d * x[1, 0] * (1.0 + x[3, 0])]])

    def odo_j(x):
        return np.array([[0.0, d * (1.0 + x[3, 0]), 0.0, d * x[1, 0]]])

    def s_h(x):
        return np.array([[x[0, 0]]])

    def s_j(x):
        return np.array([[1.0, 0.0, 0.0, 0.0]])

    for i, m in enumerate(measurements):
        if isinstance(m, InitMeas):
            line = track.line(m.line_id)
            d = _direction(m)
            ekf.x = np.array([[m.arc_length_m], [d * m.speed_mps], [0.0], [0.0]])
            ekf.P = np.diag([c.init_sigma_s_m ** 2, c.init_sigma_v_mps ** 2,
                             c.init_sigma_accel_bias_mps2 ** 2, c.init_sigma_odo_scale ** 2])
            t = m.t_s
            grade = float(line.grade_at(float(np.clip(m.arc_length_m, 0.0, line.length_m))))
            fx = d * c.gravity_mps2 * grade / math.sqrt(1.0 + grade * grade)
        elif line is not None and m.t_s >= t:
            predict(m.t_s)
            if isinstance(m, ImuMeas):
                if all(math.isfinite(v) for v in m.f_mps2):
                    fx = m.f_mps2[0]
            elif isinstance(m, OdoMeas):
                if math.isfinite(m.speed_mps) and m.sigma_mps > 0:
                    r = m.sigma_mps ** 2 + c.odo_quant_mps ** 2 / 12.0
                    ekf.update(np.array([[m.speed_mps]]), odo_j, odo_h, R=np.array([[r]]))
            elif isinstance(m, GpsMeas) and m.fix_quality != 0:
                if math.isfinite(m.lat_deg) and math.isfinite(m.lon_deg):
                    # projected near the predicted position (a route may pass a place twice)
                    e, nn = track.to_local(m.lat_deg, m.lon_deg)
                    s_fix = _project_near(line, float(e), float(nn), float(ekf.x[0, 0]), 300.0)
                    sig = m.sigma_h_m if m.sigma_h_m and m.sigma_h_m > 0 else c.gps_nominal_sigma_h_m
                    ekf.update(np.array([[float(s_fix)]]), s_j, s_h, R=np.array([[sig * sig]]))
        if line is not None:
            t_out[i], s_out[i] = t, float(ekf.x[0, 0])
    return BaselineResult("plain FilterPy EKF", t_out, s_out)
