"""From what a run observed to one row of the results table, with a PASS/FAIL per expectation.

Both runners (replay path, live processes) fill an :class:`Observation`; :func:`evaluate` turns it
into a flat row (strings and numbers only, ready for CSV/markdown/HTML). Definitions:

- *fresh output*: an output the OBCU received whose SEQ is newer than every SEQ before it.
- *error*: estimate minus truth interpolated at the estimate's epoch (``tools.accuracy``).
- *losses*: drops (and truncations, always rejected) on the input link a receiver can see (not before
  a sender's first datagram, not after its last) versus the listener's ``sequencing.lost``;
  *duplicates*: duplicated + replayed versus ``duplicates + late + probation_drops`` (a replay from
  further back than the buffer's ``max_backward`` is a restart candidate, dropped in probation);
  *reorders*: versus ``reordered``; *rejects*: datagrams that no correct decoder accepts
  (forged-invalid, garbage, truncated) versus ``input.rejected``; *net drops*: datagrams the proxy
  sent that the listener never received (live: its socket buffer overflowed).
- *age*: arrival at the OBCU minus the estimate's epoch (replay: exact, the capture clock is the
  sensor clock; live: relative to the freshest output, the clocks being unrelated).
- *recovery*: after a blackout ends, time until the link is UP again (output link) or until the
  first fresh output (input link).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tools.accuracy import accuracy


@dataclass
class Observation:
    """What one run saw (times in seconds from the run start, sensor-time scale)."""

    name: str
    mode: str
    simulated_s: float
    truth_epoch: np.ndarray
    truth_arc: np.ndarray
    start_epoch_s: float  #: sensor-set time of the scenario start [s]
    fresh_arrival: np.ndarray  #: arrival of each fresh output, from the run start [s]
    fresh_epoch: np.ndarray
    fresh_arc: np.ndarray
    fresh_lo: np.ndarray
    fresh_hi: np.ndarray
    fresh_age: np.ndarray  #: age of each fresh output [s]
    fresh_reasons: list[tuple[str, ...]] | None  #: per fresh output (None: not observable)
    metrics: dict[str, Any]  #: listener metrics at exit
    link_transitions: list[tuple[float, str]]
    input_proxy: dict[str, int]
    output_proxy: dict[str, int]
    input_blackouts: tuple[tuple[float, float], ...]
    output_blackouts: tuple[tuple[float, float], ...]  #: OBCU-link outages (blackout, silent OBCU, no acks)
    sensor_fault_windows: list[tuple[float, float]]  #: (start_s, end_s) from the scenario start
    crashes: int
    crash_detail: str = ""
    memory_growth_mb: float | None = None
    latency_p99_ms: float | None = None
    #: live, injections: p99 age of the outputs due during the injection minus that just before it [ms]
    latency_delta_ms: float | None = None
    reasons_seen: set[str] = field(default_factory=set)  #: live: reasons from the metrics events
    wall_s: float = 0.0
    notes: list[str] = field(default_factory=list)
    corruption: bool = False  #: bit flips on the input link (gaps then also come from rejects)
    auth: dict[str, Any] = field(default_factory=dict)  #: authenticated link counters (replay path)
    #: STATUS of each fresh output as the OBCU received it (extended output; None: not observable)
    fresh_status: np.ndarray | None = None
    #: kill -9 and restart: kill_s, restart_s (run time of the new process's start), last_seq_before
    #: (newest SEQ the OBCU had by then), first_seq_after (first SEQ it received after), lost_while_down
    restart: dict[str, Any] = field(default_factory=dict)
    stop_exit_s: float | None = None  #: from the real STOP's arrival to the listener's stop [s]
    status_reasons: set[str] = field(default_factory=set)  #: reasons of the non-nominal status events
    #: length of the run on the fresh_arrival axis (None: simulated_s; live: wall seconds, simulated_s /
    #: speed, so that a live row at speed 10 ends at 9 s, not 90 s) [s]
    run_s: float | None = None

    @property
    def end_s(self) -> float:
        """Where the run ends on the arrival axis [s]."""
        return self.simulated_s if self.run_s is None else self.run_s


#: the trust checks' warning events (listener.senders, listener.seqbuf through the pipeline)
TRUST_WARNINGS = ("sender_rejected", "sender_would_reject", "sequence_jump_held", "sequence_jump_dropped",
                  "sequence_gap_rate_limited")


def _fmt(x: float | None, digits: int = 2) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "n/a"
    return f"{x:.{digits}f}"


def _timeline(transitions: list[tuple[float, str]], until_s: float) -> str:
    parts = [f"{state}@{t:.1f}" for t, state in transitions if t <= until_s]
    return " ".join(parts) if parts else "idle"


def _recovery(obs: Observation) -> tuple[float | None, float | None]:
    """(worst time to DEGRADED after an output-link blackout starts, worst time to recover) [s]."""
    degraded: list[float] = []
    recover: list[float] = []
    for a, d in obs.output_blackouts:
        to_deg = [t - a for t, s in obs.link_transitions if t >= a and s in ("degraded", "down")]
        degraded.append(to_deg[0] if to_deg else math.inf)
        ups = [t - (a + d) for t, s in obs.link_transitions if t >= a + d and s == "up"]
        recover.append(ups[0] if ups else math.inf)
    for a, d in obs.input_blackouts:
        after = obs.fresh_arrival[obs.fresh_arrival >= a + d]
        recover.append(float(after[0] - (a + d)) if after.size else math.inf)
    return (max(degraded) if degraded else None), (max(recover) if recover else None)


def fault_mask(obs: Observation) -> np.ndarray:
    """True for each fresh output whose epoch (from the scenario start) lies in a sensor-fault window."""
    rel = obs.fresh_epoch - obs.start_epoch_s
    mask = np.zeros(rel.size, dtype=bool)
    for a, b in obs.sensor_fault_windows:
        mask |= (rel >= a) & (rel < b)
    return mask


def evaluate(obs: Observation, expect: dict[str, Any]) -> dict[str, Any]:
    """One results row: figures, then ``checks`` (PASS/FAIL per expectation) and ``verdict``."""
    row, checks = _figures(obs, expect)
    return _with_verdict(row, checks, obs.notes)


def _with_verdict(row: dict[str, Any], checks: dict[str, bool], notes: list[str]) -> dict[str, Any]:
    row["checks"] = " ".join(f"{k}:{'PASS' if ok else 'FAIL'}" for k, ok in checks.items()) or "-"
    row["verdict"] = "PASS" if all(checks.values()) else "FAIL"
    row["notes"] = "; ".join(notes)
    return row


def _figures(obs: Observation, expect: dict[str, Any]) -> tuple[dict[str, Any], dict[str, bool]]:
    """The row's figures and the PASS (True) / FAIL of each expectation."""
    acc = accuracy(obs.fresh_epoch, obs.fresh_arc, obs.truth_epoch, obs.truth_arc, obs.fresh_lo, obs.fresh_hi)
    seq = obs.metrics.get("sequencing", {})
    inp = obs.metrics.get("input", {})
    ip = obs.input_proxy
    row: dict[str, Any] = {
        "scenario": obs.name,
        "mode": obs.mode,
        "sim_s": round(obs.simulated_s, 1),
        "crashes": obs.crashes,
        "fresh_outputs": int(obs.fresh_epoch.size),
        "p95_m": _fmt(acc.p95_m),
        "max_m": _fmt(acc.max_m),
        "coverage": _fmt(acc.coverage, 4),
    }
    # sensor fault windows: coverage inside, reasons reported
    fault_cov = None
    reasons: set[str] = set(obs.reasons_seen)
    if obs.sensor_fault_windows:
        mask = fault_mask(obs)
        if mask.any():
            sub = accuracy(obs.fresh_epoch[mask], obs.fresh_arc[mask], obs.truth_epoch, obs.truth_arc,
                           obs.fresh_lo[mask], obs.fresh_hi[mask])
            fault_cov = sub.coverage
        if obs.fresh_reasons is not None:
            for i in np.flatnonzero(mask):
                reasons.update(obs.fresh_reasons[i])
    row["fault_coverage"] = _fmt(fault_cov, 4) if obs.sensor_fault_windows else "-"
    row["told_s"], row["told_status"] = _told(obs)
    row["nominal_age_max_s"] = _nominal_age_max(obs)
    row["reasons"] = " ".join(sorted(reasons - {"standstill"})) if obs.sensor_fault_windows else "-"
    # injected versus detected
    ip = {k: int(v) for k, v in obs.input_proxy.items()}
    zero = dict.fromkeys(("dropped_loss", "dropped_burst", "dropped_blackout", "leading_drops",
                          "trailing_drops",
                          "forged_invalid", "garbage", "truncated", "duplicated", "replayed", "reordered",
                          "bitflipped", "forged_valid", "forged_foreign", "forged_jump"), 0)
    ip = {**zero, **ip}  # no input proxy: nothing injected
    visible = (ip["dropped_loss"] + ip["dropped_burst"] + ip["dropped_blackout"] + ip["truncated"]
               - ip["leading_drops"] - ip["trailing_drops"])
    must_reject = ip["forged_invalid"] + ip["garbage"] + ip["truncated"]
    rejected = int(inp.get("rejected", 0))
    row.update({
        "lost_inj": visible, "lost_det": int(seq.get("lost", 0)),
        "dup_inj": ip["duplicated"] + ip["replayed"],
        "dup_det": (int(seq.get("duplicates", 0)) + int(seq.get("late", 0))
                    + int(seq.get("probation_drops", 0))),
        "reord_inj": ip["reordered"], "reord_det": int(seq.get("reordered", 0)),
        "rej_inj": must_reject, "rej_det": rejected,
        "flips": ip["bitflipped"], "forged_valid": ip["forged_valid"],
    })
    # what the codec accepted beyond what may legitimately be accepted (originals, their copies, valid
    # forgeries; truncated ones never): exact on the replay path, a lower bound live, where the kernel
    # may also drop datagrams between the proxy and the listener (``net_drops``)
    accepted = sum(int(v) for v in inp.get("by_type", {}).values())
    legit = (ip.get("forwarded", 0) + ip["duplicated"] + ip["replayed"] + ip["forged_valid"]
             + ip["forged_jump"] + ip.get("forged_masquerade", 0) + ip.get("burst_replayed", 0)
             - ip["truncated"])
    row["accepted_bad"] = max(0, accepted - legit) if obs.input_proxy else 0
    # issue 20: forgeries the sender table must reject (foreign GROUND TRUTH / STOP), SEQ jumps on a real
    # sender's stream (what they cost: datagrams dropped as late), and the warnings seen
    by_reason = inp.get("rejected_by_reason", {})
    row["foreign_inj"] = ip["forged_foreign"]
    row["foreign_det"] = sum(int(v) for k, v in by_reason.items() if str(k).startswith("sender_"))
    row["jump_inj"] = ip["forged_jump"]
    row["late_det"] = int(seq.get("late", 0))
    row["jump_drops"] = int(seq.get("jump_drops", 0))
    seen = obs.metrics.get("warnings_seen", {})
    row["trust_warnings"] = " ".join(f"{k}:{seen[k]}" for k in TRUST_WARNINGS if seen.get(k)) or "-"
    row["warnings"] = " ".join(f"{k}:{v}" for k, v in sorted(seen.items())) or "-"
    row["outputs_lost"], row["longest_gap_s"] = _outputs_lost(obs)
    row["status_reasons"] = " ".join(sorted(_status_reasons(obs))) or "-"
    rs = obs.restart
    if rs:
        row["kill_s"] = _fmt(rs.get("kill_s"))
        row["restart_s"] = _fmt(rs.get("restart_s"))
        row["resume_s"] = _fmt(_resume_s(obs))
        row["seq_before"] = rs.get("last_seq_before", "-")
        row["seq_after"] = rs.get("first_seq_after", "-")
        row["lost_while_down"] = rs.get("lost_while_down", "-")
    if "stop_exit_within_s" in expect or obs.stop_exit_s is not None:
        row["stop_exit_s"] = _fmt(obs.stop_exit_s, 3)
    res = obs.metrics.get("resilience", {})
    row["gt_held"] = int(res.get("ground_truth", {}).get("held", 0))
    gt = res.get("ground_truth", {})
    row["gt_confirmed"] = sum(int(v) for k, v in gt.items() if k.startswith("confirmed"))
    row["masquerade_inj"] = ip.get("forged_masquerade", 0)
    row["burst_inj"] = ip.get("burst_replayed", 0)
    if obs.auth:
        rej = obs.auth.get("rejected", {})
        row["auth_replay_rej"] = int(rej.get("auth_replay", 0)) + int(rej.get("auth_old", 0))
    row["net_drops"] = (max(0, int(ip.get("emitted", 0)) - int(inp.get("received", 0)))
                        if obs.input_proxy else 0)
    seq_resyncs = int(seq.get("resyncs", 0))
    row["resyncs"] = seq_resyncs
    if obs.auth:
        row["auth_acc"] = obs.auth.get("accepted", 0)
        row["auth_rej"] = sum(obs.auth.get("rejected", {}).values())
        row["auth_bad"] = obs.auth.get("bad", 0)
    age = obs.fresh_age[np.isfinite(obs.fresh_age)] if obs.fresh_age.size else obs.fresh_age
    row["age_p99_s"] = _fmt(float(np.percentile(age, 99)) if age.size else None, 3)
    row["age_max_s"] = _fmt(float(age.max()) if age.size else None, 3)
    row["stale_fresh"] = int(np.sum(age > 1.0)) if age.size else 0
    deg, rec = _recovery(obs)
    row["degraded_after_s"] = _fmt(deg)
    row["recover_s"] = _fmt(rec)
    row["link_timeline"] = _timeline(obs.link_transitions, obs.simulated_s + 0.5)
    row["memory_growth_mb"] = _fmt(obs.memory_growth_mb, 1)
    row["latency_p99_ms"] = _fmt(obs.latency_p99_ms, 1)
    row["wall_s"] = round(obs.wall_s, 1)
    return row, _checks(row, obs, expect, acc, fault_cov, reasons, deg, rec)


