"""Timetables for journey profiles: station list -> stopping points with arrival/departure times.

Used to write the shipped scenarios (and by anyone making a new one): the running time of each
leg is the planner's fastest profile plus a running-time supplement (the margin real timetables
carry; 5-7 % is usual in European practice, UIC leaflet 451-1), rounded up to ``round_s``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .planner import plan_leg
from .scenario import JourneyPoint
from .trains import TrainSpec


@dataclass(frozen=True)
class Station:
    """A stopping place: name and arc length on the line [m]."""

    name: str
    s_m: float


def stations_from_database(
    db,
    line_id: int,
    *,
    max_offset_m: float = 15.0,
    min_spacing_m: float = 200.0,
    s_from_m: float = 0.0,
    s_to_m: float = math.inf,
) -> list[Station]:
    """One station per name along a line (the platform nearest the track), in arc-length order."""
    best: dict[str, tuple[float, float]] = {}
    for st in db.stops():
        if st.line_id != line_id or abs(st.offset_m) > max_offset_m or not s_from_m <= st.s_m <= s_to_m:
            continue
        if st.name not in best or abs(st.offset_m) < best[st.name][1]:
            best[st.name] = (st.s_m, abs(st.offset_m))
    out: list[Station] = []
    for name, (s, _) in sorted(best.items(), key=lambda kv: kv[1][0]):
        if out and s - out[-1].s_m < min_spacing_m:
            continue
        out.append(Station(name, s))
    return out


def make_timetable(
    spec: TrainSpec,
    track,
    stations: list[Station],
    limit_at,
    *,
    dwell_s: float,
    supplement: float = 0.06,
    round_s: float = 10.0,
    start_s: float = 10.0,
    plan_step_m: float = 0.5,
) -> list[JourneyPoint]:
    """Stopping points with scheduled arrival/departure for ``stations`` in the given order."""
    points = [JourneyPoint(s_m=stations[0].s_m, kind="stop", name=stations[0].name, departure_s=start_s)]
    t = start_s
    for a, b in zip(stations[:-1], stations[1:], strict=True):
        plan = plan_leg(
            spec,
            s_start_m=a.s_m,
            s_end_m=b.s_m,
            dx_m=plan_step_m,
            limit_at=limit_at,
            grade_at=track.grade_at,
            curvature_at=track.curvature_at,
            scheduled_run_s=None,
        )
        run = math.ceil(plan.run_time_s * (1.0 + supplement) / round_s) * round_s
        t += run
        last = b is stations[-1]
        points.append(
            JourneyPoint(
                s_m=b.s_m,
                kind="stop",
                name=b.name,
                arrival_s=t,
                departure_s=None if last else t + dwell_s,
                dwell_s=dwell_s,
            )
        )
        t += 0.0 if last else dwell_s
    return points


def journey_toml(points: list[JourneyPoint]) -> str:
    """``[[journey.points]]`` tables for a scenario file."""
    out = []
    for p in points:
        out.append("[[journey.points]]")
        out.append(f'name = "{p.name}"')
        out.append(f"s_m = {p.s_m:.1f}")
        if p.kind != "stop":
            out.append(f'kind = "{p.kind}"')
        if p.arrival_s is not None:
            out.append(f"arrival_s = {p.arrival_s:.1f}")
        if p.departure_s is not None:
            out.append(f"departure_s = {p.departure_s:.1f}")
        if p.dwell_s:
            out.append(f"dwell_s = {p.dwell_s:.1f}")
        out.append("")
    return "\n".join(out)
