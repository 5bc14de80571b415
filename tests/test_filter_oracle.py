"""FilterPy as the independent oracle: the same model written out with numpy and FilterPy's
ExtendedKalmanFilter (its predict and Joseph-form update), the same inputs, agreement to 1e-9.

The oracle shares no code with sfa.kernels: the motion model, Q, the measurement functions and their
Jacobians are written out below from docs/filter.md, and the track geometry comes from track_db's
TrackLine (point_at and its vertex arrays)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from filterpy.kalman import ExtendedKalmanFilter

from interface_modules.presets import GPS_PRESETS, IMU_PRESETS, ODOMETER_PRESETS
from sfa.filter import TrackFilter
from sfa.layout import Outcome
from sfa.measurements import GpsMeas, ImuMeas, InitMeas, OdoMeas
from sfa.presets import filter_config_for
from sfa.synthetic import Profile, build_track_db, generate
from track_db import TrackDatabase

NX = 11


@pytest.fixture(scope="module")
def db(tmp_path_factory):
    path = build_track_db(tmp_path_factory.mktemp("track") / "oracle.db")
    with TrackDatabase.open(path) as database:
        yield database


class Oracle:
    """The filter's model with FilterPy: x = [s, v, b_a, k_o, e_gnss, n_gnss, b_g, m_yaw, s_f, s_g, m_x]."""

    def __init__(self, line, cfg, grade_s, grade, curv):
        from scipy.stats import chi2

        self.line, self.cfg = line, cfg
        self.grade_s, self.grade = grade_s, grade
        self.ekf = ExtendedKalmanFilter(dim_x=NX, dim_z=2)
        self.t = None
        self.fx = 0.0
        self.fy = 0.0
        self.q_acc = cfg.accel_noise_density_mps2_rthz ** 2 + cfg.accel_model_noise_mps2_rthz ** 2
        self.gate_gps = chi2.ppf(cfg.gate_prob_gps, 2)
        self.gate_gyro = chi2.ppf(cfg.gate_prob_gyro, 1)
        self.curv_s, self.curv = grade_s, curv
        self.gyro_updates = 0
        self.roll_compensated = 0
        self.direction = 1.0
        self.window = []  # gyro window: (H row, residual) per sample, residuals kept at the current state
        self.t_imu = None  # time of the previous IMU sample
        self.window_t0 = None
        self.curv_var = 0.0

    def init(self, m: InitMeas):
        c = self.cfg
        self.ekf.x = np.array([[m.arc_length_m, m.speed_mps] + [0] * (NX - 2)], dtype=float).T  # column
        self.ekf.P = np.diag([
            c.init_sigma_s_m ** 2, c.init_sigma_v_mps ** 2, c.init_sigma_accel_bias_mps2 ** 2,
            c.init_sigma_odo_scale ** 2, c.gps_gm_sigma_m ** 2, c.gps_gm_sigma_m ** 2,
            c.init_sigma_gyro_bias_radps ** 2, c.init_sigma_yaw_misalignment_rad ** 2,
            c.init_sigma_accel_scale ** 2, c.init_sigma_gyro_scale ** 2,
            c.init_sigma_gyro_roll_coupling_rad ** 2,
        ])
        g = np.interp(m.arc_length_m, self.grade_s, self.grade)
        self.fx = 9.80665 * g / math.sqrt(1 + g * g)  # until the first IMU: constant speed
        self.fy = 0.0
        self.t_imu = m.t_s  # the kernel's IMU clock starts at the initialisation
        self.t = m.t_s

    def predict(self, t):
        h = t - self.t
        if h <= 0:
            return
        c = self.cfg
        g = np.interp(self.ekf.x[0, 0], self.grade_s, self.grade)
        u = self.fx - c.gravity_mps2 * g / math.sqrt(1 + g * g)  # f_x - g sin(theta)
        # (the scale term is linear in the state: -s_f f_x sits in F, like -m_y f_y)
        phi = math.exp(-h / c.gps_gm_tau_s)
        F = np.eye(NX)
        F[0, 1] = h
        F[0, 2] = -0.5 * h * h
        F[1, 2] = -h
        F[0, 7], F[1, 7] = -0.5 * h * h * self.fy, -h * self.fy  # yaw misalignment picks up f_y
        F[0, 8], F[1, 8] = -0.5 * h * h * self.fx, -h * self.fx  # accelerometer scale factor
        F[4, 4] = F[5, 5] = phi
        Q = np.zeros((NX, NX))
        Q[0, 0] = self.q_acc * h ** 3 / 3
        Q[0, 1] = Q[1, 0] = self.q_acc * h ** 2 / 2
        Q[1, 1] = self.q_acc * h
        Q[2, 2] = c.accel_bias_rw_mps2_rts ** 2 * h
        Q[3, 3] = c.odo_scale_rw_per_rts ** 2 * h
        Q[4, 4] = Q[5, 5] = c.gps_gm_sigma_m ** 2 * (1 - phi * phi)
        Q[6, 6] = c.gyro_bias_rw_radps_rts ** 2 * h
        Q[9, 9] = c.gyro_scale_rw_per_rts ** 2 * h
        self.ekf.F, self.ekf.Q = F, Q
        self.ekf.B = np.array([[0.5 * h * h], [h]] + [[0.0]] * (NX - 2))
        self.ekf.predict(u=np.array([[u]]))
        # map registration: a random walk of the arc length in the distance travelled (at the new speed)
        self.ekf.P[0, 0] += c.registration_psd_m2pm * abs(self.ekf.x[1, 0]) * h
        self.t = t

    def update(self, z, hj, hx, R):
        """FilterPy's EKF update; the gyro window's residuals follow the state's change (y_i -= H_i dx)."""
        x0 = self.ekf.x.copy()
        self.ekf.update(z, hj, hx, R=R)
        dx = self.ekf.x - x0
        self.window = [(H, y - (H @ dx)[0, 0]) for H, y in self.window]

    def gyro_window_update(self):
        """One update from the window's n samples: mean residual, mean Jacobian, R = sigma^2/n + mean curv."""
        n = len(self.window)
        H = sum(h for h, _ in self.window) / n
        y = sum(r for _, r in self.window) / n
        R = np.array([[self.cfg.gyro_sigma_radps ** 2 / n + self.curv_var / n]])
        self.window = []
        nis = y * y / (H @ self.ekf.P @ H.T + R)[0, 0]
        if nis <= self.gate_gyro:
            self.ekf.update(np.array([[y]]), lambda _x: H, lambda _x: np.zeros((1, 1)), R=R)  # innovation y
            self.gyro_updates += 1

    def imu(self, m: ImuMeas):
        self.predict(m.t_s)
        dt_imu = m.t_s - self.t_imu
        self.t_imu = m.t_s
        self.fx, self.fy = m.f_mps2[0], m.f_mps2[1]
        x = self.ekf.x
        if not (self.cfg.use_gyro and abs(x[1, 0]) >= self.cfg.gyro_min_speed_mps):
            self.window = []
        else:
            # gz = v k(s) + b_g, k from the same per-point curvature samples as the filter
            s = x[0, 0]
            k = np.interp(s, self.curv_s, self.curv)
            i = int(np.clip(np.searchsorted(self.curv_s, s, side="right") - 1, 0, self.curv_s.size - 2))
            dk = (self.curv[i + 1] - self.curv[i]) / (self.curv_s[i + 1] - self.curv_s[i])
            # the gyro is rolled by the cant: the accelerometer's (f_y, f_z) is the level frame's
            # (v^2 k_travel, -g) turned by the roll angle; the yaw gyro reads cos(roll) times the yaw rate
            lat = x[1, 0] ** 2 * self.direction * k
            level = complex(lat, -self.cfg.gravity_mps2)
            body = complex(m.f_mps2[1], m.f_mps2[2])
            roll = np.angle(level) - np.angle(body)
            c = math.cos(roll) if 0.8 <= abs(body) / abs(level) <= 1.25 and abs(roll) <= 0.35 else 1.0
            if not self.cfg.gyro_tilt_compensation:
                c = 1.0
            self.roll_compensated += c != 1.0
            gx = m.w_radps[0]
            g1 = c * (1.0 + x[9, 0])
            H = np.zeros((1, NX))
            H[0, 0], H[0, 1], H[0, 6], H[0, 9], H[0, 10] = g1 * x[1, 0] * dk, g1 * k, 1.0, c * x[1, 0] * k, gx
            # curvature error from the geometry, correlated over curvature_corr_length_m: each window
            # inside that length carries it (length / distance per window) times over
            cf = self.cfg
            sigma_k2 = (cf.curvature_sigma_inv_m ** 2 + (cf.curvature_rel_sigma * k) ** 2
                        + (cf.curvature_registration_m * dk) ** 2)
            dt_window = min(max(dt_imu, 1e-3), cf.gyro_average_max_s)
            per_window_m = abs(x[1, 0]) * cf.gyro_average_samples * dt_window
            n_c = max(1.0, cf.curvature_corr_length_m / per_window_m)
            R = np.array([[cf.gyro_sigma_radps ** 2 + x[1, 0] ** 2 * sigma_k2 * n_c]])

            def hx(xx):  # gz = c (1 + s_g) v k(s) + b_g + m_x g_x
                return np.array([[c * (1.0 + xx[9, 0]) * xx[1, 0] * k + xx[6, 0] + xx[10, 0] * gx]])

            y = m.w_radps[2] - hx(x)[0, 0]
            if self.window and m.t_s - self.window_t0 > self.cfg.gyro_average_max_s:
                self.gyro_window_update()  # the window spans too long: apply what it holds
            if not self.window:
                self.window_t0 = m.t_s
                self.curv_var = 0.0
            self.window.append((H, y))
            self.curv_var += R[0, 0] - self.cfg.gyro_sigma_radps ** 2  # (v sigma_k)^2 of this sample
            if len(self.window) >= self.cfg.gyro_average_samples:
                self.gyro_window_update()

    def odo(self, m: OdoMeas):
        self.predict(m.t_s)
        c = self.cfg
        r = max(m.sigma_mps, c.odo_sigma_min_mps) ** 2 + c.odo_quant_mps ** 2 / 12

        def hj(x):
            return np.array([[0.0, 1 + x[3, 0], 0, x[1, 0]] + [0] * (NX - 4)])

        def hx(x):
            return np.array([[x[1, 0] * (1 + x[3, 0])]])

        self.update(np.array([[m.speed_mps]]), hj, hx, R=np.array([[r]]))

    def gps(self, m: GpsMeas, east, north):
        self.predict(m.t_s)
        c = self.cfg
        line = self.line

        def deriv(s):
            i = int(np.clip(np.searchsorted(line.s_m, s, side="right") - 1, 0, line.s_m.size - 2))
            ds = line.s_m[i + 1] - line.s_m[i]
            return (line.east_m[i + 1] - line.east_m[i]) / ds, (line.north_m[i + 1] - line.north_m[i]) / ds

        def jac(s_lin):
            de, dn = deriv(s_lin)
            z = [0] * (NX - 6)
            return np.array([[de, 0, 0, 0, 1, 0, *z], [dn, 0, 0, 0, 0, 1, *z]], dtype=float)

        def noise(s_lin):
            de, dn = deriv(s_lin)
            nrm = math.hypot(de, dn)
            ue, un = de / nrm, dn / nrm
            sw = c.gps_white_sigma_m * max(1.0, m.sigma_h_m / c.gps_nominal_sigma_h_m)
            sl2 = c.track_lateral_sigma_m ** 2
            return np.array([[sw * sw + sl2 * un * un, -sl2 * ue * un],
                             [-sl2 * ue * un, sw * sw + sl2 * ue * ue]])

        def h_at(x, s_lin):
            """h linearised at x* = x with s -> s_lin: h(x*) + H(x*) (x - x*)."""
            e, n = line.point_at(s_lin)
            xs = x.copy()
            xs[0, 0] = s_lin
            return np.array([[float(e) + xs[4, 0]], [float(n) + xs[5, 0]]]) + jac(s_lin) @ (x - xs)

        # iterated EKF in the arc length (docs/filter.md): Gauss-Newton steps s <- s + (P H' S^-1 y)_s, each
        # linearised at the last, at most 3, until the step is under 1 mm; the update uses the last
        z = np.array([[east], [north]])
        x, P = self.ekf.x, self.ekf.P
        s_lin = x[0, 0]
        for _ in range(3):
            H = jac(s_lin)
            y = z - h_at(x, s_lin)
            S = H @ P @ H.T + noise(s_lin)
            s_next = x[0, 0] + (P @ H.T @ np.linalg.solve(S, y))[0, 0]
            if abs(s_next - s_lin) < 1e-3:
                break
            s_lin = s_next
        H_lin = jac(s_lin)
        self.update(z, lambda x, H=H_lin: H, lambda x, s=s_lin: h_at(x, s), R=noise(s_lin))