_STATUS = {0: "initialising", 1: "nominal", 2: "degraded", 3: "lost"}


def _told(obs: Observation) -> tuple[str, str]:
    """Intervention time at the OBCU: from the first sensor fault's onset to the arrival of the first
    fresh output whose STATUS is not NOMINAL (times from the run start), and that status; "-" without a
    sensor fault or an observable status, "never" when no such output came during the fault."""
    if not obs.sensor_fault_windows or obs.fresh_status is None:
        return "-", "-"
    a, b = obs.sensor_fault_windows[0]
    hit = np.flatnonzero((obs.fresh_arrival >= a) & (obs.fresh_arrival < b + 5.0) & (obs.fresh_status != 1))
    if not hit.size:
        return "never", "-"
    i = int(hit[0])
    code = int(obs.fresh_status[i])
    return _fmt(float(obs.fresh_arrival[i] - a), 3), _STATUS.get(code, str(code))


def _nominal_age_max(obs: Observation) -> str:
    """Largest age at the OBCU of a fresh output that said NOMINAL (SUBSET-041: must stay below 1 s)."""
    if obs.fresh_status is None or not obs.fresh_age.size:
        return "-"
    age = obs.fresh_age[(obs.fresh_status == 1) & np.isfinite(obs.fresh_age)]
    return _fmt(float(age.max()) if age.size else None, 3)


