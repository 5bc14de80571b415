"""Journey profile -> planned legs: split the points at the stops and plan each leg (see ``planner``)."""

from __future__ import annotations

import numpy as np

from .errors import ScenarioError
from .motion import LegSchedule
from .planner import plan_leg
from .scenario import Scenario
from .trains import KMH

#: planning grid step [m]
PLAN_STEP_M = 0.5


def speed_limit_fn(sc: Scenario):
    """Vectorised line speed limit [m/s] as a function of arc length (line speed and restrictions)."""
    line = sc.track.line_speed_kmh * KMH
    zones = [(z.from_m, z.to_m, z.limit_kmh * KMH) for z in sc.track.speed_limits]

    def limit_at(s_m):
        s = np.asarray(s_m, dtype=float)
        out = np.full(s.shape, line)
        for a, b, lim in zones:
            out = np.where((s >= a) & (s <= b), np.minimum(out, lim), out)
        return out

    return limit_at


def build_legs(sc: Scenario, track) -> list[LegSchedule]:
    """Plan every leg of the scenario's journey on ``track``."""
    pts = sc.journey
    for i, p in enumerate(pts):
        if not 0.0 <= p.s_m <= track.length_m:
            raise ScenarioError(
                f"journey.points[{i}] at {p.s_m:.1f} m is outside the line (0..{track.length_m:.1f} m)"
            )
    stop_idx = [i for i, p in enumerate(pts) if p.kind == "stop"]
    limit_at = speed_limit_fn(sc)
    legs: list[LegSchedule] = []
    for a, b in zip(stop_idx[:-1], stop_idx[1:], strict=True):
        start, end = pts[a], pts[b]
        inner = pts[a + 1 : b]
        direction = 1 if end.s_m > start.s_m else -1
        for p in inner:
            if not (direction * (p.s_m - start.s_m) > 0 and direction * (end.s_m - p.s_m) > 0):
                raise ScenarioError(
                    f"passing point {p.name or p.s_m} is not between {start.name} and {end.name}"
                )
        departure = (
            start.departure_s if start.departure_s is not None else (start.arrival_s or 0.0) + start.dwell_s
        )
        scheduled_run = None if end.arrival_s is None else end.arrival_s - departure
        if scheduled_run is not None and scheduled_run <= 0:
            raise ScenarioError(f"arrival at {end.name} is not after the departure from {start.name}")
        pass_points = tuple((p.s_m, None if p.arrival_s is None else p.arrival_s - departure) for p in inner)

        def planner(run_s, late_s=0.0, s0=start.s_m, s1=end.s_m, pp=pass_points):
            return plan_leg(
                sc.train,
                s_start_m=s0,
                s_end_m=s1,
                dx_m=PLAN_STEP_M,
                limit_at=limit_at,
                grade_at=track.grade_at,
                curvature_at=track.curvature_at,
                scheduled_run_s=run_s,
                pass_points=tuple((s, None if tp is None else max(tp - late_s, 1.0)) for s, tp in pp),
            )

        plan = planner(scheduled_run)
        legs.append(
            LegSchedule(
                plan=plan,
                departure_s=departure,
                min_dwell_s=start.dwell_s if a > 0 else 0.0,
                from_name=start.name or f"{start.s_m:.0f} m",
                to_name=end.name or f"{end.s_m:.0f} m",
                arrival_s=end.arrival_s,
                pass_names=tuple(p.name or f"{p.s_m:.0f} m" for p in inner),
                pass_scheduled_s=tuple(p.arrival_s for p in inner),
                replan=planner,
            )
        )
    return legs
