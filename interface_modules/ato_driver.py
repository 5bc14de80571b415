"""The ATO seed's speed tracker (section 5.1): gain-scheduled PID with feed-forward over the LSPB profile.

The seed's remote-driving controller is a Proportional-Integral-Derivative Gain-Scheduling (PIDGS)
law with a feed-forward action: the gains are scheduled on the reference speed ``v_ref`` and the
feed-forward compensates the known line and vehicle forces. Here, per truth step ``dt``:

    e        = v_ref(x) - v
    k(v_ref) = k_low + (k_high - k_low) clip(v_ref / v_sched, 0, 1)     for kp, ki, kd
    a_cmd    = a_ref(x_p) + kp e + ki I + kd de/dt          (x_p = x + v t_p: the preview point;
                                                             de/dt low-passed, I clamped: anti-windup)
    u_cmd    = M_eff a_cmd + F_davis(v) + F_grade(s) + F_curve(s)     (the feed-forward of the model)

``u_cmd`` is clipped to the actuator envelope (traction ``min(effort, adhesion, P / v)`` times
``traction_saturation``, service brake) and its rate to ``M_eff j_max`` (the train's jerk limit).
The force the train actually gets, ``u``, follows ``u_cmd`` through a first-order lag (time constant
``traction_lag_s`` while traction is commanded, ``brake_lag_s`` while braking: the electro-dynamic
and pneumatic brake response) and is rate-limited by the same jerk limit, so the train's
acceleration changes no faster than ``j_max`` plus the slow change of the resistances. The integral
only runs while the command is not clipped. The reference comes from :mod:`interface_modules.planner`
(LSPB in space: accelerate, cruise, brake; limits, curves and stops). Near the stopping point the
holding brake stops the train (as the PI driver of :mod:`interface_modules.motion`).

Nothing here is random: the same scenario gives the same trajectory, whatever the seed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from .dynamics import train_step


@dataclass(frozen=True)
class AtoPidConfig:
    """Gains, actuator response and stop logic of the seed-style driver (``[driver] kind = "ato-pid"``)."""

    kp_low_per_s: float = 0.8  #: proportional gain at v_ref = 0 [1/s] (acceleration per speed error)
    kp_high_per_s: float = 0.5  #: proportional gain at v_ref >= schedule_speed_mps [1/s]
    ki_low_per_s2: float = 0.10  #: integral gain at v_ref = 0 [1/s^2]
    ki_high_per_s2: float = 0.05  #: integral gain at v_ref >= schedule_speed_mps [1/s^2]
    kd_low: float = 0.10  #: derivative gain at v_ref = 0 [-] (acceleration per rate of speed error)
    kd_high: float = 0.05  #: derivative gain at v_ref >= schedule_speed_mps [-]
    schedule_speed_mps: float = 11.0  #: reference speed at which the gains reach their high values [m/s]
    derivative_filter_s: float = 0.5  #: time constant of the derivative's low-pass filter [s]
    integral_limit_mps2: float = 0.3  #: largest |ki I| (anti-windup clamp) [m/s^2]
    traction_lag_s: float = 0.4  #: first-order response time of the traction force [s]
    brake_lag_s: float = 0.8  #: first-order response time of the brake force [s]
    #: usable share of the traction envelope (the seed's field test capped the traction requests) [-]
    traction_saturation: float = 1.0
    preview_factor: float = 1.0  #: look-ahead in units of (jerk build-up a / (2 j) + brake lag) [-]
    stop_tolerance_m: float = 1.0  #: a standstill this close to the stopping point counts as arrived [m]
    #: below this speed within the stop tolerance the holding brake stops the train [m/s]
    holding_speed_mps: float = 0.15
    max_leg_overrun_s: float = 900.0  #: a leg taking this much longer than planned is an error [s]

    def __post_init__(self) -> None:
        positive = ("schedule_speed_mps", "derivative_filter_s", "traction_lag_s", "brake_lag_s",
                    "stop_tolerance_m", "holding_speed_mps", "max_leg_overrun_s")
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"driver.{name} must be > 0, got {value!r}")
        for name in ("kp_low_per_s", "kp_high_per_s", "ki_low_per_s2", "ki_high_per_s2", "kd_low", "kd_high",
                     "integral_limit_mps2", "preview_factor"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"driver.{name} must be >= 0, got {value!r}")
        if not 0.0 < self.traction_saturation <= 1.0:
            raise ValueError(
                f"driver.traction_saturation must be in (0, 1], got {self.traction_saturation!r}")

    def preview_s(self, plan_accel_mps2: float, plan_decel_mps2: float, jerk_limit_mps3: float) -> float:
        """Look-ahead time of the reference [s]."""
        build_up = max(plan_accel_mps2, plan_decel_mps2) / (2.0 * jerk_limit_mps3)
        return self.preview_factor * (build_up + self.brake_lag_s)


def kernel_params(cfg: AtoPidConfig, base: np.ndarray) -> np.ndarray:
    """The kernel's parameter vector: the PI driver's ``base`` (19 values) then the PIDGS terms."""
    extra = [
        cfg.kp_low_per_s, cfg.kp_high_per_s, cfg.ki_low_per_s2, cfg.ki_high_per_s2, cfg.kd_low, cfg.kd_high,
        cfg.schedule_speed_mps, cfg.derivative_filter_s, cfg.integral_limit_mps2, cfg.traction_lag_s,
        cfg.brake_lag_s, cfg.traction_saturation,
    ]
    return np.concatenate((base, np.asarray(extra, dtype=float)))


@numba.njit(cache=True)
def _interp(arr, fi):
    """Linear interpolation of the grid ``arr`` at the fractional index ``fi`` (clamped to the ends)."""
    n = arr.size
    if fi <= 0.0:
        return arr[0]
    if fi >= n - 1:
        return arr[n - 1]
    i = int(fi)
    return arr[i] + (arr[i + 1] - arr[i]) * (fi - i)


@numba.njit(cache=True)
def ato_leg_kernel(state, params, vp, ap, fg_arr, fc_arr, out_s, out_v, out_a, k0, k_limit, k_overrun):
    """Drive one leg from ``state`` = [s, v, u_cmd, u] at step ``k0`` (see module doc).

    ``params``: the PI driver's 19 values (``motion._leg_kernel``; its kp/ki unused) followed by
    [kp_lo, kp_hi, ki_lo, ki_hi, kd_lo, kd_hi, v_sched, tau_d, i_lim, tau_trac, tau_brake, trac_sat].
    Writes one row per step into ``out_*``; returns (steps written, status): 0 arrived, 1 time
    limit, 2 overrun.
    """
    dt, s0, d, length, inv_dx, preview_s = params[0], params[1], params[2], params[3], params[4], params[5]
    m_eff, jerk_df, brake_n = params[8], params[9], params[10]
    a_davis, b_davis, c_davis, trac_const, power = params[11], params[12], params[13], params[14], params[15]
    hold_v, stop_tol, plan_decel = params[16], params[17], params[18]
    kp_lo, kp_hi, ki_lo, ki_hi = params[19], params[20], params[21], params[22]
    kd_lo, kd_hi = params[23], params[24]
    v_sched, tau_d, i_lim, tau_t, tau_b, trac_sat = (
        params[25], params[26], params[27], params[28], params[29], params[30])
    alpha_t = 1.0 - np.exp(-dt / tau_t)
    alpha_b = 1.0 - np.exp(-dt / tau_b)
    beta_d = dt / (tau_d + dt)
    s, v, u_cmd, u = state[0], state[1], state[2], state[3]
    integ = 0.0
    e_prev = 0.0
    de_f = 0.0
    first = True
    n_grid = vp.size
    n = 0
    k = k0
    while True:
        if k >= k_limit:
            state[0], state[1], state[2], state[3] = s, v, u_cmd, u
            return n, 1
        x = d * (s - s0)
        if v == 0.0 and x >= length - stop_tol:
            state[0], state[1], state[2], state[3] = s, v, u_cmd, u
            return n, 0
        if k >= k_overrun:
            state[0], state[1], state[2], state[3] = s, v, u_cmd, u
            return n, 2
        # speed reference here; acceleration feed-forward at the preview point (the actuator's delay)
        v_ref = _interp(vp, x * inv_dx) if x < length else 0.0
        xp = x + v * preview_s
        a_ref = _interp(ap, xp * inv_dx) if xp < length else -plan_decel
        ix = int(x * inv_dx + 0.5)
        ix = min(max(ix, 0), n_grid - 1)
        fg = fg_arr[ix]
        fc = fc_arr[ix]
        # gain scheduling on the reference speed
        w = min(max(v_ref / v_sched, 0.0), 1.0)
        kp = kp_lo + (kp_hi - kp_lo) * w
        ki = ki_lo + (ki_hi - ki_lo) * w
        kd = kd_lo + (kd_hi - kd_lo) * w
        err = v_ref - v
        if first:
            first = False
        else:
            de_f += ((err - e_prev) / dt - de_f) * beta_d
        e_prev = err
        a_cmd = a_ref + kp * err + ki * integ + kd * de_f
        f_res = a_davis + b_davis * v + c_davis * v * v if v > 0.0 else 0.0
        u_des = m_eff * a_cmd + f_res + fg + fc
        if v < hold_v and x >= length - stop_tol:
            u_des = -brake_n  # final stop: holding brake
        u_max = trac_const if v <= 1e-6 else min(trac_const, power / v)
        u_max *= trac_sat
        u_clip = min(max(u_des, -brake_n), u_max)
        saturated = u_clip != u_des
        u_cmd = min(max(u_clip, u_cmd - jerk_df), u_cmd + jerk_df)
        if not saturated and ki > 0.0:
            integ += err * dt
            lim = i_lim / ki
            integ = min(max(integ, -lim), lim)
        # actuator: first-order lag (traction or brake time constant), slew-limited by the jerk limit
        alpha = alpha_t if u_cmd >= 0.0 else alpha_b
        du = (u_cmd - u) * alpha
        u += min(max(du, -jerk_df), jerk_df)
        # M_eff dv/dt = u - Davis - grade - curve; at rest the brakes hold the train (no rollback)
        a, v_next = train_step(u, v, fg, fc, a_davis, b_davis, c_davis, m_eff, dt)
        out_s[n] = s
        out_v[n] = v
        out_a[n] = a
        n += 1
        s = s + d * (v * dt + 0.5 * a * dt * dt)
        v = v_next
        k += 1