def _outputs_lost(obs: Observation) -> tuple[int, str]:
    """(outputs missing, longest gap between fresh outputs [s]) from the first fresh output to the end:
    each gap longer than 3 median intervals counts as gap / median - 1 missing outputs."""
    t = np.sort(obs.fresh_arrival[np.isfinite(obs.fresh_arrival)])
    if t.size < 3:
        return 0, "n/a"
    gaps = np.diff(np.append(t, max(float(t[-1]), obs.end_s)))
    med = float(np.median(gaps[:-1]))
    if med <= 0.0:
        return 0, _fmt(float(gaps.max()))
    long = gaps[gaps > 3.0 * med]
    return int(round(float(np.sum(long / med - 1.0)))), _fmt(float(gaps.max()))


def _status_reasons(obs: Observation) -> set[str]:
    """Reasons carried by a non-nominal status: the listener's status events, and the fresh outputs'."""
    out = set(obs.status_reasons)
    if obs.fresh_reasons is not None and obs.fresh_status is not None:
        for status, reasons in zip(obs.fresh_status.tolist(), obs.fresh_reasons, strict=True):
            if status != 1:
                out.update(reasons)
    return out


def _resume_s(obs: Observation) -> float | None:
    """From the restart to the first fresh output after it [s] (inf: none came)."""
    rs = obs.restart
    if not rs or rs.get("restart_s") is None:
        return None
    after = obs.fresh_arrival[obs.fresh_arrival >= rs["restart_s"]]
    return float(after.min() - rs["restart_s"]) if after.size else math.inf


