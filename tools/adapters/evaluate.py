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
#: one row per measurement the filter processed (``updates.csv``): what it did with it and the reported
#: hypothesis's state right after (direction +1/-1, 0 while both senses are kept)
UPDATE_FIELDS = ("epoch", "kind", "outcome", "nis", "arc_length", "speed", "sigma_s", "status", "direction",
                 "hypotheses", "accel_bias", "odo_scale", "gyro_bias")


def recommended_hold_s(conv) -> float | None:
    """The merge hold-off [s] a converted capture's metadata.json recommends for the listener (None:
    none recommended)."""
    import json

    meta = json.loads(Path(conv.metadata).read_text(encoding="utf-8"))
    hold = meta.get("recommended_listener", {}).get("merge.hold_s")
    return None if hold is None else float(hold)


def listener_config_for(hold_s: float | None, config=None):
    """The listener configuration a converted capture is evaluated with: ``config`` (default: the
    listener's defaults) with the merge hold-off its metadata.json recommends (``hold_s``, from
    :func:`recommended_hold_s`; None: unchanged)."""
    from listener.config import ListenerConfig

    cfg = config or ListenerConfig()
    if hold_s is not None:
        cfg = replace(cfg, merge=replace(cfg.merge, hold_s=float(hold_s)))
    return cfg


def run_pipeline(capture: str | Path, track_path: str | Path, config=None, port: int | None = None,
                 filter_config=None, exclude_ports: frozenset[int] = frozenset(),
                 gps_gap: tuple[float, float] | None = None,
                 gap_ports: frozenset[int] | None = None, vet_outputs: bool = False) -> dict:
    """Estimates (columns of ``ESTIMATE_FIELDS``) and the pipeline's metrics for one capture.

    ``exclude_ports``: source ports whose datagrams are not replayed (e.g. a sensor left out).
    ``gps_gap``: (start, end) epochs [s]: GNSS fixes dated in [start, end) are not replayed (an outage);
    the result's ``gps_withheld`` counts them. ``gap_ports``: the source ports the gap applies to (None:
    the GNSS module's; add the odometer's when its speed comes from the same receiver, as in Dresden).
    ``vet_outputs``: keep the listener's plausibility stage (off by default here: this measures the
    filter, and the stage withholds exactly the estimates that are far off, e.g. off the line)."""
    from listener.codec import GpsFix, OdometerSample, decode_input, decode_output_extended, encode_ack
    from listener.config import ListenerConfig
    from listener.pipeline import Pipeline
    from sfa import layout as L
    from tools.adapters.common import MODULE_PORTS, read_pcap_udp
    from track_db import TrackDatabase

    cfg = config or ListenerConfig()
    cfg = replace(cfg, link=replace(cfg.link, extended=True))
    if not vet_outputs:
        cfg = replace(cfg, plausibility=replace(cfg.plausibility, enabled=False))
    track = TrackDatabase.open(track_path)
    filt = None
    if filter_config is not None:
        from sfa.filter import TrackFilter

        filt = TrackFilter(track, filter_config)
    pipe = Pipeline(track, cfg, filt)
    frames = read_pcap_udp(capture)
    rows: list[tuple] = []
    updates: list[tuple] = []

    def on_update(upd) -> None:
        f = pipe.filter
        if not f.initialised:
            return
        e = f.estimate()
        x, _ = f.state()
        updates.append((upd.t_s, upd.kind, upd.outcome.name.lower(), math.nan if upd.nis is None else upd.nis,
                        e.arc_length_m, e.speed_mps, e.sigma_s_m, e.status.name.lower(), e.direction,
                        e.hypotheses,
                        float(x[L.BA]), float(x[L.KO]), float(x[L.BG])))

    pipe.on_update = on_update
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

    withheld = 0
    if gap_ports is None:
        gap_ports = frozenset({MODULE_PORTS["gps"]})
    for ts, sport, payload in frames:
        if sport in exclude_ports:
            continue
        if gps_gap is not None and sport in gap_ports:
            msg = decode_input(payload)
            if isinstance(msg, GpsFix | OdometerSample) and msg.epoch is not None \
                    and gps_gap[0] <= msg.epoch < gps_gap[1]:
                withheld += 1
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
    return {"estimates": est, "metrics": pipe.metrics(), "gps_withheld": withheld, "updates": updates}


def write_updates_csv(path: str | Path, updates: list[tuple]) -> int:
    """``updates.csv``: the rows of :data:`UPDATE_FIELDS` recorded by :func:`run_pipeline`."""
    try:
        with open(path, "w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh, lineterminator="\n")
            w.writerow(UPDATE_FIELDS)
            for r in updates:
                w.writerow([f"{r[0]:.3f}", r[1], r[2], f"{r[3]:.3f}", f"{r[4]:.3f}", f"{r[5]:.3f}",
                            f"{r[6]:.3f}", r[7], r[8], r[9], f"{r[10]:.4f}", f"{r[11]:.4f}", f"{r[12]:.5f}"])
    except OSError as exc:
        raise ToolError(f"cannot write {str(path)!r}: {exc}") from exc
    return len(updates)


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


def self_consistency(estimates: dict[str, np.ndarray], reference: dict[str, np.ndarray],
                     gps_gap: tuple[float, float] | None = None) -> dict:
    """Checks possible without truth (Dresden), against gnss_on_track.csv (each GNSS fix projected on
    the track, locally): the estimate at each fix's epoch minus the fix's arc length (along-track
    residual: p50, p95, max, rms), the fixes' distance from the track, and the continuity of the output
    (each step of the arc length against speed x time, speed changes, backward steps). With ``gps_gap``
    (epochs [start, end) of fixes withheld from the filter) the residual against the withheld fixes is
    reported separately (``gap_*``): how far the estimate drifts from the GNSS it did not see."""
    et, es, ev = estimates["epoch"], estimates["arc_length"], estimates["speed"]
    t, s_fix = reference["epoch"], reference["arc_length"]
    inside = (t >= et[0]) & (t <= et[-1])
    resid = np.interp(t[inside], et, es) - s_fix[inside]
    a = np.abs(resid)
    gap: dict[str, float | int] = {}
    if gps_gap is not None:
        tin = t[inside]
        g = np.abs(resid[(tin >= gps_gap[0]) & (tin < gps_gap[1])])
        gap = {"gap_start_epoch": float(gps_gap[0]), "gap_end_epoch": float(gps_gap[1]),
               "gap_fixes": int(g.size)}
        if g.size:
            gap.update(gap_residual_p50_m=float(np.percentile(g, 50)),
                       gap_residual_p95_m=float(np.percentile(g, 95)),
                       gap_residual_max_m=float(g.max()), gap_residual_end_m=float(g[-1]))
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
        **gap,
    }