#: the digitised-map terms of sfa.presets.datasheet_config_for on the model-matched sensor preset: the
#: geometry curvature error with its correlation inflation, and the map registration random walk
MAP_TERMS = {"curvature_rel_sigma": 0.25, "curvature_registration_m": 20.0, "curvature_corr_length_m": 40.0,
             "registration_psd_m2pm": 1.0e-3}


@pytest.mark.parametrize("map_terms", [{}, MAP_TERMS], ids=["model-matched", "map-terms"])
def test_filter_matches_filterpy_oracle_to_1e9(db, map_terms):
    cfg = filter_config_for("mems-train", "wheel-odometer", "standalone", **map_terms)
    # no standstill in this profile (ZUPT is a separate pseudo-measurement), speeds 8..14 m/s
    profile = Profile(segments=((20.0, 0.3), (20.0, -0.3)), v0_mps=8.0, s0_m=50.0)
    run = generate(db, 1, 300.0, IMU_PRESETS["mems-train"], ODOMETER_PRESETS["wheel-odometer"],
                   GPS_PRESETS["standalone"], seed=21, profile=profile)
    f = TrackFilter(db, cfg)
    line = db.line(1)
    arrays = f.line_arrays(1)  # the grade samples the filter uses (the database's smoothed grade)
    oracle = Oracle(line, cfg, arrays.s_m, arrays.grade, arrays.curvature_inv_m)
    compared = 0
    for m in run.measurements:
        u = f.process(m)
        if isinstance(m, InitMeas):
            oracle.init(m)
            continue
        assert u.outcome == Outcome.ACCEPTED, (m, u)
        if isinstance(m, ImuMeas):
            oracle.imu(m)
        elif isinstance(m, OdoMeas):
            oracle.odo(m)
        else:
            e, n = db.to_local(m.lat_deg, m.lon_deg)
            oracle.gps(m, float(e), float(n))
        if not isinstance(m, ImuMeas) or compared % 50 == 0:
            x, P = f.state()
            np.testing.assert_allclose(x, oracle.ekf.x.ravel(), rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(P, oracle.ekf.P, rtol=1e-9, atol=1e-12)
        compared += 1
    assert compared == len(run.measurements) - 1
    # the gyro update (one per window of gyro_average_samples IMU samples) is part of the compared model
    assert cfg.use_gyro and cfg.gyro_average_samples > 1
    assert oracle.gyro_updates > 10000 / cfg.gyro_average_samples
    assert oracle.roll_compensated > 10000  # and so is its roll compensation
    assert f.counters()["gyro_accepted"] == oracle.gyro_updates
    x, _ = f.state()
    assert abs(x[0] - run.s_m[-1]) < 2.0  # and the shared answer is a good one
