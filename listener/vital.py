"""Vital supervision (sans-I/O), after the Vital Control seed: module vitality and the latched decay state.

Two pieces, both driven by the pipeline with ``now`` (listener seconds):

- :class:`ModuleHealth`, one per interface module (IMU, odometer, GNSS): when it was last heard, how
  many datagrams, its rate over a sliding window against its nominal rate.
- :class:`DecaySupervisor`: the seed's *System Decay*. It is entered when the position cannot be
  vouched for: the filter reports LOST (``vital.decay_on_lost``), or a declared sensor fault (a
  reason in ``vital.decay_reasons``) has lasted longer than ``vital.fault_budget_s``. It is latched:
  the filter becoming NOMINAL again does not leave it. It is left only by the recovery sequence,
  in this order:

  1. ``await_standstill``: the filter reports ``standstill`` (its own detector: odometer at rest and
     a quiet IMU);
  2. ``await_ground_truth``: a GROUND TRUTH re-initialises the filter while still at standstill
     (motion before it sends the sequence back to step 1);
  3. ``confirming``: ``vital.recovery_updates`` consecutive consistent updates: odometer or GNSS
     measurements accepted by the filter while its status is NOMINAL (a gated one, or any other
     status, restarts the count).

  A further fault while latched (LOST, or any decay reason appearing, with no budget) sends the
  recovery back to step 1. While latched the pipeline sends no position as nominal
  (docs/protocol.md, "What the OBCU sees").

Events are returned as dicts (``{"event": ..., **fields}``); the pipeline queues them for the log.
"""

from __future__ import annotations

from collections import deque
from enum import StrEnum
from typing import Any

from listener.config import VitalConfig, decay_reasons
from sfa.layout import FilterStatus, Outcome

#: module name -> SENSOR_TYPE
MODULES = {"imu": 1, "odometer": 2, "gnss": 3}
#: the filter's Update.kind of each module
UPDATE_KIND = {"imu": "imu", "odometer": "odo", "gnss": "gps"}


class Phase(StrEnum):
    NORMAL = "normal"  #: not latched
    AWAIT_STANDSTILL = "await_standstill"
    AWAIT_GROUND_TRUTH = "await_ground_truth"
    CONFIRMING = "confirming"


class ModuleHealth:
    """Last heard, count and rate of one interface module."""

    def __init__(self, name: str, nominal_hz: float, window_s: float) -> None:
        self.name = name
        self.nominal_hz = nominal_hz
        self.window_s = window_s
        self.count = 0  #: valid datagrams heard
        self.last_heard: float | None = None  #: listener time of the last one [s]
        self.first_heard: float | None = None
        # arrival times within the window, bounded (a flood cannot grow it past 4x the nominal rate)
        self._times: deque[float] = deque(maxlen=max(16, int(4 * nominal_hz * window_s)))

    def heard(self, now: float) -> None:
        self.count += 1
        self.last_heard = now
        if self.first_heard is None:
            self.first_heard = now
        self._times.append(now)

    def age(self, now: float) -> float | None:
        """Seconds since it was last heard (None: never)."""
        return None if self.last_heard is None else max(0.0, now - self.last_heard)

    def rate(self, now: float) -> float:
        """Datagrams per second over the last ``window_s`` (over the time since first heard when shorter)."""
        times = self._times
        lo = now - self.window_s
        while times and times[0] < lo:
            times.popleft()
        if self.first_heard is None:
            return 0.0
        span = min(self.window_s, now - self.first_heard)
        return len(times) / span if span > 0 else 0.0


