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

Robustness (issue 20): a STROBE is not taken into the model when it would step the timebase (more
than ``max_step_s`` from the prediction) or, once the model has settled (``confirm_s`` after its
start), move it forward faster than the drift bound allows: its offset may exceed the settled
offset ``o_0`` by at most ``(rate - 1 + max_drift * rate) * (now - t_0) + max_jitter_s``
(SUBSET-041: 0.1 %; the upper envelope could otherwise be dragged forward a jitter allowance at a
time). ``rate`` is ``clock.rate``, or the rate the source showed while the model settled when that
is more than 2 % off (a misconfigured or accelerated source, logged as ``clock_rate_mismatch``).
Such a STROBE becomes the candidate for a new offset (counted ``unconfirmed``; every STROBE not
taken is counted ``rejected`` and dates ``trouble_at``). The candidate is adopted (the window
discarded and the estimate restarted: a sensor-set clock reset, a listener restart) only when
STROBEs agreeing with it (within ``max_step_s`` of it, carried at the rate) keep coming for
``confirm_s`` and none agrees with the current model in between: a forger interleaving shifted or
ramping STROBEs with the real ones never gets there (each real STROBE agrees with the model and
clears the candidate); a real reset does. With ``confirm_s = 0`` the second agreeing STROBE adopts
it (the rule before issue 20).
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
        self.rejected = 0  #: STROBEs not taken (a step or beyond the drift bound, not yet persisted)
        self.trouble_at: float | None = None  #: listener time of the last STROBE not taken
        self._candidate: float | None = None
        self._cand_since = 0.0  # listener time the candidate was first seen
        self._anchor_t = 0.0  # start of the model (t_0) [listener s]
        self._anchor_o = 0.0  # settled offset o_0 at t_0 [s]
        self._anchor_r = math.nan  # settled rate (NaN while settling) [sensor s per listener s]

    @property
    def synced(self) -> bool:
        """True once at least one STROBE has been seen."""
        return bool(self._samples)

    def on_strobe(self, timestamp_s: float, now: float) -> None:
        """Take one STROBE: sensor-set ``timestamp_s`` received at listener time ``now``."""
        if not math.isfinite(timestamp_s) or not math.isfinite(now):
            return
        offset = timestamp_s - now
        cfg = self._cfg
        if self._samples:
            predicted = self.offset_at(now)
            since = now - self._anchor_t
            bad = abs(offset - predicted) > cfg.max_step_s
            if not bad and since >= cfg.confirm_s:
                if math.isnan(self._anchor_r):
                    self._settle()
                r = self._anchor_r
                bad = offset > self._anchor_o + (r - 1.0 + cfg.max_drift * r) * since + cfg.max_jitter_s
            if bad:
                # a step, or faster than the drift bound: believed only once STROBEs agreeing with it
                # persist for confirm_s with none agreeing with the model (one corrupted timestamp, or a
                # forger's stream beside the real one, must not move the timebase)
                cand = self._candidate
                if cand is not None:  # agreeing with the candidate: within max_step_s of it (carried
                    # at the nominal rate), so a lone source running off the drift bound is followed
                    age = now - self._cand_since
                    r = cfg.rate if math.isnan(self._anchor_r) else self._anchor_r
                    if abs(offset - (r - 1.0) * age - cand) > cfg.max_step_s:
                        cand = None
                if cand is None:
                    self._candidate = offset
                    self._cand_since = now
                    self.unconfirmed += 1
                    self.rejected += 1
                    self.trouble_at = now
                    return
                if now - self._cand_since < cfg.confirm_s:
                    self.rejected += 1
                    self.trouble_at = now
                    return
                self._samples.clear()
                self.resets += 1
        self._candidate = None
        if not self._samples:
            self._anchor_t, self._anchor_o, self._anchor_r = now, offset, math.nan
        self._samples.append((now, offset))
        self.strobes += 1
        self._fit()

    def _settle(self) -> None:
        """End of the settling period: the rate the source has shown (the configured one unless it is
        more than 2 % off: an accelerated or misconfigured source is then judged at its own rate) and
        the least delayed offset at the model's start, o_0, on that rate."""
        pts = self._samples
        (t0, o0), (t1, o1) = pts[0], pts[-1]
        rate = self._cfg.rate
        r = rate
        if t1 > t0:
            raw = 1.0 + (o1 - o0) / (t1 - t0)
            if abs(raw - rate) > 0.02 * rate:
                r = raw
        self._anchor_r = r
        ta = self._anchor_t
        self._anchor_o = max(o - (r - 1.0) * (t - ta) for t, o in pts)

    @property
    def settled_rate(self) -> float | None:
        """The rate the drift bound is judged at (None while settling): ``clock.rate`` unless the source
        showed another one (more than 2 % off) while the model settled."""
        return None if math.isnan(self._anchor_r) else self._anchor_r

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
