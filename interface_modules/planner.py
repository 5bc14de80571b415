"""Speed planning for one leg of a journey profile (stop to stop), LSPB in space.

The ATO seed (section 5) plans a point-to-point trajectory with Linear Segments with Parabolic
Blends: accelerate, cruise, brake, respecting the arrival times of the journey profile and the
speed limits of the section. Here the profile is built as a speed-versus-distance curve on a
regular grid ``x`` (distance travelled from the leg's start):

1. the cap ``v_cap(x) = min(line limit, speed restrictions, curve limit, train maximum, cruise cap)``;
2. a backward pass with the constant planning deceleration ``b``:
   ``v(x)^2 <= min_{y >= x}(v_cap(y)^2 + 2 b (y - x))`` (a suffix minimum, vectorised);
3. a forward pass with the speed-dependent acceleration ``a(v)`` (traction envelope: effort, power,
   adhesion, minus Davis resistance): with ``Phi(v) = int_0^v u / a(u) du`` (distance needed from
   standstill to ``v``), ``Phi(v(x)) <= min_{y <= x}(Phi(v(y)) + x - y)`` (a prefix minimum).

Both passes are exact for their acceleration laws and cost O(n) numpy operations, so choosing the
cruise cap of each timing section by bisection (to arrive at the scheduled time) is cheap.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import dynamics
from .errors import ScenarioError
from .trains import TrainSpec

#: bisection iterations when fitting a cruise cap to a scheduled time
_BISECT_STEPS = 40
#: lowest cruise cap the planner will consider [m/s]
MIN_CRUISE_MPS = 0.3


@dataclass(frozen=True)
class LegPlan:
    """Planned speed profile of one leg (standstill to standstill)."""

    s_start_m: float  #: track arc length where the leg starts [m]
    s_end_m: float  #: track arc length of the stopping point [m]
    direction: int  #: +1 if arc length increases along the leg, -1 otherwise
    dx_m: float  #: grid step of ``x`` [m]
    x_m: np.ndarray  #: distance travelled from the start of the leg [m]
    v_mps: np.ndarray  #: planned speed at each ``x`` [m/s]
    a_ff_mps2: np.ndarray  #: planned acceleration ``v dv/dx`` at each ``x`` [m/s^2]
    grade: np.ndarray  #: grade in the direction of travel at each ``x`` [-]
    curvature_per_m: np.ndarray  #: curvature in the direction of travel at each ``x`` [1/m]
    run_time_s: float  #: planned running time [s]
    pass_x_m: tuple[float, ...]  #: distance of the passing points inside the leg [m]
    pass_planned_s: tuple[float, ...]  #: planned time from departure to each passing point [s]

    @property
    def length_m(self) -> float:
        """Leg length [m]."""
        return float(self.x_m[-1])


def accel_distance_table(spec: TrainSpec, v_top_mps: float, n: int = 2000) -> tuple[np.ndarray, np.ndarray]:
    """Tabulate ``Phi(v)``: distance [m] to accelerate from rest to ``v`` [m/s] under the planning law.

    The planning acceleration is ``min(plan_accel, 0.9 * traction envelope on level track)``, floored
    at 0.05 m/s^2 so that every speed below ``v_top`` is reachable.
    """
    v = np.linspace(0.0, max(v_top_mps, 0.5), n)
    a = np.minimum(spec.plan_accel_mps2, 0.9 * dynamics.max_accel_mps2(spec, v))
    a = np.maximum(a, 0.05)
    integrand = v / a
    phi = np.concatenate(([0.0], np.cumsum(0.5 * (integrand[1:] + integrand[:-1]) * np.diff(v))))
    return v, phi


def lspb_profile_mps(
    x_m: np.ndarray, v_cap_mps: np.ndarray, decel_mps2: float, phi_table: tuple[np.ndarray, np.ndarray]
) -> np.ndarray:
    """Speed profile from standstill at ``x[0]`` to standstill at ``x[-1]`` under the cap (see module doc)."""
    cap = np.asarray(v_cap_mps, dtype=float).copy()
    cap[0] = 0.0
    cap[-1] = 0.0
    # backward pass: braking curves from every restriction (suffix minimum)
    q = cap * cap + 2.0 * decel_mps2 * x_m
    q_min = np.minimum.accumulate(q[::-1])[::-1]
    v_back = np.sqrt(np.maximum(q_min - 2.0 * decel_mps2 * x_m, 0.0))
    # forward pass: acceleration curves through Phi (prefix minimum)
    v_tab, phi_tab = phi_table
    phi = np.interp(v_back, v_tab, phi_tab)
    p_min = np.minimum.accumulate(phi - x_m)
    v = np.interp(p_min + x_m, phi_tab, v_tab)
    return np.minimum(v, v_back)


def travel_times_s(x_m: np.ndarray, v_mps: np.ndarray) -> np.ndarray:
    """Cumulative time [s] to reach each grid point at the profile's speed (trapezoidal in 1/v)."""
    dx = np.diff(x_m)
    vm = 0.5 * (v_mps[1:] + v_mps[:-1])
    # segments that start or end at rest: constant-acceleration time 2 dx / (v0 + v1)
    dt = 2.0 * dx / np.maximum(v_mps[1:] + v_mps[:-1], 1e-9)
    dt = np.where(vm > 0, dt, np.inf)
    return np.concatenate(([0.0], np.cumsum(dt)))


