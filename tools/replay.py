"""Offline replay: a capture through the listener's own pipeline core, with time from the capture.

``replay_datagrams`` feeds :class:`listener.pipeline.Pipeline` exactly as the daemon does (same
object, same code path), with ``now`` = each packet's capture timestamp and the pipeline's timers
fired at their scheduled times between packets. Nothing reads a clock, so the same capture gives
bit-identical estimates on every run.

The result holds one row per OUTPUT_PROTOCOL datagram the listener would have sent (new estimates
and retransmissions, flagged), the filter's per-measurement outcomes (for the innovation and gating
plots), the GNSS fixes seen, and every pipeline counter.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from listener.codec import DecodeError, GpsFix, decode_header, decode_input, decode_output
from listener.config import ListenerConfig
from listener.defaults import DEFAULT_LISTENER_PORT
from listener.pipeline import Pipeline
from tools.errors import ToolError
from tools.estimates_schema import reason_bits

SENSOR_TYPES = {"imu": 1, "odometer": 2, "gps": 3}
ESTIMATE_COLUMNS = (
    "epoch",
    "arc_length",
    "seq",
    "retransmit",
    "arrival",
    "speed",
    "sigma",
    "interval_low",
    "interval_high",
    "status",
    "line_id",
    "lat",
    "lon",
)


@dataclass(frozen=True)
class ReplayOptions:
    """How to replay."""

    port: int = DEFAULT_LISTENER_PORT  #: listener port the capture is filtered on
    config: ListenerConfig = field(default_factory=ListenerConfig)  #: the listener's configuration
    sensors: frozenset[str] = frozenset(SENSOR_TYPES)  #: sensors whose datagrams are replayed
    filter_overrides: tuple[tuple[str, Any], ...] = ()  #: FilterConfig fields to override (sweeps)
    label: str = "sfa"  #: name of this configuration in tables
    record_measurements: bool = False  #: keep the dated measurements (for the baselines)


@dataclass
class ReplayResult:
    """Everything one replay produced."""

    label: str
    estimates: dict[str, np.ndarray]  #: columns of ESTIMATE_COLUMNS, one row per output datagram
    updates: dict[str, np.ndarray]  #: t, kind, outcome, nis per processed measurement
    gps: dict[str, np.ndarray]  #: t (arrival), lat, lon, fix_quality of GNSS datagrams
    metrics: dict[str, Any]  #: the pipeline's counters at the end
    datagrams: int  #: input datagrams replayed
    skipped_sensor: int  #: datagrams of disabled sensors
    capture: dict[str, Any] = field(default_factory=dict)  #: capture reader counters
    measurements: list = field(default_factory=list)  #: dated measurements, in filter order (if recorded)
    reasons: np.ndarray | None = None  #: status reason bits per estimates row (None: not recorded)

    def new_estimates(self) -> dict[str, np.ndarray]:
        """Rows of new estimates only (no retransmissions)."""
        keep = self.estimates["retransmit"] == 0
        return {k: v[keep] for k, v in self.estimates.items()}

    def new_reasons(self) -> np.ndarray | None:
        """Reason bits of the new estimates (None where the replay did not record them)."""
        if self.reasons is None:
            return None
        return self.reasons[self.estimates["retransmit"] == 0]


def build_pipeline(track, options: ReplayOptions) -> Pipeline:
    """The listener pipeline for ``options`` (the filter built with any sweep overrides)."""
    from sfa.filter import TrackFilter

    try:
        cfg = options.config.filter.filter_config(**dict(options.filter_overrides))
    except (KeyError, TypeError) as exc:
        raise ToolError(f"filter configuration: {exc}") from exc
    except Exception as exc:
        from sfa.errors import SfaError

        if isinstance(exc, SfaError):
            raise ToolError(f"filter configuration: {exc}") from exc
        raise
    return Pipeline(track, options.config, filt=TrackFilter(track, cfg))


def replay_datagrams(
    datagrams: Iterable[tuple[float, Any, bytes]], track, options: ReplayOptions | None = None, progress=None
) -> ReplayResult:
    """Replay ``(arrival_time_s, source_address, payload)`` in order through a fresh pipeline."""
    options = options or ReplayOptions()
    pipe = build_pipeline(track, options)
    enabled = {SENSOR_TYPES[s] for s in options.sensors}
    disabled = set(SENSOR_TYPES.values()) - enabled

    est_rows: list[tuple] = []
    reason_rows: list[int] = []
    upd_t: list[float] = []
    upd_kind: list[str] = []
    upd_outcome: list[int] = []
    upd_nis: list[float] = []
    gps_rows: list[tuple[float, float, float, int]] = []
    by_seq: dict[int, Any] = {}  # SEQ -> the estimate last encoded with it
    fresh: deque[int] = deque()  # SEQs encoded as new estimates and not yet seen in an output

    def on_update(upd) -> None:
        upd_t.append(upd.t_s)
        upd_kind.append(upd.kind)
        upd_outcome.append(int(upd.outcome))
        upd_nis.append(math.nan if upd.nis is None else float(upd.nis))

    def on_output(seq: int, est) -> None:
        by_seq[seq] = est
        fresh.append(seq)

    pipe.on_output = on_output
    pipe.on_update = on_update
    measurements: list = []
    if options.record_measurements:
        pipe.on_measurement = measurements.append

    def record(outputs: list[bytes], now: float) -> None:
        for payload in outputs:
            msg = decode_output(payload[:18])
            est = by_seq.get(msg.seq)
            # a new estimate's datagram follows its encoding; anything else is a resend of the newest
            if fresh and fresh[0] == msg.seq:
                fresh.popleft()
                retransmit = 0
            else:
                retransmit = 1
            if est is None:  # pragma: no cover - every output passes through the encoder
                raise ToolError(f"output SEQ {msg.seq} was not recorded")
            est_rows.append(estimate_row(msg, est, retransmit, now))
            reason_rows.append(reason_bits(est.reasons))

    n = 0
    skipped = 0
    last_t = None
    for t, addr, payload in datagrams:
        n += 1
        if progress is not None:
            progress(1)
        if disabled:
            try:
                stype = int(decode_header(payload)[0])
            except DecodeError:
                stype = -1
            if stype in disabled:
                skipped += 1
                continue
        # timers due before this packet fire at their own time, as the event loop would fire them
        for _ in range(1000):
            nxt = pipe.next_timer()
            if nxt is None or nxt > t:
                break
            record(pipe.handle_timer(nxt), nxt)
        if stype_is_gps(payload):
            try:
                msg = decode_input(payload)
                if isinstance(msg, GpsFix):
                    gps_rows.append((t, msg.lat, msg.lon, -1 if msg.fix_quality is None else msg.fix_quality))
            except DecodeError:
                pass
        record(pipe.receive(payload, addr, t), t)
        last_t = t
        if pipe.stopped:
            break
    if last_t is not None and not pipe.stopped:
        record(pipe.flush(last_t), last_t)

    est = {
        name: np.array(
            [r[i] for r in est_rows],
            dtype=float if name not in ("seq", "retransmit", "status", "line_id") else np.int64,
        )
        for i, name in enumerate(ESTIMATE_COLUMNS)
    }
    updates = {
        "t": np.array(upd_t, dtype=float),
        "kind": np.array(upd_kind, dtype=object),
        "outcome": np.array(upd_outcome, dtype=np.int64),
        "nis": np.array(upd_nis, dtype=float),
    }
    gps = {
        "t": np.array([g[0] for g in gps_rows], dtype=float),
        "lat": np.array([g[1] for g in gps_rows], dtype=float),
        "lon": np.array([g[2] for g in gps_rows], dtype=float),
        "fix_quality": np.array([g[3] for g in gps_rows], dtype=np.int64),
    }
    return ReplayResult(
        label=options.label,
        estimates=est,
        updates=updates,
        gps=gps,
        metrics=pipe.metrics(last_t),
        datagrams=n,
        skipped_sensor=skipped,
        measurements=measurements,
        reasons=np.array(reason_rows, dtype=np.int64),
    )


def estimate_row(msg, est, retransmit: int, now: float) -> tuple:
    """One ``ESTIMATE_COLUMNS`` row: the output datagram ``msg``, the estimate it carries, and when."""
    return (
        msg.epoch,
        msg.arc_length,
        msg.seq,
        retransmit,
        now,
        est.speed_mps,
        est.sigma_s_m,
        est.interval_low_m,
        est.interval_high_m,
        int(est.status),
        -1 if est.line_id is None else est.line_id,
        est.lat_deg,
        est.lon_deg,
    )


def stype_is_gps(payload: bytes) -> bool:
    return len(payload) >= 5 and payload[0] == 3


def replay_capture(
    path: str | Path, track, options: ReplayOptions | None = None, show_progress: bool = False
):
    """Replay a pcap/pcapng file (see :mod:`tools.capture_reader`)."""
    from tools.capture_reader import CaptureStats, read_capture

    options = options or ReplayOptions()
    stats = CaptureStats()
    gen = ((d.time_s, d.src, d.payload) for d in read_capture(path, options.port, stats))
    if show_progress:
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        size = Path(path).stat().st_size
        with Progress(
            TextColumn("replay"),
            BarColumn(),
            TextColumn("{task.completed:,.0f} datagrams"),
            TimeElapsedColumn(),
            transient=True,
        ) as bar:
            task = bar.add_task("replay", total=None if size else 0)
            result = replay_datagrams(gen, track, options, progress=lambda k: bar.advance(task, k))
    else:
        result = replay_datagrams(gen, track, options)
    warning = stats.truncation_warning(path)
    result.capture = {
        "frames": stats.frames,
        "datagrams": stats.datagrams,
        "skipped": dict(stats.skipped),
        "truncated_bytes": stats.truncated_bytes,
        "truncated_records": stats.truncated_records,
        "warnings": [] if warning is None else [warning],
    }
    if stats.datagrams == 0:
        raise ToolError(
            f"{path}: no UDP datagram to port {options.port} in the capture "
            f"({stats.frames} frames; skipped: {dict(stats.skipped) or 'none'})"
        )
    return result
