"""Plausibility of GROUND TRUTH and of the published arc length (sans-I/O; docs/listener.md, "Plausibility").

- :func:`line_limits`: each line's length and maximum speed. The track database has no speed-limit
  table; a line's ``maxspeed`` tag (OSM convention: km/h, or ``"<n> mph"``/``"<n> knots"``) in its
  ``properties`` is used when present, else ``plausibility.max_speed_mps``.
- :class:`GroundTruthGuard`: a GROUND TRUTH that disagrees with a NOMINAL filter (another line, or an
  arc length outside the filter's interval once the estimate is carried to the GROUND TRUTH's time) is
  not applied until it is confirmed: by a second GROUND TRUTH consistent with it (same line, the first
  carried forward at its speed, within ``gt_confirm_tolerance_m``, within ``gt_confirm_window_s``), or
  by the filter reporting standstill. One further than ``gt_confirm_window_s`` in time from the
  filter's state is never applied while the filter is NOMINAL (a corrupted epoch would drag the filter
  there). While the filter is not NOMINAL every GROUND TRUTH is applied, as before.
- :class:`OutputGuard`: the published arc length stays on its line ([-arc_margin_m, length +
  arc_margin_m]) and moves, from one sent output to the next on the same line, no more than
  ``max_speed x speed_margin x dt + step_allowance_m + 3 sigma`` (sigma of the last sent output).
  An output that violates either is not sent; the pipeline reports the status DEGRADED with the reason
  ``arc_off_line`` or ``arc_implausible_step`` meanwhile. An accepted (re)initialisation restarts the
  comparison. The rule is written once, in :mod:`listener.guard_core` (compiled kernels), which the
  fast replay runs over every new estimate in one loop (:meth:`OutputGuard.first_refused`).
"""

from __future__ import annotations

import math
import re
from typing import Any

import numpy as np

from listener import guard_core
from listener.config import PlausibilityConfig

OFF_LINE = "arc_off_line"
IMPLAUSIBLE_STEP = "arc_implausible_step"
_NOMINAL = 1
_SPEED = re.compile(r"^\s*([0-9]+(?:\.[0-9]+)?)\s*(km/h|kmh|kph|mph|knots)?\s*$")
_UNIT = {None: 1 / 3.6, "km/h": 1 / 3.6, "kmh": 1 / 3.6, "kph": 1 / 3.6, "mph": 0.44704, "knots": 0.514444}


def parse_maxspeed(value: Any) -> float | None:
    """An OSM ``maxspeed`` value in m/s (``"70"``, ``"70 km/h"``, ``"45 mph"``); None when not a speed."""
    if isinstance(value, bool):
        return None
    if isinstance(value, int | float):
        v = float(value) / 3.6
    elif isinstance(value, str):
        m = _SPEED.match(value.lower())
        if m is None:
            return None
        v = float(m.group(1)) * _UNIT[m.group(2)]
    else:
        return None
    return v if math.isfinite(v) and v > 0.0 else None


def line_limits(track, default_max_speed_mps: float) -> dict[int, tuple[float, float]]:
    """line_id -> (length [m], maximum speed [m/s]) of every line of ``track``."""
    out = {}
    for info in track.lines():
        v = parse_maxspeed((info.properties or {}).get("maxspeed"))
        out[int(info.line_id)] = (float(info.length_m), default_max_speed_mps if v is None else v)
    return out