def curve_limit_mps(spec: TrainSpec, curvature_per_m: np.ndarray, dx_m: float, window_m: float) -> np.ndarray:
    """Curve speed limit held over ``window_m`` (the train's length) around each point [m/s]."""
    limit = dynamics.curve_speed_limit_mps(spec, curvature_per_m)
    half = max(int(round(0.5 * window_m / dx_m)), 0)
    if half == 0 or limit.size < 2:
        return limit
    padded = np.pad(limit, half, mode="edge")
    windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1)
    return windows.min(axis=1)


def plan_leg(
    spec: TrainSpec,
    *,
    s_start_m: float,
    s_end_m: float,
    dx_m: float,
    limit_at,
    grade_at,
    curvature_at,
    scheduled_run_s: float | None,
    pass_points: tuple[tuple[float, float | None], ...] = (),
    curve_window_m: float = 30.0,
) -> LegPlan:
    """Plan one leg from ``s_start_m`` to ``s_end_m`` (either direction).

    ``limit_at(s)``, ``grade_at(s)`` and ``curvature_at(s)`` are vectorised functions of track arc
    length (grade and curvature in the direction of increasing arc length). ``pass_points`` are
    ``(arc length, scheduled time from departure or None)`` inside the leg; ``scheduled_run_s`` is
    the scheduled running time to the stop (None: run as fast as allowed). The cruise cap of each
    timing section is fitted by bisection so that the planned time matches the schedule; a
    schedule faster than the train can run keeps the fastest profile (the run will be late).
    """
    length = abs(s_end_m - s_start_m)
    if length < 2.0 * dx_m:
        raise ScenarioError(f"leg from {s_start_m:.1f} m to {s_end_m:.1f} m is shorter than {2 * dx_m} m")
    direction = 1 if s_end_m > s_start_m else -1
    n = int(np.ceil(length / dx_m)) + 1
    x = np.linspace(0.0, length, n)
    s = s_start_m + direction * x
    grade = direction * np.asarray(grade_at(s), dtype=float)
    curvature = direction * np.asarray(curvature_at(s), dtype=float)
    cap = np.minimum(np.asarray(limit_at(s), dtype=float), spec.max_speed_mps)
    cap = np.minimum(cap, curve_limit_mps(spec, curvature, x[1] - x[0], curve_window_m))
    phi_table = accel_distance_table(spec, float(cap.max()))

    # timing sections: boundaries at the passing points with a scheduled time, then the stop
    xs: list[float] = []
    ts: list[float | None] = []
    for s_p, t_p in pass_points:
        x_p = direction * (s_p - s_start_m)
        if not 0.0 < x_p < length:
            raise ScenarioError(
                f"passing point at {s_p:.1f} m is not inside the leg {s_start_m:.1f}-{s_end_m:.1f} m"
            )
        xs.append(x_p)
        ts.append(t_p)
    xs.append(length)
    ts.append(scheduled_run_s)
    section = np.searchsorted(np.asarray(xs[:-1]), x, side="left") if len(xs) > 1 else np.zeros(n, int)
    caps = np.full(len(xs), float(cap.max()))

    def profile(section_caps: np.ndarray) -> np.ndarray:
        return lspb_profile_mps(x, np.minimum(cap, section_caps[section]), spec.plan_decel_mps2, phi_table)

    def time_to(v: np.ndarray, x_target: float) -> float:
        return float(np.interp(x_target, x, travel_times_s(x, v)))

    for i, (x_i, t_i) in enumerate(zip(xs, ts, strict=True)):
        if t_i is None:
            continue
        fastest = time_to(profile(caps), x_i)
        if fastest >= t_i:
            continue  # cannot be on time: run as fast as allowed
        lo, hi = MIN_CRUISE_MPS, caps[i]
        for _ in range(_BISECT_STEPS):
            mid = 0.5 * (lo + hi)
            trial = caps.copy()
            trial[i] = mid
            if time_to(profile(trial), x_i) > t_i:
                lo = mid
            else:
                hi = mid
        caps[i] = hi
    v = profile(caps)
    a_ff = np.gradient(0.5 * v * v, x)
    times = travel_times_s(x, v)
    return LegPlan(
        s_start_m=float(s_start_m),
        s_end_m=float(s_end_m),
        direction=direction,
        dx_m=float(x[1] - x[0]),
        x_m=x,
        v_mps=v,
        a_ff_mps2=a_ff,
        grade=grade,
        curvature_per_m=curvature,
        run_time_s=float(times[-1]),
        pass_x_m=tuple(xs[:-1]),
        pass_planned_s=tuple(float(np.interp(xp, x, times)) for xp in xs[:-1]),
    )