def _seq_continues(obs: Observation) -> bool:
    from listener.serial import serial_gt

    rs = obs.restart
    before, after = rs.get("last_seq_before"), rs.get("first_seq_after")
    if after is None:
        return False
    return before is None or serial_gt(int(after), int(before))


def _checks(row, obs, expect, acc, fault_cov, reasons, deg, rec) -> dict[str, bool]:
    out: dict[str, bool] = {"crashes": obs.crashes <= int(expect.get("crashes", 0))}
    def le(value, bound):
        return value is not None and math.isfinite(value) and value <= bound

    def ge(value, bound):
        return value is not None and math.isfinite(value) and value >= bound

    if "p95_m" in expect:
        out["p95_m"] = le(acc.p95_m, expect["p95_m"])
    if "max_m" in expect:
        out["max_m"] = le(acc.max_m, expect["max_m"])
    if "coverage" in expect:
        out["coverage"] = ge(acc.coverage, expect["coverage"])
    if "fault_coverage" in expect:
        out["fault_coverage"] = ge(fault_cov, expect["fault_coverage"])
    if "losses_match" in expect:
        out["losses_match"] = not obs.corruption and row["lost_inj"] == row["lost_det"]
    if "duplicates_match" in expect:
        out["duplicates_match"] = row["dup_inj"] == row["dup_det"]
    if "reorders_match" in expect:
        out["reorders_match"] = row["reord_inj"] == row["reord_det"]
    if "rejected_match" in expect:
        out["rejected_match"] = row["rej_det"] + row["net_drops"] >= row["rej_inj"]
    if "accepted_bad" in expect:
        out["accepted_bad"] = row["accepted_bad"] <= expect["accepted_bad"]
    if "max_fresh_age_s" in expect:
        age = obs.fresh_age[np.isfinite(obs.fresh_age)]
        out["max_fresh_age_s"] = bool(age.size) and float(age.max()) <= expect["max_fresh_age_s"]
    if "degraded_within_s" in expect:
        out["degraded_within_s"] = le(deg, expect["degraded_within_s"])
    if "recover_within_s" in expect:
        out["recover_within_s"] = le(rec, expect["recover_within_s"])
    if "reasons" in expect:
        out["reasons"] = bool(reasons & set(expect["reasons"]))
    if "foreign_rejected_match" in expect:
        out["foreign_rejected_match"] = row["foreign_det"] + row["net_drops"] >= row["foreign_inj"] > 0
    if "late_max" in expect:
        out["late_max"] = row["late_det"] <= expect["late_max"]
    if "outputs_to_end_s" in expect:
        last = float(obs.fresh_arrival.max()) if obs.fresh_arrival.size else -math.inf
        out["outputs_to_end_s"] = obs.end_s - last <= expect["outputs_to_end_s"]
    if "auth_bad" in expect:
        out["auth_bad"] = bool(obs.auth) and obs.auth.get("bad", 0) <= expect["auth_bad"]
    if "resume_within_s" in expect:
        out["resume_within_s"] = le(_resume_s(obs), expect["resume_within_s"])
    if "seq_continues" in expect:
        out["seq_continues"] = bool(obs.restart) and _seq_continues(obs)
    if "warnings" in expect:
        seen = obs.metrics.get("warnings_seen", {})
        out["warnings"] = all(seen.get(w, 0) > 0 for w in expect["warnings"])
    if "status_reasons" in expect:
        out["status_reasons"] = set(expect["status_reasons"]) <= _status_reasons(obs)
    if "max_gap_s" in expect:
        gap = row["longest_gap_s"]
        out["max_gap_s"] = gap != "n/a" and float(gap) <= expect["max_gap_s"]
    if "stop_exit_within_s" in expect:
        out["stop_exit_within_s"] = le(obs.stop_exit_s, expect["stop_exit_within_s"])
    if "ground_truth_held_match" in expect:
        out["ground_truth_held_match"] = (row["gt_held"] >= row["masquerade_inj"] > 0
                                          and row["gt_confirmed"] == 0)
    if "burst_rejected_match" in expect:
        # a restart row's input counters are the restarted process's only: no net_drops figure there
        net = 0 if obs.restart else row["net_drops"]
        out["burst_rejected_match"] = (bool(obs.auth) and obs.auth.get("bad", 0) == 0
                                       and row.get("auth_replay_rej", 0) + net >= row["burst_inj"] > 0)
    # process-level figures exist in live mode only: elsewhere the check is not run (and said so)
    for key, value in (("memory_growth_mb", obs.memory_growth_mb), ("latency_p99_ms", obs.latency_p99_ms),
                       ("latency_delta_ms", obs.latency_delta_ms)):
        if key in expect:
            if value is None and not obs.mode.startswith("live"):
                obs.notes.append(f"{key}: live mode only")
            else:
                out[key] = le(value, expect[key])
    return out


