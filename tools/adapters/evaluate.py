"""Run a converted capture through the listener's pipeline core and measure what SFA achieves.

``run_pipeline`` feeds :class:`listener.pipeline.Pipeline` the capture's datagrams in capture order
with ``now`` = the capture timestamp (the daemon's code path, no sockets), fires its timers in
between, and acknowledges every output at once as an OBCU would. It records each new estimate the
listener sends (extended output form: epoch, arc length, speed, interval, status).

Figures:

* :func:`truth_figures` -- along-track error against truth.csv (tools.accuracy).
* :func:`self_consistency` -- without truth (Dresden): GNSS fixes projected on the track versus the
  estimate at the fix time, cross-track distance of the fixes, and continuity of the output.
"""

from __future__ import annotations

import csv
import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from tools.errors import ToolError

ESTIMATE_FIELDS = ("epoch", "arc_length", "speed", "interval_low", "interval_high", "status")


def run_pipeline(capture: str | Path, track_path: str | Path, config=None, port: int | None = None,
                 filter_config=None, exclude_ports: frozenset[int] = frozenset()) -> dict:
    """Estimates (columns of ``ESTIMATE_FIELDS``) and the pipeline's metrics for one capture.

    ``exclude_ports``: source ports whose datagrams are not replayed (e.g. a sensor left out)."""
    from listener.codec import decode_output_extended, encode_ack
    from listener.config import ListenerConfig
    from listener.pipeline import Pipeline
    from tools.adapters.common import read_pcap_udp
    from track_db import TrackDatabase

    cfg = config or ListenerConfig()
    cfg = replace(cfg, link=replace(cfg.link, extended=True))
    track = TrackDatabase.open(track_path)
    filt = None
    if filter_config is not None:
        from sfa.filter import TrackFilter

        filt = TrackFilter(track, filter_config)
    pipe = Pipeline(track, cfg, filt)
    frames = read_pcap_udp(capture)
    rows: list[tuple] = []
    last_seq = None

    def take(outputs: list[bytes], now: float) -> None:
        nonlocal last_seq
        for data in outputs:
            out = decode_output_extended(data)
            if out.seq != last_seq:  # a retransmission repeats the SEQ of the estimate it resends
                rows.append((out.epoch, out.arc_length, out.speed, out.interval_low, out.interval_high,
                             out.status))
                last_seq = out.seq
            pipe.receive_ack(encode_ack(out.seq), now)

    for ts, sport, payload in frames:
        if sport in exclude_ports:
            continue
        while (due := pipe.next_timer()) is not None and due <= ts:
            take(pipe.handle_timer(due), due)
        take(pipe.receive(payload, ("127.0.0.1", sport), ts), ts)
        if pipe.stopped:
            break
    if not pipe.stopped and frames:
        take(pipe.flush(frames[-1][0]), frames[-1][0])
    track.close()
    arr = np.asarray(rows, dtype=np.float64).reshape(-1, len(ESTIMATE_FIELDS))
    est = {name: arr[:, i] for i, name in enumerate(ESTIMATE_FIELDS)}
    return {"estimates": est, "metrics": pipe.metrics()}


def read_truth(path: str | Path) -> dict[str, np.ndarray]:
    """truth.csv as float columns."""
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            reader = csv.DictReader(fh)
            rows = list(reader)
            names = reader.fieldnames or []
    except OSError as exc:
        raise ToolError(f"cannot read truth {str(path)!r}: {exc}") from None
    if not rows or "epoch" not in names or "arc_length" not in names:
        raise ToolError(f"{path}: truth needs the columns epoch and arc_length")
    return {n: np.array([float(r[n]) for r in rows]) for n in names}


def truth_figures(estimates: dict[str, np.ndarray], truth: dict[str, np.ndarray]) -> dict:
    """Along-track accuracy of the estimates against truth (rms, p50, p95, max [m], coverage)."""
    from tools.accuracy import accuracy

    acc = accuracy(estimates["epoch"], estimates["arc_length"], truth["epoch"], truth["arc_length"],
                   estimates["interval_low"], estimates["interval_high"])
    return acc.as_dict()


def self_consistency(estimates: dict[str, np.ndarray], reference: dict[str, np.ndarray]) -> dict:
    """Checks possible without truth (Dresden), against gnss_on_track.csv (each GNSS fix projected on
    the track, locally): the estimate at each fix's epoch minus the fix's arc length (along-track
    residual), the fixes' distance from the track, and the continuity of the output (each step of
    the arc length against speed x time, speed changes, backward steps)."""
    et, es, ev = estimates["epoch"], estimates["arc_length"], estimates["speed"]
    t, s_fix = reference["epoch"], reference["arc_length"]
    inside = (t >= et[0]) & (t <= et[-1])
    resid = np.interp(t[inside], et, es) - s_fix[inside]
    a = np.abs(resid)
    off = np.abs(reference["cross_track"]) if "cross_track" in reference else np.zeros(1)
    dt = np.diff(et)
    ok = dt > 0
    accel = np.abs(np.diff(ev)[ok] / dt[ok])
    step_gap = np.abs(np.diff(es)[ok] - 0.5 * (ev[1:] + ev[:-1])[ok] * dt[ok])
    return {
        "fixes": int(inside.sum()),
        "along_track_residual_rms_m": float(math.sqrt(np.mean(resid ** 2))),
        "along_track_residual_p50_m": float(np.percentile(a, 50)),
        "along_track_residual_p95_m": float(np.percentile(a, 95)),
        "along_track_residual_max_m": float(a.max()),
        "fix_cross_track_p95_m": float(np.percentile(off, 95)),
        "fix_cross_track_max_m": float(off.max()),
        "output_step_minus_speed_dt_max_m": float(step_gap.max()) if step_gap.size else 0.0,
        "speed_change_p99_mps2": float(np.percentile(accel, 99)) if accel.size else 0.0,
        "backward_steps": int(np.sum(np.diff(es) < -1e-6)),
    }
