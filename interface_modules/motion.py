"""The driver and the truth trajectory: journey profile -> truth (time, arc length, speed, acceleration).

Integration scheme (what the sensor models and the tests rely on): time advances in fixed steps
``dt``; over step ``k`` (from ``t_k`` to ``t_k + dt``) the train's acceleration ``a_k`` is constant,
so ``v_{k+1} = v_k + a_k dt`` and ``d_{k+1} = d_k + v_k dt + a_k dt^2 / 2`` (``d`` = distance travelled;
arc length ``s = s_start + direction * d`` within a leg). A step that would make the speed negative is
shortened to stop exactly at 0 (``a_k = -v_k / dt``). The truth arrays store ``t_k, s_k, v_k, a_k``.

The driver follows the leg's planned profile in space (``v_ref(x)``, ``a_ff(x) = v dv/dx``). The
default is the ATO seed's gain-scheduled PID with actuator lag (:mod:`interface_modules.ato_driver`);
:class:`DriverConfig` selects the earlier feedforward + PI speed tracker (``[driver] kind = "pi"``):
its commanded force adds the known resistances, is clipped to the traction envelope and the service
brake, and its rate is limited by the jerk limit (no actuator lag). At a stopping point the train
dwells until ``max(actual arrival + dwell, scheduled departure)``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numba
import numpy as np

from . import dynamics
from .ato_driver import AtoPidConfig, ato_leg_kernel, kernel_params
from .dynamics import train_step
from .errors import SimError
from .planner import LegPlan
from .trains import TrainSpec

#: a departure this much later than scheduled makes the driver replan the leg to recover [s]
REPLAN_DELAY_S = 0.5


@dataclass(frozen=True)
class DriverConfig:
    """Speed tracker and stop logic."""

    kp_per_s: float = 1.0  #: proportional gain: acceleration per speed error [1/s]
    ki_per_s2: float = 0.15  #: integral gain [1/s^2]
    stop_tolerance_m: float = 1.0  #: a standstill this close to the stopping point counts as arrived [m]
    holding_speed_mps: float = (
        0.15  #: below this speed within the stop tolerance the brake stops the train [m/s]
    )
    preview_factor: float = 1.0  #: look-ahead in units of the jerk build-up time a / (2 j) [-]
    max_leg_overrun_s: float = 900.0  #: a leg taking this much longer than planned is an error [s]


@dataclass(frozen=True)
class LegSchedule:
    """One leg to drive, with its timetable."""

    plan: LegPlan
    departure_s: float  #: scheduled departure from the leg's first stop [s from scenario start]
    min_dwell_s: float  #: minimum dwell at the leg's first stop before departing [s]
    from_name: str  #: name of the stop the leg starts at
    to_name: str  #: name of the stop the leg ends at
    arrival_s: float | None  #: scheduled arrival at the leg's last stop [s], None if not timetabled
    pass_names: tuple[str, ...] = ()  #: names of the passing points inside the leg
    pass_scheduled_s: tuple[float | None, ...] = ()  #: scheduled passing times [s]
    #: plans the leg again for (running time [s], delay [s]) when the train departs late (None: keep the plan)
    replan: Callable[[float, float], LegPlan] | None = None


@dataclass
class Trajectory:
    """Truth trajectory at the truth rate (arrays of equal length) and the driving events."""

    dt_s: float
    t_s: np.ndarray
    s_m: np.ndarray
    v_mps: np.ndarray
    a_mps2: np.ndarray
    direction: np.ndarray  #: +1 / -1: sense of travel along the arc length at each sample
    events: list[tuple[float, str, str]]  #: (t [s from start], kind, detail)


@numba.njit(cache=True)
def _leg_kernel(state, params, vp, ap, fg_arr, fc_arr, out_s, out_v, out_a, k0, k_limit, k_overrun):
    """Drive one leg from ``state`` = [s, v, u_prev] at step ``k0`` (see module doc).

    ``params`` = [dt, s0, direction, length, inv_dx, preview_s, kp, ki, m_eff, jerk_df, brake_n, A, B, C,
    traction_const, power, holding_speed, stop_tol, plan_decel, mass, rot_factor]. Writes one row per
    step into ``out_*`` and returns (steps written, status): 0 arrived, 1 time limit, 2 overrun.
    """
    dt, s0, d, length, inv_dx, preview_s = params[0], params[1], params[2], params[3], params[4], params[5]
    kp, ki, m_eff, jerk_df, brake_n = params[6], params[7], params[8], params[9], params[10]
    a_davis, b_davis, c_davis, trac_const, power = params[11], params[12], params[13], params[14], params[15]
    hold_v, stop_tol, plan_decel = params[16], params[17], params[18]
    s, v, u_prev = state[0], state[1], state[2]
    integ = 0.0
    n_grid = vp.size
    n = 0
    k = k0
    while True:
        if k >= k_limit:
            state[0], state[1], state[2] = s, v, u_prev
            return n, 1
        x = d * (s - s0)
        if v == 0.0 and x >= length - stop_tol:
            state[0], state[1], state[2] = s, v, u_prev
            return n, 0
        if k >= k_overrun:
            state[0], state[1], state[2] = s, v, u_prev
            return n, 2
        # reference speed and feedforward at the previewed distance (linear interpolation)
        xp = x + v * preview_s
        fi = xp * inv_dx
        if fi <= 0.0:
            i, frac = 0, 0.0
        elif fi >= n_grid - 1:
            i, frac = n_grid - 2, 1.0
        else:
            i = int(fi)
            frac = fi - i
        if xp >= length:
            v_ref, a_ff = 0.0, -plan_decel
        else:
            v_ref = vp[i] + (vp[i + 1] - vp[i]) * frac
            a_ff = ap[i] + (ap[i + 1] - ap[i]) * frac
        # grade and curve forces at the current position
        ix = int(x * inv_dx + 0.5)
        ix = min(max(ix, 0), n_grid - 1)
        fg = fg_arr[ix]
        fc = fc_arr[ix]
        err = v_ref - v
        a_cmd = a_ff + kp * err + ki * integ
        f_res = a_davis + b_davis * v + c_davis * v * v if v > 0.0 else 0.0
        u_des = m_eff * a_cmd + f_res + fg + fc
        if v < hold_v and x >= length - stop_tol:
            u_des = -brake_n  # final stop: holding brake
        u_max = trac_const if v <= 1e-6 else min(trac_const, power / v)
        u = min(max(u_des, -brake_n), u_max)
        saturated = u != u_des
        u = min(max(u, u_prev - jerk_df), u_prev + jerk_df)
        if not saturated:
            integ += err * dt
        u_prev = u
        # M_eff dv/dt = u - Davis - grade - curve; at rest the brakes hold the train (no rollback)
        a, v_next = train_step(u, v, fg, fc, a_davis, b_davis, c_davis, m_eff, dt)
        out_s[n] = s
        out_v[n] = v
        out_a[n] = a
        n += 1
        s = s + d * (v * dt + 0.5 * a * dt * dt)
        v = v_next
        k += 1


def drive(
    spec: TrainSpec,
    legs: list[LegSchedule],
    *,
    dt_s: float,
    tail_s: float = 5.0,
    max_time_s: float | None = None,
    driver: DriverConfig | AtoPidConfig | None = None,
) -> Trajectory:
    """Simulate the train through ``legs`` (see module doc). ``max_time_s`` truncates the run.

    ``driver``: :class:`~interface_modules.ato_driver.AtoPidConfig` (the seed's PIDGS with actuator
    lag; None: its defaults) or :class:`DriverConfig` (the earlier feedforward + PI driver).
    """
    if not legs:
        raise SimError("a journey needs at least two stopping points")
    cfg = driver or AtoPidConfig()
    ato = isinstance(cfg, AtoPidConfig)
    if ato:
        preview_s = cfg.preview_s(spec.plan_accel_mps2, spec.plan_decel_mps2, spec.jerk_limit_mps3)
    else:
        a_plan = max(spec.plan_accel_mps2, spec.plan_decel_mps2)
        preview_s = cfg.preview_factor * a_plan / (2.0 * spec.jerk_limit_mps3)  # the original's order
    k_limit = np.iinfo(np.int64).max if max_time_s is None else int(np.ceil(max_time_s / dt_s - 1e-9))
    adhesion = spec.adhesion_coefficient * spec.adhesive_mass_fraction * spec.mass_kg * 9.80665
    chunks_s: list[np.ndarray] = []
    chunks_v: list[np.ndarray] = []
    chunks_a: list[np.ndarray] = []
    chunks_d: list[np.ndarray] = []
    events: list[tuple[float, str, str]] = []
    k = 0
    state = np.array([legs[0].plan.s_start_m, 0.0, 0.0, 0.0])  # s, v, commanded force, applied force
    arrived_t = 0.0
    prev_dir = legs[0].plan.direction
    truncated = False

    def hold(k_end: int, direction: int) -> bool:
        nonlocal k
        k_stop = min(k_end, k_limit)
        if k_stop > k:
            m = k_stop - k
            chunks_s.append(np.full(m, state[0]))
            chunks_v.append(np.zeros(m))
            chunks_a.append(np.zeros(m))
            chunks_d.append(np.full(m, direction, dtype=np.int8))
            k = k_stop
        return k_end <= k_limit

    for leg in legs:
        plan = leg.plan
        depart_t = max(arrived_t + leg.min_dwell_s, leg.departure_s)
        if not hold(int(np.ceil(depart_t / dt_s - 1e-9)), prev_dir):
            truncated = True
            break
        late_s = k * dt_s - leg.departure_s
        if leg.replan is not None and leg.arrival_s is not None and late_s > REPLAN_DELAY_S:
            # departed late: plan to recover the delay (as far as the line and the train allow)
            plan = leg.replan(max(leg.arrival_s - k * dt_s, 1.0), late_s)
        if plan.direction != prev_dir:
            events.append((k * dt_s, "reverse", f"cab change at {leg.from_name}"))
        prev_dir = plan.direction
        events.append((k * dt_s, "depart", f"{leg.from_name} (scheduled {leg.departure_s:.1f} s)"))
        state[1] = 0.0
        state[2] = 0.0  # holding brake released
        state[3] = 0.0
        params = np.array(
            [
                dt_s,
                plan.s_start_m,
                float(plan.direction),
                plan.length_m,
                1.0 / plan.dx_m,
                preview_s,
                0.0 if ato else cfg.kp_per_s,
                0.0 if ato else cfg.ki_per_s2,
                spec.effective_mass_kg,
                spec.effective_mass_kg * spec.jerk_limit_mps3 * dt_s,
                dynamics.brake_limit_n(spec),
                spec.davis_a_n,
                spec.davis_b_n_per_mps,
                spec.davis_c_n_per_mps2,
                min(spec.max_tractive_effort_n, adhesion),
                spec.max_power_w,
                cfg.holding_speed_mps,
                cfg.stop_tolerance_m,
                spec.plan_decel_mps2,
            ]
        )
        if ato:
            params = kernel_params(cfg, params)
        k_overrun = k + int((plan.run_time_s + cfg.max_leg_overrun_s) / dt_s)
        size = min(k_overrun, k_limit) - k + 2
        out_s, out_v, out_a = np.empty(size), np.empty(size), np.empty(size)
        fg = np.asarray(dynamics.grade_force_n(spec, plan.grade), dtype=float)
        fc = np.asarray(dynamics.curve_resistance_n(spec, plan.curvature_per_m), dtype=float)
        k_start = k
        kernel = ato_leg_kernel if ato else _leg_kernel
        n, status = kernel(
            state, params, plan.v_mps, plan.a_ff_mps2, fg, fc, out_s, out_v, out_a, k, k_limit, k_overrun
        )
        chunks_s.append(out_s[:n])
        chunks_v.append(out_v[:n])
        chunks_a.append(out_a[:n])
        chunks_d.append(np.full(n, plan.direction, dtype=np.int8))
        k += n
        events.extend(_pass_events(leg, plan, out_s[:n], out_v[:n], k_start, dt_s))
        if status == 2:
            raise SimError(f"train did not reach {leg.to_name} within {cfg.max_leg_overrun_s:.0f} s of plan")
        if status == 1:
            truncated = True
            break
        arrived_t = k * dt_s
        x_end = plan.direction * (state[0] - plan.s_start_m)
        detail = f"{leg.to_name} stop error {x_end - plan.length_m:+.2f} m"
        if leg.arrival_s is not None:
            detail += f" (scheduled {leg.arrival_s:.1f} s, {arrived_t - leg.arrival_s:+.1f} s)"
        events.append((arrived_t, "arrive", detail))
    if not truncated:
        hold(k + int(round(tail_s / dt_s)), prev_dir)
    cat = np.concatenate
    n_total = k
    return Trajectory(
        dt_s=dt_s,
        t_s=np.arange(n_total) * dt_s,
        s_m=cat(chunks_s) if chunks_s else np.empty(0),
        v_mps=cat(chunks_v) if chunks_v else np.empty(0),
        a_mps2=cat(chunks_a) if chunks_a else np.empty(0),
        direction=cat(chunks_d) if chunks_d else np.empty(0, dtype=np.int8),
        events=events,
    )


def _pass_events(leg: LegSchedule, plan: LegPlan, s: np.ndarray, v: np.ndarray, k_start: int, dt_s: float):
    """Events of the passing points the leg went through."""
    out = []
    x = plan.direction * (s - plan.s_start_m)
    for j, x_p in enumerate(plan.pass_x_m):
        hit = np.flatnonzero(x >= x_p)
        if hit.size == 0:
            continue
        i = int(hit[0])
        t = (k_start + i) * dt_s
        name = leg.pass_names[j] if j < len(leg.pass_names) else "pass"
        sched = leg.pass_scheduled_s[j] if j < len(leg.pass_scheduled_s) else None
        detail = f"{name} at {v[i] * 3.6:.1f} km/h"
        if sched is not None:
            detail += f" (scheduled {sched:.1f} s, {t - sched:+.1f} s)"
        out.append((t, "pass", detail))
    return out