def _summed(values: list[Any]) -> Any:
    """Counters of several runs added up (nested dicts of numbers; anything else: the first run's)."""
    first = values[0]
    if isinstance(first, dict):
        keys = {k for v in values if isinstance(v, dict) for k in v}
        return {k: _summed([v.get(k, 0) for v in values if isinstance(v, dict)]) for k in sorted(keys)}
    if isinstance(first, (int, float)) and not isinstance(first, bool):
        return sum(v for v in values if isinstance(v, (int, float)) and not isinstance(v, bool))
    return first


def pool(runs: list[Observation]) -> Observation:
    """Independent repetitions of one row as one observation: the figures are then the pooled ones.

    Repetition k is laid out ``k * span`` seconds after the first, on both its sensor time (truth,
    estimates, scenario start) and its run time (arrivals, link transitions, blackouts, fault
    windows), so every time-relative figure keeps its meaning; counters add up. ``simulated_s`` is
    the total.
    """
    if len(runs) == 1:
        return runs[0]
    span = 10.0 ** math.ceil(math.log10(max(r.simulated_s for r in runs) + 1e3))
    first = runs[0]

    def cat(get) -> np.ndarray:
        return np.concatenate([np.asarray(get(r, k), dtype=float) for k, r in enumerate(runs)])

    def epoch_shift(r: Observation, k: int) -> float:  # sensor time of repetition k
        return first.start_epoch_s - r.start_epoch_s + k * span

    def windows(get) -> tuple[tuple[float, float], ...]:
        return tuple((a + k * span, b) for k, r in enumerate(runs) for a, b in get(r))

    status = None if any(r.fresh_status is None for r in runs) else np.concatenate(
        [np.asarray(r.fresh_status) for r in runs])
    reasons = None if any(r.fresh_reasons is None for r in runs) else [
        x for r in runs for x in (r.fresh_reasons or [])]
    return Observation(
        name=first.name, mode=first.mode, simulated_s=sum(r.simulated_s for r in runs),
        # each run's truth fenced by NaN just outside it: an estimate dated outside its own run's truth
        # gets no error (as accuracy() drops it from one run), not one across two runs' seam
        truth_epoch=cat(lambda r, k: _fenced(r.truth_epoch, 1e-6) + epoch_shift(r, k)),
        truth_arc=cat(lambda r, k: np.concatenate([[np.nan], r.truth_arc, [np.nan]])),
        start_epoch_s=first.start_epoch_s,
        fresh_arrival=cat(lambda r, k: r.fresh_arrival + k * span),
        fresh_epoch=cat(lambda r, k: r.fresh_epoch + epoch_shift(r, k)),
        fresh_arc=cat(lambda r, k: r.fresh_arc), fresh_lo=cat(lambda r, k: r.fresh_lo),
        fresh_hi=cat(lambda r, k: r.fresh_hi), fresh_age=cat(lambda r, k: r.fresh_age),
        fresh_reasons=reasons,
        metrics=_summed([r.metrics for r in runs]),
        link_transitions=[(t + k * span, s) for k, r in enumerate(runs) for t, s in r.link_transitions],
        input_proxy=_summed([r.input_proxy for r in runs]),
        output_proxy=_summed([r.output_proxy for r in runs]),
        input_blackouts=windows(lambda r: r.input_blackouts),
        output_blackouts=windows(lambda r: r.output_blackouts),
        sensor_fault_windows=[(a + k * span, b + k * span) for k, r in enumerate(runs)
                              for a, b in r.sensor_fault_windows],
        crashes=sum(r.crashes for r in runs),
        crash_detail="".join(r.crash_detail for r in runs),
        memory_growth_mb=_max_or_none([r.memory_growth_mb for r in runs]),
        latency_p99_ms=_max_or_none([r.latency_p99_ms for r in runs]),
        latency_delta_ms=_max_or_none([r.latency_delta_ms for r in runs]),
        reasons_seen=set().union(*(r.reasons_seen for r in runs)),
        wall_s=sum(r.wall_s for r in runs),
        notes=[n for r in runs for n in r.notes],
        corruption=any(r.corruption for r in runs),
        auth=_summed([r.auth for r in runs]) if all(r.auth for r in runs) else {},
        fresh_status=status,
        status_reasons=set().union(*(r.status_reasons for r in runs)),
        run_s=None if all(r.run_s is None for r in runs) else sum(r.end_s for r in runs),
    )