class GroundTruthGuard:
    """Holds a GROUND TRUTH that disagrees with a NOMINAL filter until it is confirmed."""

    def __init__(self, config: PlausibilityConfig | None = None, default_line: int | None = None) -> None:
        self.cfg = config or PlausibilityConfig()
        self.default_line = default_line
        self.held = None  #: the unconfirmed InitMeas
        self.counters = {"held": 0, "confirmed_by_second": 0, "confirmed_by_standstill": 0, "far_in_time": 0}

    def _line(self, meas) -> int | None:
        return self.default_line if meas.line_id is None else int(meas.line_id)

    def admit(self, meas, est) -> tuple[bool, dict[str, Any] | None]:
        """Whether the GROUND TRUTH ``meas`` (an InitMeas) may go to the filter, whose estimate is
        ``est``; with an event dict (``{"event": ..., ...}``) when it was held or confirmed."""
        if not self.cfg.enabled or est is None or int(est.status) != _NOMINAL:
            self.held = None
            return True, None
        t, s = float(meas.t_s), float(meas.arc_length_m)
        dt = t - est.epoch_s
        fields = {"arc_length_m": s, "line_id": self._line(meas), "epoch": t,
                  "filter_arc_length_m": est.arc_length_m, "filter_line_id": est.line_id}
        if not (math.isfinite(t) and math.isfinite(s)) or abs(dt) > self.cfg.gt_confirm_window_s:
            self.counters["far_in_time"] += 1
            self.counters["held"] += 1
            self.held = None
            return False, {"event": "ground_truth_rejected", "why": "epoch far from the filter's time",
                           "dt_s": dt if math.isfinite(dt) else None, **fields}
        direction = est.direction if est.direction else 0
        predicted = est.arc_length_m + direction * est.speed_mps * dt
        half = max(est.interval_high_m - est.arc_length_m, est.arc_length_m - est.interval_low_m)
        same_line = self._line(meas) == est.line_id
        if same_line and abs(s - predicted) <= half:
            self.held = None
            return True, None
        if "standstill" in est.reasons:
            self.counters["confirmed_by_standstill"] += 1
            self.held = None
            return True, {"event": "ground_truth_confirmed", "by": "standstill", **fields}
        prev = self.held
        if prev is not None and self._consistent(prev, meas):
            self.counters["confirmed_by_second"] += 1
            self.held = None
            return True, {"event": "ground_truth_confirmed", "by": "second ground truth", **fields}
        self.held = meas
        self.counters["held"] += 1
        return False, {"event": "ground_truth_unconfirmed", "disagreement_m": s - predicted if same_line
                       else None, "interval_half_m": half, **fields}

    def _consistent(self, a, b) -> bool:
        dt = float(b.t_s) - float(a.t_s)
        if self._line(a) != self._line(b) or not 0.0 <= dt <= self.cfg.gt_confirm_window_s:
            return False
        tol = self.cfg.gt_confirm_tolerance_m
        moved = float(a.speed_mps) * dt
        ds = float(b.arc_length_m) - float(a.arc_length_m)
        return min(abs(ds - moved), abs(ds + moved)) <= tol  # GROUND TRUTH has no sense of travel


class OutputGuard:
    """Vets each output's arc length against its line and the last sent output (the rule is
    :mod:`listener.guard_core`'s compiled kernels, over this guard's state)."""

    def __init__(
        self, limits: dict[int, tuple[float, float]], config: PlausibilityConfig | None = None
    ) -> None:
        self.cfg = config or PlausibilityConfig()
        self.limits = limits
        self._g, self._gi = guard_core.new_state(limits, self.cfg)
        self.counters = {OFF_LINE: 0, IMPLAUSIBLE_STEP: 0}

    def reset(self) -> None:
        """An accepted (re)initialisation: the next output is not compared with the last one."""
        guard_core.reset(self._g)

    def check(self, est) -> str | None:
        """The reason ``est`` may not be published, or None (pure: nothing is counted)."""
        if not self.cfg.enabled or est.line_id is None:
            return None
        g, gi = self._g, self._gi
        return _REASON[guard_core.check(g, gi, int(est.line_id), float(est.epoch_s), float(est.arc_length_m))]

    def count(self, reason: str) -> None:
        self.counters[reason] = self.counters.get(reason, 0) + 1

    def sent(self, est) -> None:
        line = est.line_id
        guard_core.sent(self._g, self._gi, line is not None, 0 if line is None else int(line),
                        float(est.epoch_s), float(est.arc_length_m), float(est.sigma_s_m))

    def first_refused(self, line_id: np.ndarray, epoch_s: np.ndarray, arc_length_m: np.ndarray,
                      sigma_s_m: np.ndarray) -> int:
        """Outputs sent one after the other (``line_id`` -1: none), each vetted as the resilience stage
        vets one (:meth:`check` when its epoch and arc length are finite, then :meth:`sent`), in one
        compiled loop: the index of the first refused, or -1 (the guard is then left after the last)."""
        f = np.ascontiguousarray
        return int(guard_core.first_refused(self._g, self._gi, f(line_id, dtype=np.int64),
                                            f(epoch_s, dtype=np.float64), f(arc_length_m, dtype=np.float64),
                                            f(sigma_s_m, dtype=np.float64)))


_REASON = {guard_core.OK: None, guard_core.OFF_LINE: OFF_LINE, guard_core.IMPLAUSIBLE_STEP: IMPLAUSIBLE_STEP}
