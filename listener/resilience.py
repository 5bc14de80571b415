"""The pipeline's resilience stage (sans-I/O): plausibility, clock trouble, checkpoints and resume.

One object per :class:`listener.pipeline.Pipeline` (``pipeline.resilience``), called at a few points:

- ``before_measurement``: seeds the filter from a pending checkpoint (:mod:`listener.checkpoint`) at
  the first measurement after a restart, and holds a GROUND TRUTH that disagrees with a NOMINAL filter
  (:class:`listener.plausibility.GroundTruthGuard`);
- ``vet``: every estimate the pipeline observes or may send, as reported: DEGRADED with ``resumed``
  while a resumed filter is not re-anchored, ``clock_untrusted`` for ``clock.trouble_hold_s`` after
  a STROBE was rejected, ``arc_off_line`` / ``arc_implausible_step`` when the output guard refuses it
  (the same object when none applies, so a normal run's outputs are untouched);
- ``publishable`` / ``sent``: an output carrying a plausibility reason is not sent (counted, warned);
- ``tick`` / ``next_timer``: the checkpoint schedule (only once the service enabled it: a replay never
  checkpoints unless asked, so its timers and outputs are those of the listener before);
- ``warn``: rate-limited warning events (:class:`listener.warnlimit.WarningLimiter`), queued with the
  status events for the log; every occurrence is counted in ``metrics()["resilience"]``.
"""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from typing import Any

from listener.checkpoint import (
    RESUMED,
    RESUMED_UNCERTAIN,
    Checkpointer,
    CheckpointError,
    ResumeGuard,
    ResumePlan,
    assess,
    decode,
    filter_state,
    seed_values,
    track_fingerprint,
)
from listener.errors import ListenerError
from listener.plausibility import IMPLAUSIBLE_STEP, OFF_LINE, GroundTruthGuard, OutputGuard, line_limits
from listener.warnlimit import WarningLimiter

CLOCK_UNTRUSTED = "clock_untrusted"
_NOMINAL = 1
_DEGRADED = 2
_INITIALISED = 6  #: Outcome.INITIALISED
_ACCEPTED = 0  #: Outcome.ACCEPTED


def degrade(est, reason: str):
    """``est`` reported at least DEGRADED with ``reason`` added."""
    if reason in est.reasons:
        return est
    status = est.status if int(est.status) >= _DEGRADED else type(est.status)(_DEGRADED)
    return dataclasses.replace(est, status=status, reasons=(*est.reasons, reason))


