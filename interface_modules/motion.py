"""The driver and the truth trajectory: journey profile -> truth (time, arc length, speed, acceleration).

Integration scheme (what the sensor models and the tests rely on): time advances in fixed steps
``dt``; over step ``k`` (from ``t_k`` to ``t_k + dt``) the train's acceleration ``a_k`` is constant,
so ``v_{k+1} = v_k + a_k dt`` and ``d_{k+1} = d_k + v_k dt + a_k dt^2 / 2`` (``d`` = distance travelled;
arc length ``s = s_start + direction * d`` within a leg). A step that would make the speed negative is
shortened to stop exactly at 0 (``a_k = -v_k / dt``). The truth arrays store ``t_k, s_k, v_k, a_k``.

The driver follows the leg's planned profile in space (``v_ref(x)``, ``a_ff(x) = v dv/dx``) with a
feedforward + PI speed tracker; the commanded force adds the known resistances, is clipped to the
traction envelope and the service brake, and its rate is limited by the jerk limit. At a stopping
point the train dwells until ``max(actual arrival + dwell, scheduled departure)``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from . import dynamics
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


def drive(
    spec: TrainSpec,
    legs: list[LegSchedule],
    *,
    dt_s: float,
    tail_s: float = 5.0,
    max_time_s: float | None = None,
    driver: DriverConfig | None = None,
) -> Trajectory:
    """Simulate the train through ``legs`` (see module doc). ``max_time_s`` truncates the run."""
    if not legs:
        raise SimError("a journey needs at least two stopping points")
    cfg = driver or DriverConfig()
    m_eff = spec.effective_mass_kg
    jerk_df = m_eff * spec.jerk_limit_mps3 * dt_s
    brake_n = dynamics.brake_limit_n(spec)
    a_davis, b_davis, c_davis = spec.davis_a_n, spec.davis_b_n_per_mps, spec.davis_c_n_per_mps2
    kp, ki = cfg.kp_per_s, cfg.ki_per_s2
    # preview: the jerk limit needs about a/(2 j) to build up an acceleration change
    preview_s = (
        cfg.preview_factor * max(spec.plan_accel_mps2, spec.plan_decel_mps2) / (2.0 * spec.jerk_limit_mps3)
    )
    limit_t = float("inf") if max_time_s is None else float(max_time_s)

    ts: list[float] = []
    ss: list[float] = []
    vs: list[float] = []
    accs: list[float] = []
    dirs: list[int] = []
    events: list[tuple[float, str, str]] = []

    k = 0
    s = legs[0].plan.s_start_m
    v = 0.0
    u_prev = 0.0
    arrived_t = 0.0
    prev_dir = legs[0].plan.direction
    truncated = False

    def hold_until(t_end: float, direction: int) -> bool:
        nonlocal k
        while k * dt_s < t_end - 1e-9:
            t = k * dt_s
            if t >= limit_t:
                return False
            ts.append(t)
            ss.append(s)
            vs.append(0.0)
            accs.append(0.0)
            dirs.append(direction)
            k += 1
        return True

    for leg in legs:
        plan = leg.plan
        depart_t = max(arrived_t + leg.min_dwell_s, leg.departure_s)
        if not hold_until(depart_t, prev_dir):
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
        u_prev = 0.0  # holding brake released
        integ = 0.0
        x_grid_n = plan.x_m.size
        inv_dx = 1.0 / plan.dx_m
        vp = plan.v_mps.tolist()
        ap = plan.a_ff_mps2.tolist()
        f_grade = dynamics.grade_force_n(spec, plan.grade).tolist()
        f_curve = dynamics.curve_resistance_n(spec, plan.curvature_per_m).tolist()
        length = plan.length_m
        s0 = plan.s_start_m
        d = plan.direction
        pass_next = 0
        n_pass = len(plan.pass_x_m)
        t_leg0 = k * dt_s
        t_leg_limit = t_leg0 + plan.run_time_s + cfg.max_leg_overrun_s
        while True:
            t = k * dt_s
            if t >= limit_t:
                truncated = True
                break
            x = d * (s - s0)
            while pass_next < n_pass and x >= plan.pass_x_m[pass_next]:
                sched = leg.pass_scheduled_s[pass_next] if pass_next < len(leg.pass_scheduled_s) else None
                name = leg.pass_names[pass_next] if pass_next < len(leg.pass_names) else "pass"
                detail = f"{name} at {v * 3.6:.1f} km/h" + (
                    f" (scheduled {sched:.1f} s, {t - sched:+.1f} s)" if sched is not None else ""
                )
                events.append((t, "pass", detail))
                pass_next += 1
            if v == 0.0 and x >= length - cfg.stop_tolerance_m:
                arrived_t = t
                sched = leg.arrival_s
                detail = f"{leg.to_name} stop error {x - length:+.2f} m" + (
                    f" (scheduled {sched:.1f} s, {t - sched:+.1f} s)" if sched is not None else ""
                )
                events.append((t, "arrive", detail))
                break
            if t > t_leg_limit:
                raise SimError(
                    f"train did not reach {leg.to_name} within {cfg.max_leg_overrun_s:.0f} s of plan"
                )
            # reference speed and feedforward at the current distance (linear interpolation)
            fi = (x + v * preview_s) * inv_dx
            if fi <= 0.0:
                i, frac = 0, 0.0
            elif fi >= x_grid_n - 1:
                i, frac = x_grid_n - 2, 1.0
            else:
                i = int(fi)
                frac = fi - i
            if x + v * preview_s >= length:
                v_ref, a_ff = 0.0, -spec.plan_decel_mps2
            else:
                v_ref = vp[i] + (vp[i + 1] - vp[i]) * frac
                a_ff = ap[i] + (ap[i + 1] - ap[i]) * frac
            fg = f_grade[i]
            fc = f_curve[i]
            err = v_ref - v
            a_cmd = a_ff + kp * err + ki * integ
            f_res = (a_davis + b_davis * v + c_davis * v * v) if v > 0.0 else 0.0
            u_des = m_eff * a_cmd + f_res + fg + fc
            if v < cfg.holding_speed_mps and x >= length - cfg.stop_tolerance_m:
                u_des = -brake_n  # final stop: holding brake
            u_max = dynamics.traction_limit_n(spec, v)
            u = min(max(u_des, -brake_n), u_max)
            saturated = u != u_des
            u = min(max(u, u_prev - jerk_df), u_prev + jerk_df)
            if not saturated:
                integ += err * dt_s
            u_prev = u
            a = dynamics.acceleration_mps2(spec, u, v, fg, fc)
            v_next = v + a * dt_s
            if v_next < 0.0:
                a = -v / dt_s
                v_next = 0.0
            ts.append(t)
            ss.append(s)
            vs.append(v)
            accs.append(a)
            dirs.append(d)
            s = s + d * (v * dt_s + 0.5 * a * dt_s * dt_s)
            v = v_next
            k += 1
        if truncated:
            break
    if not truncated:
        hold_until(k * dt_s + tail_s, prev_dir)
    return Trajectory(
        dt_s=dt_s,
        t_s=np.asarray(ts, dtype=float),
        s_m=np.asarray(ss, dtype=float),
        v_mps=np.asarray(vs, dtype=float),
        a_mps2=np.asarray(accs, dtype=float),
        direction=np.asarray(dirs, dtype=np.int8),
        events=events,
    )
