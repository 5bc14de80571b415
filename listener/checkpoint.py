"""Checkpoint and resume (sans-I/O): the listener's state once a second, and a restart without GROUND TRUTH.

What is saved (a JSON document, :func:`encode`): the filter's reported hypothesis (line, arc length,
speed along the line, sense of travel, 1-sigma of both, the sensor error states with their sigma),
the next output SEQ, the authenticated links' anti-replay windows and output epoch counter
(:meth:`listener.auth_link.LinkAuth.export_state`), an ``extra`` dict other components fill through
:attr:`listener.pipeline.Pipeline.checkpoint_extra`, the time of the snapshot (listener monotonic
time, wall time and boot id: the service adds the last two) and a fingerprint of the track database.
The document carries its format name, version and the SHA-256 of its body, so a torn, edited or
foreign file is refused rather than believed.

On start (:func:`assess`) a checkpoint is refused, with a reason, when it is corrupt (not JSON, wrong
format, checksum), of another version, of another track database, from the future or older than
``checkpoint.max_age_s``. An accepted one gives a :class:`ResumePlan`. The filter is seeded from it
at the first measurement that reaches the filter (:func:`seed_values`), once that measurement's
sensor time is known: it must match the checkpoint's sensor time plus the elapsed time (else the
sensor-set clock was reset while the listener was down and the plan is refused); the arc length is
carried forward at the saved speed, and its sigma widened by the gap x the line's maximum speed (the
speed sigma by the gap x ``max_accel_mps2``). A widened sigma beyond ``checkpoint.max_sigma_m``
refuses the plan too (the position can no longer be vouched for: wait for GROUND TRUTH).

Until GNSS and the odometer have re-anchored the seeded filter (:class:`ResumeGuard`: accepted fixes
and samples, and the filter NOMINAL by itself) its estimates are reported DEGRADED with the reason
``resumed``; while their sigma exceeds the filter's LOST bound they also carry ``resumed_uncertain``
and are not sent (they would be LOST, and LOST would latch the decay state, which only a GROUND TRUTH
at standstill leaves: the first GNSS fix narrows them instead).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass
from typing import Any

from listener.config import CheckpointConfig
from listener.errors import ListenerError

FORMAT = "sfa-listener-checkpoint"
VERSION = 1
RESUMED = "resumed"  #: the reason carried while a resumed filter is not re-anchored
RESUMED_UNCERTAIN = "resumed_uncertain"  #: ... and its sigma is beyond the LOST bound: not sent
_LOST = 3
_DEGRADED = 2
_NOMINAL = 1


class CheckpointError(ListenerError):
    """A checkpoint is refused. ``reason`` is a short stable label, ``detail`` a sentence."""

    __slots__ = ("reason", "detail")

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


# ---------------------------------------------------------------- document
def _canonical(body: Any) -> bytes:
    return json.dumps(body, sort_keys=True, separators=(",", ":"), allow_nan=False).encode()


def encode(body: dict[str, Any]) -> bytes:
    """The checkpoint document of ``body`` (JSON; non-finite numbers are not allowed in it)."""
    raw = _canonical(body)
    doc = {"format": FORMAT, "version": VERSION, "sha256": hashlib.sha256(raw).hexdigest(), "body": body}
    return _canonical(doc) + b"\n"


def decode(data: bytes) -> dict[str, Any]:
    """The body of a checkpoint document; :class:`CheckpointError` (corrupt, format, version, checksum)."""
    try:
        doc = json.loads(data)
    except (ValueError, UnicodeDecodeError) as exc:
        raise CheckpointError("corrupt", f"not JSON: {exc}") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise CheckpointError("format", "not an sfa listener checkpoint")
    if doc.get("version") != VERSION:
        raise CheckpointError("version", f"version {doc.get('version')!r}, this listener reads {VERSION}")
    body = doc.get("body")
    if not isinstance(body, dict):
        raise CheckpointError("corrupt", "no body")
    try:
        digest = hashlib.sha256(_canonical(body)).hexdigest()
    except ValueError as exc:
        raise CheckpointError("corrupt", f"body: {exc}") from None
    if digest != doc.get("sha256"):
        raise CheckpointError("checksum", "SHA-256 of the body does not match")
    return body


def track_fingerprint(track) -> str:
    """SHA-256 (16 hex digits) of the track database's lines (id, length, vertices) and projection."""
    lines = [[i.line_id, round(float(i.length_m), 3), int(i.n_vertices)] for i in track.lines()]
    meta = getattr(track, "meta", {}) or {}
    doc = {"lines": lines, "projection": meta.get("projection", ""), "default": meta.get("default_line_id")}
    return hashlib.sha256(_canonical(doc)).hexdigest()[:16]


