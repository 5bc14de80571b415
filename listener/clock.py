"""Sensor-set timebase from STROBE: maps listener arrival times onto sensor-set time (sans-I/O).

Each STROBE carries the sensor-set time ``T_k`` at which it was sent and arrives at listener time
``now_k = T_k - offset + d_k`` with a network delay ``d_k >= d_min``. The observed offsets
``o_k = T_k - now_k = offset - d_k`` are therefore the true offset minus a positive, jittery delay:
the *largest* recent ``o_k`` is the least delayed and the best estimate (the lower-delay envelope,
as NTP's clock filter keeps the minimum-delay sample). A slow rate difference (skew) between the
listener's monotonic clock and the sensor set is estimated by the linear-programming method of Moon,
Skelly and Towsley (1999): the line lying above every ``o_k`` of the window that minimises the summed
distance to them, which is the edge of their upper convex hull spanning the window's mean time.
Jitter therefore never drags the estimate; only the minimum delay (typically tens of microseconds on
a switched Ethernet) stays as a constant bias, which is below every sensor's sampling period.

An accelerated live run (the simulator at ``--speed X``) has a sensor clock X times faster than the
listener's; ``ClockConfig.rate = X`` centres the skew bound on it (otherwise the offset would be
extrapolated flat and every gap between STROBEs would look like a step).

A step larger than ``max_step_s`` between the prediction and a new STROBE (sensor-set clock reset,
listener restart) discards the window and restarts the estimate, once a second STROBE confirms the
new offset: a single corrupted timestamp is ignored (counted as ``unconfirmed``).
"""

from __future__ import annotations

import math
from collections import deque

from listener.config import ClockConfig


class StrobeClock:
    """Estimate of ``sensor_time = now + offset(now)`` from STROBE arrivals."""

    def __init__(self, config: ClockConfig | None = None) -> None:
        self._cfg = config or ClockConfig()
        self._samples: deque[tuple[float, float]] = deque(maxlen=self._cfg.window_strobes)
        self._slope = 0.0
        self._ref_now = 0.0
        self._intercept = 0.0
        self.resets = 0  #: times the model was restarted by a clock step
        self.strobes = 0  #: STROBEs used
        self.unconfirmed = 0  #: STROBEs that disagreed with the model and were not (yet) confirmed
        self._candidate: float | None = None

    @property
    def synced(self) -> bool:
        """True once at least one STROBE has been seen."""
        return bool(self._samples)

    def on_strobe(self, timestamp_s: float, now: float) -> None:
        """Take one STROBE: sensor-set ``timestamp_s`` received at listener time ``now``."""
        if not math.isfinite(timestamp_s) or not math.isfinite(now):
            return
        offset = timestamp_s - now
        if self._samples:
            predicted = self.offset_at(now)
            if abs(offset - predicted) > self._cfg.max_step_s:
                # a step: believed only when the next STROBE confirms it (one corrupted timestamp
                # must not move the timebase)
                cand = self._candidate
                if cand is None or abs(offset - cand) > self._cfg.max_step_s:
                    self._candidate = offset
                    self.unconfirmed += 1
                    return
                self._samples.clear()
                self.resets += 1
        self._candidate = None
        self._samples.append((now, offset))
        self.strobes += 1
        self._fit()

    def _fit(self) -> None:
        pts = list(self._samples)
        ref = pts[-1][0]
        slope = 0.0
        intercept = max(o for _, o in pts)
        rate = self._cfg.rate
        if rate != 1.0:
            # an accelerated sensor clock: the offset grows by (rate - 1) s per second, from the start
            slope = rate - 1.0
            intercept = max(o - slope * (t - ref) for t, o in pts)
        if len(pts) >= 10 and pts[-1][0] - pts[0][0] >= 20.0:
            # Linear-programming skew estimate (Moon, Skelly & Towsley, 1999): the line above every
            # point that minimises the summed vertical distance is the upper-hull edge spanning the
            # mean time. Delay jitter only pushes points down, so it never moves that line.
            hull = _upper_hull(pts)
            t_mean = sum(t for t, _ in pts) / len(pts)
            for (ta, oa), (tb, ob) in zip(hull, hull[1:], strict=False):
                if ta <= t_mean <= tb and tb > ta:
                    slope = (ob - oa) / (tb - ta)
                    break
            if rate == 1.0:
                slope = max(-1e-3, min(1e-3, slope))  # |skew| <= 1000 ppm: anything larger is not a clock
            else:  # the same bound around the nominal rate
                slope = max(rate - 1.0 - 1e-3 * rate, min(rate - 1.0 + 1e-3 * rate, slope))
            intercept = max(o - slope * (t - ref) for t, o in pts)
        self._intercept = intercept
        self._slope = slope
        self._ref_now = ref

    def offset_at(self, now: float) -> float:
        """Estimated ``sensor_time - now`` at listener time ``now`` [s]."""
        return self._intercept + self._slope * (now - self._ref_now)

    def to_sensor_time(self, now: float) -> float | None:
        """Sensor-set time of a measurement that arrived at ``now``; None before the first STROBE."""
        if not self._samples:
            return None
        return now + self.offset_at(now)


def _upper_hull(points: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """Upper convex hull of points sorted by time (Andrew's monotone chain)."""
    hull: list[tuple[float, float]] = []
    for p in points:
        while len(hull) >= 2:
            (x1, y1), (x2, y2) = hull[-2], hull[-1]
            # drop the middle point if it lies on or below the segment from hull[-2] to p
            if (x2 - x1) * (p[1] - y1) - (y2 - y1) * (p[0] - x1) >= 0:
                hull.pop()
            else:
                break
        hull.append(p)
    return hull