def _max_or_none(values: list[float | None]) -> float | None:
    got = [v for v in values if v is not None]
    return max(got) if got else None


def _fenced(epoch: np.ndarray, eps: float) -> np.ndarray:
    e = np.asarray(epoch, dtype=float)
    return np.concatenate([[e[0] - eps], e, [e[-1] + eps]])


#: expectations judged on the pooled outputs of a row's repetitions; every other one (counts, times,
#: matches, reasons) must hold in each repetition on its own
POOLED_CHECKS = frozenset({"p95_m", "max_m", "coverage", "fault_coverage"})


def evaluate_pooled(runs: list[Observation], expect: dict[str, Any]) -> dict[str, Any]:
    """The row of several repetitions: figures of :func:`pool`; the accuracy checks
    (:data:`POOLED_CHECKS`) on the pooled outputs, every other check passing only where it passes in
    every repetition (a bound such as ``late_max`` is per run, not per sum of runs). ``notes`` lists
    each repetition's p95/max/coverage."""
    if len(runs) == 1:
        return evaluate(runs[0], expect)
    singles = [_figures(r, expect) for r in runs]
    pooled = pool(runs)
    row, checks = _figures(pooled, expect)
    notes = [f"{len(runs)} seeds pooled (p95/max/coverage: "
             + ", ".join(f"{r['p95_m']}/{r['max_m']}/{r['coverage']}" for r, _ in singles) + ")"]
    for key in ("resume_s", "stop_exit_s", "longest_gap_s"):  # per-run times: the worst seed's
        vals = [r.get(key) for r, _ in singles if r.get(key) not in (None, "n/a", "-")]
        if vals:
            row[key] = max(vals, key=float)
    row["outputs_lost"] = sum(int(r["outputs_lost"]) for r, _ in singles)  # not the seams between runs
    if any("kill_s" in r for r, _ in singles):
        row["kill_s"] = " ".join(str(r.get("kill_s")) for r, _ in singles)
        row["seq_before"] = row["seq_after"] = row["restart_s"] = "per seed"
    for key in checks:
        if key not in POOLED_CHECKS:
            bad = [k for k, (_, c) in enumerate(singles) if not c.get(key, False)]
            checks[key] = not bad
            if bad:
                notes.append(f"{key} fails in seeds {','.join(map(str, bad))}")
    return _with_verdict(row, checks, notes + pooled.notes)