def filter_state(filt) -> dict[str, Any] | None:
    """The reported hypothesis of ``filt`` (a :class:`sfa.filter.TrackFilter`) as saved; None before it
    is initialised or while its state is not finite."""
    if not filt.initialised:
        return None
    from sfa.layout import STATE_NAMES

    est = filt.estimate()
    x, P = filt.state()
    values = [float(v) for v in x]
    sig = [math.sqrt(max(float(P[i, i]), 0.0)) for i in range(len(values))]
    numbers = [*values, *sig, est.epoch_s, est.sigma_v_mps]
    if not all(math.isfinite(v) for v in numbers) or est.line_id is None:
        return None
    return {
        "t_s": float(est.epoch_s),
        "line_id": int(est.line_id),
        "s_m": values[0],
        "v_mps": values[1],  # along increasing arc length
        "direction": int(est.direction),
        "sigma_s_m": sig[0],
        "sigma_v_mps": max(sig[1], float(est.sigma_v_mps)),
        "errors": {name: [values[i], sig[i]] for i, name in enumerate(STATE_NAMES) if i > 1},
        "status": int(est.status),
    }


# ---------------------------------------------------------------- scheduling
class Checkpointer:
    """When the next checkpoint is due (listener time): once per ``interval_s``, driven by ``now``."""

    def __init__(self, config: CheckpointConfig | None = None) -> None:
        self.cfg = config or CheckpointConfig()
        self.next_due: float | None = None
        self.taken = 0

    def due(self, now: float) -> bool:
        return self.next_due is None or now >= self.next_due

    def mark(self, now: float) -> None:
        self.taken += 1
        # from the deadline, not from now: a late timer does not drift the schedule (but never bunches)
        base = now if self.next_due is None or now - self.next_due > self.cfg.interval_s else self.next_due
        self.next_due = base + self.cfg.interval_s


# ---------------------------------------------------------------- resume
@dataclass(frozen=True)
class ResumePlan:
    """An accepted checkpoint: what to restore now, and the filter state to seed later."""

    elapsed_s: float  #: listener seconds from the snapshot to the assessment [s]
    next_seq: int | None  #: output SEQ to continue at (skip included)
    filter: dict[str, Any] | None  #: :func:`filter_state`'s dict, None when it was not initialised
    auth: dict[str, Any] | None
    extra: dict[str, Any]


def assess(
    body: dict[str, Any],
    *,
    track_fp: str,
    wall_now: float,
    mono_now: float,
    boot_id: str | None,
    config: CheckpointConfig | None = None,
) -> ResumePlan:
    """Check a decoded checkpoint against this start; the plan, or :class:`CheckpointError`."""
    cfg = config or CheckpointConfig()
    if body.get("track") != track_fp:
        raise CheckpointError("track", f"taken on track {body.get('track')!r}, this one is {track_fp!r}")
    taken = body.get("taken")
    if not isinstance(taken, dict):
        raise CheckpointError("corrupt", "no snapshot time")
    try:
        same_boot = boot_id is not None and taken.get("boot_id") == boot_id
        elapsed = mono_now - float(taken["monotonic"]) if same_boot else wall_now - float(taken["wall"])
    except (KeyError, TypeError, ValueError):
        raise CheckpointError("corrupt", "snapshot time missing or not a number") from None
    if not math.isfinite(elapsed):
        raise CheckpointError("corrupt", "snapshot time not finite")
    if elapsed < -1.0:
        raise CheckpointError("future", f"taken {-elapsed:.1f} s in the future")
    elapsed = max(0.0, elapsed)
    if elapsed > cfg.max_age_s:
        raise CheckpointError("stale", f"{elapsed:.1f} s old, checkpoint.max_age_s = {cfg.max_age_s:g} s")
    link = body.get("link")
    next_seq = None
    if isinstance(link, dict) and link.get("next_seq") is not None:
        seq = link["next_seq"]
        if isinstance(seq, bool) or not isinstance(seq, int) or not 0 <= seq <= 0xFFFF:
            raise CheckpointError("corrupt", f"link.next_seq {seq!r}")
        next_seq = (seq + cfg.seq_skip) & 0xFFFF
    filt = body.get("filter")
    if filt is not None:
        need = ("t_s", "line_id", "s_m", "v_mps", "direction", "sigma_s_m", "sigma_v_mps", "errors")
        if not isinstance(filt, dict) or any(k not in filt for k in need):
            raise CheckpointError("corrupt", "filter state incomplete")
        nums = [filt[k] for k in ("t_s", "s_m", "v_mps", "sigma_s_m", "sigma_v_mps")]
        if not all(isinstance(v, float | int) and not isinstance(v, bool) and math.isfinite(v) for v in nums):
            raise CheckpointError("corrupt", "filter state not finite numbers")
        if filt["direction"] not in (-1, 0, 1) or not isinstance(filt["errors"], dict):
            raise CheckpointError("corrupt", "filter direction or error states malformed")
    auth = body.get("auth")
    extra = body.get("extra") or {}
    if not isinstance(extra, dict) or (auth is not None and not isinstance(auth, dict)):
        raise CheckpointError("corrupt", "auth or extra malformed")
    return ResumePlan(elapsed, next_seq, filt, auth, extra)