class Resilience:
    def __init__(self, pipeline, track) -> None:
        self.p = pipeline
        cfg = pipeline.cfg
        self.cfg = cfg
        try:
            self.limits = line_limits(track, cfg.plausibility.max_speed_mps)
        except (AttributeError, TypeError):  # a stand-in track without line metadata
            self.limits = {}
        self.track = track
        self.gt = GroundTruthGuard(cfg.plausibility, getattr(track, "default_line_id", None))
        self.out = OutputGuard(self.limits, cfg.plausibility)
        self.warnings = WarningLimiter(cfg.log.warning_interval_s)
        self.resume_guard = ResumeGuard(cfg.checkpoint)
        self.checkpointer: Checkpointer | None = None
        self.counters: Counter[str] = Counter()
        self._fp: str | None = None
        self._pending: dict[str, Any] | None = None  # filter state waiting for the first measurement
        self._gap0 = 0.0
        self._resume_at = 0.0
        self._snapshot: dict[str, Any] | None = None
        self._strobe_rejected = 0
        self._strobe_resets = 0
        self._rate_warned: float | None = None

    # ------------------------------------------------------------------ warnings
    def warn(self, kind: str, now: float, **fields: Any) -> None:
        ev = self.warnings.event(kind, now, **fields)
        if ev is not None:
            self.p.events.append(ev)

    def after_strobe(self, msg, arrival: float) -> None:
        clock = self.p.clock
        if clock.rejected != self._strobe_rejected:
            self._strobe_rejected = clock.rejected
            self.warn("strobe_rejected", arrival, timestamp=msg.timestamp,
                      offset_s=msg.timestamp - arrival, model_offset_s=clock.offset_at(arrival),
                      rejected=clock.rejected)
        rate = clock.settled_rate
        if rate is not None and rate != self.cfg.clock.rate and rate != self._rate_warned:
            self._rate_warned = rate
            self.warn("clock_rate_mismatch", arrival, settled_rate=rate, configured_rate=self.cfg.clock.rate)
        if clock.resets != self._strobe_resets:
            self._strobe_resets = clock.resets
            self.warn("clock_reset", arrival, timestamp=msg.timestamp, resets=clock.resets)

    # ------------------------------------------------------------------ measurements
    def before_measurement(self, meas, now: float) -> bool:
        """False when ``meas`` must not reach the filter (a GROUND TRUTH held for confirmation)."""
        from sfa.measurements import InitMeas

        is_gt = isinstance(meas, InitMeas)
        if self._pending is not None:
            self._seed(meas, now, is_gt)
        if not is_gt:
            return True
        filt = self.p.filter
        est = None if not filt.initialised or self.resume_guard.active else filt.estimate()
        ok, ev = self.gt.admit(meas, est)
        if ev is not None:
            kind = ev.pop("event")
            self.counters[kind] += 1
            self.warn(kind, now, **ev)
        return ok

    def _seed(self, meas, now: float, is_gt: bool) -> None:
        state, self._pending = self._pending, None
        if is_gt:
            self.counters["resume_superseded"] += 1
            self.p.events.append({"event": "checkpoint_superseded", "at": now, "why": "GROUND TRUTH first"})
            return
        if self.p.filter.initialised:
            return
        line = int(state["line_id"])
        vmax = self.limits.get(line, (math.inf, self.cfg.plausibility.max_speed_mps))[1]
        lost = float(getattr(self.p.filter.config, "lost_sigma_m", 100.0))
        try:
            seed = seed_values(state, float(meas.t_s), self._gap0 + (now - self._resume_at),
                               rate=self.cfg.clock.rate, max_speed_mps=vmax, config=self.cfg.checkpoint)
        except CheckpointError as exc:
            self.refused(exc, now)
            return
        upd = self.p.filter.seed(seed.t_s, seed.line_id, seed.arc_length_m, seed.speed_mps, seed.direction,
                                 seed.sigma_s_m, seed.sigma_v_mps, seed.errors)
        if int(upd.outcome) != _INITIALISED:
            self.refused(CheckpointError("seed", f"the filter refused the seed ({upd.outcome})"), now)
            return
        self.p.mark_initialised(now)
        self.out.reset()
        self.resume_guard.start(now, lost)
        self.counters["resumed"] += 1
        self.p.events.append({"event": "resumed", "at": now, "line_id": seed.line_id,
                              "arc_length_m": seed.arc_length_m, "sigma_s_m": seed.sigma_s_m,
                              "gap_s": seed.gap_s, "max_speed_mps": vmax})

    def refused(self, exc: CheckpointError, now: float) -> None:
        """A checkpoint refused (at start or at the seed): counted, logged; GROUND TRUTH is awaited."""
        self.counters[f"refused_{exc.reason}"] += 1
        self.warn("checkpoint_refused", now, reason=exc.reason, detail=exc.detail)

    # ------------------------------------------------------------------ estimates
    def vet(self, est, update, now: float):
        if update is not None:
            if update.kind == "init" and int(update.outcome) == _INITIALISED:
                self.out.reset()
                self.resume_guard.stop()  # a GROUND TRUTH initialises as without a checkpoint
            elif self.resume_guard.active:
                self.resume_guard.on_update(update.kind, int(update.outcome) == _ACCEPTED)
        if not math.isfinite(est.epoch_s):
            return est
        if self.resume_guard.active:
            est = self.resume_guard.overlay(est)
        trouble = self.p.clock.trouble_at
        if trouble is not None and now - trouble <= self.cfg.clock.trouble_hold_s:
            est = degrade(est, CLOCK_UNTRUSTED)
        if math.isfinite(est.arc_length_m):
            reason = self.out.check(est)
            if reason is not None:
                est = degrade(est, reason)
        return est

    def publishable(self, est, now: float) -> bool:
        if RESUMED_UNCERTAIN in est.reasons:
            self.counters["not_sent_resumed_uncertain"] += 1
            return False
        for reason in (OFF_LINE, IMPLAUSIBLE_STEP):
            if reason in est.reasons:
                self.out.count(reason)
                self.counters[f"not_sent_{reason}"] += 1
                self.warn("output_implausible", now, reason=reason, arc_length_m=est.arc_length_m,
                          line_id=est.line_id, epoch=est.epoch_s)
                return False
        return True

    def sent(self, est) -> None:
        self.out.sent(est)

    # ------------------------------------------------------------------ checkpoints
    def fingerprint(self) -> str:
        if self._fp is None:
            self._fp = track_fingerprint(self.track)
        return self._fp

    def enable_checkpoints(self, now: float) -> None:
        """Take a checkpoint every ``checkpoint.interval_s`` from ``now`` on (the service, when it has a
        path; the first one is taken one interval after ``now``)."""
        self.checkpointer = Checkpointer(self.cfg.checkpoint)
        self.checkpointer.next_due = now + self.cfg.checkpoint.interval_s
        self.fingerprint()

    def next_timer(self) -> float | None:
        ck = self.checkpointer
        return None if ck is None or self.p.stopped else ck.next_due

    def tick(self, now: float) -> None:
        ck = self.checkpointer
        if ck is not None and ck.due(now) and not self.p.stopped:
            self._snapshot = self.body(now)
            ck.mark(now)

    def take_checkpoint(self) -> dict[str, Any] | None:
        """The checkpoint body taken by the last due tick, once (the service writes it)."""
        snap, self._snapshot = self._snapshot, None
        return snap

    def body(self, now: float) -> dict[str, Any]:
        p = self.p
        status = p.observed_status
        vouched = not p.vital.latched and (status is None or status <= _DEGRADED)
        return {
            "track": self.fingerprint(),
            "taken": {"monotonic": now},
            "filter": filter_state(p.filter) if vouched else None,
            "link": {"next_seq": p.link.next_seq},
            "auth": None if p.auth is None else p.auth.export_state(),
            "extra": {name: save() for name, (save, _) in sorted(p.checkpoint_extra.items())},
        }

    def load(self, data: bytes | None, now: float, *, wall_now: float, mono_now: float,
             boot_id: str | None) -> bool:
        """Resume from the checkpoint document ``data`` (None: there is none) if it is acceptable, else
        refuse it with a reason (warned, counted: the filter then waits for GROUND TRUTH); then start
        checkpoints. True when resumed. The service calls it with the file's bytes; the campaign's
        replay path with the file its earlier pipeline wrote."""
        resumed = False
        if data is not None:
            try:
                plan = assess(decode(data), track_fp=self.fingerprint(), wall_now=wall_now, mono_now=mono_now,
                              boot_id=boot_id, config=self.cfg.checkpoint)
                self.resume(plan, now)
                resumed = True
            except CheckpointError as exc:
                self.refused(exc, now)
        self.enable_checkpoints(now)
        return resumed

    def resume(self, plan: ResumePlan, now: float) -> None:
        """Restore an accepted checkpoint: the output SEQ, the anti-replay state and the extras now; the
        filter at the first measurement. CheckpointError when a part is malformed (nothing then used)."""
        p = self.p
        if plan.auth is not None and p.auth is not None:
            try:
                p.auth.restore_state(plan.auth)
            except (ValueError, TypeError, KeyError) as exc:
                raise CheckpointError("corrupt", f"auth state: {exc}") from None
        for name, data in plan.extra.items():
            entry = p.checkpoint_extra.get(name)
            if entry is not None and entry[1] is not None:
                try:
                    entry[1](data)
                except (ListenerError, ValueError, TypeError, KeyError) as exc:
                    raise CheckpointError("corrupt", f"{name} state: {exc}") from None
        if plan.next_seq is not None:
            p.link.continue_at(plan.next_seq)
        if plan.filter is not None:
            self._pending = plan.filter
            self._gap0 = plan.elapsed_s
            self._resume_at = now
        self.counters["checkpoints_resumed"] += 1
        p.events.append({"event": "checkpoint_loaded", "at": now, "age_s": round(plan.elapsed_s, 3),
                         "next_seq": plan.next_seq, "filter": plan.filter is not None,
                         "extra": sorted(plan.extra)})

    def stats(self) -> dict[str, Any]:
        return {
            "counters": dict(sorted(self.counters.items())),
            "warnings": dict(sorted(self.warnings.total.items())),
            "ground_truth": dict(self.gt.counters),
            "outputs_not_sent": dict(self.out.counters),
            "resumed_unanchored": self.resume_guard.active,
            "checkpoints_taken": 0 if self.checkpointer is None else self.checkpointer.taken,
        }


__all__ = ["CLOCK_UNTRUSTED", "RESUMED", "Resilience", "degrade"]