class DecaySupervisor:
    """The latched decay state and its recovery sequence (see the module docstring)."""

    def __init__(self, config: VitalConfig | None = None) -> None:
        self.cfg = config or VitalConfig()
        self._decay = frozenset(decay_reasons(self.cfg))
        self.phase = Phase.NORMAL
        self.onsets: dict[str, float] = {}  #: decay reason -> listener time it was first seen (current run)
        self.entered_at: float | None = None
        self.cause = ""
        self.confirmed = 0  #: consistent updates counted in ``confirming``
        self.entries = 0  #: times decay was entered
        self.releases = 0  #: times it was released
        self.refaults = 0  #: further faults while latched

    @property
    def latched(self) -> bool:
        return self.phase is not Phase.NORMAL

    def next_timer(self) -> float | None:
        """When a fault's budget runs out (only while not latched)."""
        if self.latched or not self.onsets:
            return None
        return min(self.onsets.values()) + self.cfg.fault_budget_s

    # ------------------------------------------------------------------ status
    def observe(self, status: int, reasons: tuple[str, ...], now: float) -> list[dict[str, Any]]:
        """The filter's status and reasons as of ``now``; returns the events this causes."""
        faults = self._decay.intersection(reasons)
        new_faults = [r for r in faults if r not in self.onsets]
        for r in new_faults:
            self.onsets[r] = now
        for r in [r for r in self.onsets if r not in faults]:
            del self.onsets[r]
        lost = status == FilterStatus.LOST and self.cfg.decay_on_lost
        if self.latched:
            if lost or new_faults:
                why = "lost" if lost and not new_faults else ",".join(sorted(new_faults))
                return self._refault(why, now)
            return []
        if lost:
            return self._enter("lost", now)
        if self.onsets:
            r = min(self.onsets, key=lambda k: (self.onsets[k], k))
            if now - self.onsets[r] >= self.cfg.fault_budget_s:
                return self._enter(f"{r} for more than {self.cfg.fault_budget_s:g} s", now)
        return []

    def _enter(self, cause: str, now: float) -> list[dict[str, Any]]:
        self.phase = Phase.AWAIT_STANDSTILL
        self.entered_at = now
        self.cause = cause
        self.confirmed = 0
        self.entries += 1
        return [{"event": "decay_entered", "cause": cause, "phase": self.phase.value}]

    def _refault(self, why: str, now: float) -> list[dict[str, Any]]:
        self.refaults += 1
        previous = self.phase
        self.phase = Phase.AWAIT_STANDSTILL
        self.confirmed = 0
        if previous is Phase.AWAIT_STANDSTILL:
            return [{"event": "decay_fault", "fault": why, "phase": self.phase.value}]
        return [
            {"event": "decay_recovery_reset", "why": f"fault: {why}", "from_phase": previous.value,
             "phase": self.phase.value}
        ]

    # ------------------------------------------------------------------ recovery
    def on_update(
        self, kind: str, outcome: int, status: int, reasons: tuple[str, ...], now: float
    ) -> list[dict[str, Any]]:
        """One processed measurement (``Update.kind``, ``Update.outcome``) and the estimate after it."""
        if not self.latched:
            return []
        phase = self.phase
        if kind == "init" and outcome == Outcome.INITIALISED:
            if phase is Phase.AWAIT_STANDSTILL:
                return [{"event": "decay_recovery_rejected", "why": "GROUND TRUTH before standstill",
                         "phase": phase.value}]
            self.phase = Phase.CONFIRMING
            self.confirmed = 0
            return [{"event": "decay_reinitialised", "phase": self.phase.value,
                     "needed": self.cfg.recovery_updates}]
        if phase is Phase.AWAIT_STANDSTILL:
            if "standstill" in reasons and status != FilterStatus.LOST:
                self.phase = Phase.AWAIT_GROUND_TRUTH
                return [{"event": "decay_standstill", "phase": self.phase.value}]
            return []
        if phase is Phase.AWAIT_GROUND_TRUTH:
            if "standstill" not in reasons:
                self.phase = Phase.AWAIT_STANDSTILL
                return [{"event": "decay_recovery_reset", "why": "motion before the GROUND TRUTH",
                         "from_phase": phase.value, "phase": self.phase.value}]
            return []
        # confirming
        if kind not in ("odo", "gps"):
            return []
        if outcome == Outcome.ACCEPTED and status == FilterStatus.NOMINAL:
            self.confirmed += 1
            if self.confirmed >= self.cfg.recovery_updates:
                self.phase = Phase.NORMAL
                self.releases += 1
                held = None if self.entered_at is None else now - self.entered_at
                self.onsets.clear()
                return [{"event": "decay_released", "confirmed": self.confirmed, "latched_s": held,
                         "cause": self.cause}]
        elif outcome == Outcome.GATED or status != FilterStatus.NOMINAL:
            self.confirmed = 0
        return []

    def stats(self) -> dict[str, Any]:
        return {
            "latched": self.latched,
            "phase": self.phase.value,
            "cause": self.cause if self.latched else "",
            "entered_at": self.entered_at if self.latched else None,
            "confirmed": self.confirmed,
            "entries": self.entries,
            "releases": self.releases,
            "refaults": self.refaults,
            "faults": dict(sorted(self.onsets.items())),
        }