@dataclass(frozen=True)
class Seed:
    """Arguments of :meth:`sfa.filter.TrackFilter.seed`."""

    t_s: float
    line_id: int
    arc_length_m: float
    speed_mps: float  #: forward speed
    direction: int
    sigma_s_m: float
    sigma_v_mps: float
    errors: dict[str, tuple[float, float]]
    gap_s: float  #: sensor seconds between the checkpoint and the seed [s]


def seed_values(
    state: dict[str, Any],
    t_s: float,
    listener_gap_s: float,
    *,
    rate: float,
    max_speed_mps: float,
    config: CheckpointConfig | None = None,
) -> Seed:
    """The filter seed at sensor time ``t_s`` (the first measurement after the restart), ``listener_gap_s``
    listener seconds after the snapshot; :class:`CheckpointError` (clock, uncertain) when it is refused."""
    cfg = config or CheckpointConfig()
    gap = float(t_s) - float(state["t_s"])
    expected = listener_gap_s * rate
    if not math.isfinite(gap) or abs(gap - expected) > cfg.clock_tolerance_s * max(1.0, rate):
        raise CheckpointError(
            "clock",
            f"sensor time moved {gap:.3f} s since the checkpoint, {expected:.3f} s expected "
            f"(sensor-set clock reset?)",
        )
    gap = max(0.0, gap)
    v_along = float(state["v_mps"])
    sigma_s = math.hypot(float(state["sigma_s_m"]), gap * max_speed_mps)
    sigma_v = math.hypot(float(state["sigma_v_mps"]), min(max_speed_mps, gap * cfg.max_accel_mps2))
    if sigma_s > cfg.max_sigma_m:
        raise CheckpointError(
            "uncertain",
            f"arc-length sigma {sigma_s:.1f} m after {gap:.2f} s at {max_speed_mps:g} m/s exceeds "
            f"checkpoint.max_sigma_m = {cfg.max_sigma_m:g} m",
        )
    direction = int(state["direction"])
    forward = v_along * direction if direction else abs(v_along)
    errors = {str(k): (float(v[0]), float(v[1])) for k, v in state["errors"].items()}
    return Seed(float(t_s), int(state["line_id"]), float(state["s_m"]) + v_along * gap, forward, direction,
                sigma_s, max(sigma_v, 1e-3), errors, gap)


class ResumeGuard:
    """DEGRADED (reason ``resumed``) from a seed until GNSS and the odometer have re-anchored the filter."""

    def __init__(self, config: CheckpointConfig | None = None) -> None:
        self.cfg = config or CheckpointConfig()
        self.active = False
        self.gnss = 0
        self.odometer = 0
        self.since: float | None = None
        self.lost_sigma_m = math.inf

    def start(self, now: float, lost_sigma_m: float = math.inf) -> None:
        self.active, self.gnss, self.odometer, self.since = True, 0, 0, now
        self.lost_sigma_m = lost_sigma_m

    def stop(self) -> None:
        self.active = False

    def on_update(self, kind: str, accepted: bool) -> None:
        if self.active and accepted:
            if kind == "gps":
                self.gnss += 1
            elif kind == "odo":
                self.odometer += 1

    def overlay(self, est):
        """``est`` as reported: DEGRADED with ``resumed`` while not re-anchored; releases the guard once
        it is and the filter is NOMINAL by itself."""
        if not self.active:
            return est
        anchored = self.gnss >= self.cfg.reanchor_gnss and self.odometer >= self.cfg.reanchor_odometer
        if anchored and int(est.status) == _NOMINAL:
            self.active = False
            return est
        reasons = (*est.reasons, RESUMED)
        status = est.status if int(est.status) >= _DEGRADED else type(est.status)(_DEGRADED)
        if est.sigma_s_m > self.lost_sigma_m and int(est.status) == _LOST:
            # LOST only by the widened sigma: reported DEGRADED (no decay latch), not sent
            only_sigma = all(r in ("sigma_too_high", "standstill") for r in est.reasons)
            if only_sigma:
                status = type(est.status)(_DEGRADED)
                reasons = (*reasons, RESUMED_UNCERTAIN)
        return dataclasses.replace(est, status=status, reasons=reasons)
