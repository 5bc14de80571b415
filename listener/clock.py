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

The arithmetic lives once, in :mod:`listener.clock_core` (compiled kernels over one state array);
this class is the listener's handle on it, and the fast replay advances the same state through
:meth:`StrobeClock.take_strobes` and :meth:`StrobeClock.sensor_times`.
"""

from __future__ import annotations

import math

import numpy as np

from listener import clock_core as K
from listener.config import ClockConfig


class StrobeClock:
    """Estimate of ``sensor_time = now + offset(now)`` from STROBE arrivals."""

    def __init__(self, config: ClockConfig | None = None) -> None:
        self._cfg = config or ClockConfig()
        self._s = K.new_state(self._cfg)  #: the whole clock (listener.clock_core's layout)

    # ------------------------------------------------------------------ the listener's calls
    def on_strobe(self, timestamp_s: float, now: float) -> None:
        """Take one STROBE: sensor-set ``timestamp_s`` received at listener time ``now``."""
        K.on_strobe(self._s, float(timestamp_s), float(now))

    def offset_at(self, now: float) -> float:
        """Estimated ``sensor_time - now`` at listener time ``now`` [s]."""
        return K.offset_at(self._s, float(now))

    def to_sensor_time(self, now: float) -> float | None:
        """Sensor-set time of a measurement that arrived at ``now``; None before the first STROBE."""
        if self._s[K.C_N] == 0.0:
            return None
        return K.sensor_time(self._s, float(now))

    @property
    def synced(self) -> bool:
        """True once at least one STROBE has been seen."""
        return bool(self._s[K.C_N] != 0.0)

    @property
    def settled_rate(self) -> float | None:
        """The rate the drift bound is judged at (None while settling): ``clock.rate`` unless the source
        showed another one (more than 2 % off) while the model settled."""
        r = float(self._s[K.C_ANCHOR_R])
        return None if math.isnan(r) else r

    @property
    def resets(self) -> int:
        """Times the model was restarted by a clock step."""
        return int(self._s[K.C_RESETS])

    @property
    def strobes(self) -> int:
        """STROBEs used."""
        return int(self._s[K.C_STROBES])

    @property
    def unconfirmed(self) -> int:
        """STROBEs that disagreed with the model and were not (yet) confirmed."""
        return int(self._s[K.C_UNCONFIRMED])

    @property
    def rejected(self) -> int:
        """STROBEs not taken (a step or beyond the drift bound, not yet persisted)."""
        return int(self._s[K.C_REJECTED])

    @property
    def trouble_at(self) -> float | None:
        """Listener time of the last STROBE not taken (None: none yet)."""
        t = float(self._s[K.C_TROUBLE])
        return None if math.isnan(t) else t

    # ------------------------------------------------------------------ many STROBEs at once (replay)
    def model(self) -> tuple[float, float, float, float]:
        """(synced, intercept, slope, ref) of the current model, as :meth:`take_strobes` records it."""
        s = self._s
        return (1.0 if s[K.C_N] != 0.0 else 0.0, float(s[K.C_INTERCEPT]), float(s[K.C_SLOPE]),
                float(s[K.C_REF]))

    def take_strobes(self, timestamp: np.ndarray, now: np.ndarray) -> np.ndarray:
        """:meth:`on_strobe` for every STROBE (``timestamp[k]`` received at ``now[k]``) in one compiled
        loop; returns the model after each, (k, 4) rows as :meth:`model`."""
        ts = np.ascontiguousarray(timestamp, dtype=np.float64)
        out = np.zeros((ts.shape[0], 4))
        K.run_strobes(self._s, ts, np.ascontiguousarray(now, dtype=np.float64), out)
        return out

    def sensor_times(self, strobes, queries) -> tuple[np.ndarray, np.ndarray]:
        """Take the STROBEs ``strobes`` = (position, timestamp, arrival) and answer the queries
        ``queries`` = (position, time a, time b) on the way, both in ascending position: the
        :meth:`to_sensor_time` (NaN for None) at each query's two times, with the clock as the STROBEs
        before its position left it. Every STROBE is taken."""
        f = np.ascontiguousarray
        q_pos = f(queries[0], dtype=np.int64)
        out_a = np.empty(q_pos.shape[0])
        out_b = np.empty(q_pos.shape[0])
        K.sensor_times(self._s, f(strobes[0], dtype=np.int64), f(strobes[1], dtype=np.float64),
                       f(strobes[2], dtype=np.float64), q_pos, f(queries[1], dtype=np.float64),
                       f(queries[2], dtype=np.float64), out_a, out_b)
        return out_a, out_b

    def samples(self) -> list[tuple[float, float]]:
        """The window: (arrival, offset) of each STROBE in it, oldest first."""
        t, o = K.window_of(self._s)
        return list(zip(t.tolist(), o.tolist(), strict=True))

    def state(self) -> np.ndarray:
        """A copy of the whole clock state (the array :mod:`listener.clock_core` works on): two clocks
        that saw the same STROBEs have bit-identical states."""
        return self._s.copy()
