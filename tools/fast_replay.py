"""Fast replay: the exact replay's estimates at compiled speed, on captures that allow it.

``tools.replay.replay_capture`` drives the listener's pipeline object per datagram (a few thousand
datagrams per second). On a clean capture almost all of that work is bookkeeping whose outcome is
known in advance: every stream in order, every measurement dated by its own epoch, the merge
releasing each measurement at once (``merge.hold_s = 0``), one line hypothesis. :func:`fast_replay`
checks that this is so and then runs the whole capture in compiled code:

1. the pcap is memory-mapped and walked in a numba loop (:mod:`tools.fast_pcap`; classic pcap,
   Ethernet, IPv4, UDP at fixed offsets),
2. INPUT payloads are decoded in one compiled pass driven by listener.codec's own tables
   (:mod:`tools.fast_decode`); rejected ones get their reason from ``listener.codec`` itself,
3. the start of the capture (until every stream is past its start-up hold and the filter keeps a
   single line hypothesis) goes through the exact pipeline, datagram by datagram,
4. the rest is checked (each stream continues in sequence, no gap, no reordering, epochs present,
   no GROUND TRUTH re-initialisation), packed into ``sfa.batch`` arrays and stepped through the same
   kernels as the per-message filter (:mod:`tools.fast_loop`), from the exact pipeline's filter state,
5. the result is refused after the fact if the estimate came within the junction window of a
   junction of its line (where the per-message filter would have spawned branch hypotheses).

When any condition fails it returns None (and :func:`try_fast_replay` says why): the caller runs the
exact replay instead. What the result does not simulate: retransmissions of the OBCU link after the
exact prefix (the fast path returns new estimates only; retransmissions never change a new
estimate), and link state transitions. Everything else (estimates, per-measurement outcomes and NIS,
GNSS fixes, input/sequencing/clock/filter counters) equals the exact replay's, which
tests/test_fast_replay.py checks field by field.
"""

from __future__ import annotations

import math
import sys
from collections import Counter, deque
from dataclasses import dataclass

import numpy as np

#: datagrams replayed through the exact pipeline at most before the hand-over to compiled code
MAX_EXACT_PREFIX = 200_000
_KIND_NAME = {1: "imu", 2: "odo", 3: "gps", 8: "init"}
_TYPE_NAME = {1: "imu", 2: "odometer", 3: "gps", 8: "ground_truth", 9: "strobe", 10: "stop"}


@dataclass(frozen=True)
class FastReplayInfo:
    """How a fast replay went."""

    used: bool  #: True: the result came from the fast path
    reason: str  #: why the exact replay is needed ("" when used)
    exact_prefix: int = 0  #: datagrams that went through the exact pipeline first
    compiled: int = 0  #: datagrams handled by the compiled path


def fast_replay(capture_path, track, options=None):
    """Replay ``capture_path`` like :func:`tools.replay.replay_capture`, in compiled code.

    Returns a :class:`tools.replay.ReplayResult` (new estimates only after the exact prefix) or None
    when the capture or the options need the exact replay.
    """
    result, _ = try_fast_replay(capture_path, track, options)
    return result


def try_fast_replay(capture_path, track, options=None):
    """(ReplayResult or None, FastReplayInfo saying which path and why)."""
    from tools.replay import ReplayOptions

    options = options or ReplayOptions()
    why = _options_reason(options)
    if why:
        return None, FastReplayInfo(False, why)
    from tools.fast_pcap import scan_capture

    scan = scan_capture(capture_path, options.port)
    if isinstance(scan, str):
        return None, FastReplayInfo(False, f"capture: {scan}")
    if scan.time_s.size == 0:
        return None, FastReplayInfo(False, "no datagram to the listener port")
    return _replay_scanned(scan, track, options)


def _options_reason(options) -> str:
    from tools.replay import SENSOR_TYPES

    cfg = options.config
    if sys.byteorder != "little":
        return "big-endian host"
    if set(options.sensors) != set(SENSOR_TYPES):
        return "sensor selection (some sensors disabled)"
    if options.record_measurements:
        return "measurements recorded (baselines)"
    if cfg.merge.hold_s != 0.0:
        return f"merge.hold_s = {cfg.merge.hold_s} (the fast path needs 0)"
    if cfg.link.max_rate_hz != 0.0:
        return f"link.max_rate_hz = {cfg.link.max_rate_hz} (the fast path needs 0)"
    return ""


# ---------------------------------------------------------------------------------------- prefix
class _Prefix:
    """The exact pipeline over the first datagrams, recording exactly as tools.replay does."""

    def __init__(self, track, options) -> None:
        from tools.replay import build_pipeline

        self.pipe = build_pipeline(track, options)
        self.est_rows: list[tuple] = []
        self.upd: list[tuple] = []
        self.gps_rows: list[tuple] = []
        self.by_seq: dict = {}  # SEQ -> the estimate last encoded with it
        self.fresh: deque[int] = deque()  # SEQs encoded as new estimates, not yet seen in an output
        self.pipe.on_output = self._on_output
        self.pipe.on_update = lambda u: self.upd.append(
            (u.t_s, u.kind, int(u.outcome), math.nan if u.nis is None else float(u.nis))
        )

    def _on_output(self, seq: int, est) -> None:
        self.by_seq[seq] = est
        self.fresh.append(seq)

    def record(self, outputs, now) -> None:
        from listener.codec import decode_output
        from tools.replay import estimate_row

        for payload in outputs:
            msg = decode_output(payload[:18])
            est = self.by_seq[msg.seq]
            # as tools.replay: a new estimate's datagram follows its encoding; anything else is a resend
            if self.fresh and self.fresh[0] == msg.seq:
                self.fresh.popleft()
                retransmit = 0
            else:
                retransmit = 1
            self.est_rows.append(estimate_row(msg, est, retransmit, now))

    def feed(self, t, addr, payload, gps) -> None:
        pipe = self.pipe
        for _ in range(1000):
            nxt = pipe.next_timer()
            if nxt is None or nxt > t:
                break
            self.record(pipe.handle_timer(nxt), nxt)
        if gps is not None:
            self.gps_rows.append((t, *gps))
        self.record(pipe.receive(payload, addr, t), t)

    def ready(self) -> bool:
        """Hand-over point: one hypothesis, nothing held in sequence buffers, merge or undated queue."""
        pipe = self.pipe
        if pipe.stopped or not pipe.filter.initialised or pipe.streams.next_deadline() is not None:
            return False
        if pipe.filter.estimate().hypotheses != 1:
            return False
        m = pipe.metrics()
        seq = m["sequencing"]
        clean = all(
            seq[k] == 0
            for k in (
                "reordered",
                "duplicates",
                "lost",
                "late",
                "resyncs",
                "overflow",
                "probation_drops",
                "pending",
            )
        )
        return (
            clean
            and m["merge"]["pending"] == 0
            and m["clock"]["undated_pending"] == 0
            and seq["evictions"] == 0
        )


def _gps_of(dec, i):
    """(lat, lon, fix quality) of a decoded GPS datagram, as tools.replay records it."""
    v = dec.values[i]
    ni = int(dec.n_int[i])
    fq = int(v[0]) if ni == 2 else -1
    return float(v[ni]), float(v[ni + 1]), fq


# ---------------------------------------------------------------------------------------- main path
def _replay_scanned(scan, track, options):
    from listener.codec import DecodeError, decode_input
    from tools.fast_decode import decode_batch
    from tools.fast_pack import EPOCH_DOUBLES
    from tools.fast_pcap import SKIP_REASONS, ipv4_text

    dec = decode_batch(scan.data, scan.offset, scan.length)
    n_all = scan.time_s.size
    stop_rows = np.flatnonzero(dec.ok & (dec.stype == 10))
    n = int(stop_rows[0]) + 1 if stop_rows.size else n_all  # the replay ends at a released STOP

    def payload(i: int) -> bytes:
        o = int(scan.offset[i])
        return bytes(scan.data[o : o + int(scan.length[i])])

    def addr(i: int):
        return (ipv4_text(scan.src_ip[i]), int(scan.src_port[i]))

    per_type = options.config.input.per_type_sequence
    type_part = dec.stype & 0xFF if per_type else 0
    key_all = (scan.src_ip.astype(np.int64) << 24) | (scan.src_port << 8) | type_part

    # 1. exact prefix
    prefix = _Prefix(track, options)
    h = 0
    limit = min(n, MAX_EXACT_PREFIX)
    while h < limit:
        gps = _gps_of(dec, h) if dec.ok[h] and dec.stype[h] == 3 else None
        prefix.feed(float(scan.time_s[h]), addr(h), payload(h), gps)
        h += 1
        if prefix.pipe.stopped:
            break
        if (h & 63) == 0 and prefix.ready():
            break
    pipe = prefix.pipe
    if pipe.stopped or h >= n:
        why = "the capture ended during the exact prefix"
        return None, _info(False, why, h)
    if not prefix.ready():
        why = f"no hand-over point in the first {limit} datagrams (hypotheses or holds)"
        return None, _info(False, why, h)

    # 2. the compiled part must be a continuation the pipeline would release at once, in order
    rows = np.arange(h, n)
    ok = dec.ok[rows]
    st = dec.stype[rows]
    if np.any(ok & (st == 8)):
        return None, _info(False, "GROUND TRUTH after the start (re-initialisation)", h)
    meas = ok & ((st == 1) | (st == 2) | (st == 3))
    for t, nd in EPOCH_DOUBLES.items():
        if np.any(ok & (st == t) & (dec.n_double[rows] != nd)):
            return None, _info(False, f"{_TYPE_NAME[t]} datagrams without epoch (need STROBE dating)", h)
    if np.any(ok & (st == 10) & (rows != n - 1)):  # pragma: no cover - n ends at the first STOP
        return None, _info(False, "STOP before the end", h)
    why = _check_sequences(key_all, dec, h, n, options)
    if why:
        return None, _info(False, why, h)

    # 3. pack and run
    from sfa import layout as L
    from tools.fast_pack import pack_rows

    filt = pipe.filter
    try:  # the state arrays of the single hypothesis (ready() checked there is one)
        hyp = filt._hyps[filt._reported]
        line = hyp.line
        x, P, aux, cnt, mem = hyp.x, hyp.P, hyp.aux, hyp.cnt, hyp.mem  # advanced in place
    except (AttributeError, IndexError):
        return None, _info(False, "the filter does not expose its hypothesis arrays", h)
    mrows = rows[meas]
    kind, t_s, vals = pack_rows(dec, mrows, track)
    nm = mrows.size

    why = _time_jump_reason(filt, aux, t_s)
    if why:
        return None, _info(False, why, h)

    from tools.fast_loop import interp_many, run_replay_loop

    cfg = filt.config.to_array()
    last = pipe.last_estimate
    last_epoch = -math.inf if last is None else float(last.epoch_s)
    last_s = math.nan if last is None else float(last.arc_length_m)
    out_f = np.zeros((nm, 5))
    out_i = np.zeros((nm, 4), dtype=np.int64)
    run_replay_loop(
        kind,
        t_s,
        vals,
        x,
        P,
        aux,
        cnt,
        mem,
        cfg,
        line.s_m,
        line.east_m,
        line.north_m,
        line.grade,
        line.curvature_inv_m,
        last_epoch,
        last_s,
        out_f,
        out_i,
    )

    # 4. refuse after the fact near junctions of this line (the exact filter would branch there)
    why = _junction_reason(filt, line, out_f[:, 1])
    if why:
        return None, _info(False, why, h)

    # 5. the result, as tools.replay builds it
    from tools.replay import ESTIMATE_COLUMNS, ReplayResult

    z = float(cfg[L.K_Z_INTERVAL])
    d = float(aux[L.A_DIR])
    send = out_i[:, 3] == 1
    s_out = out_f[send, 1]
    sig_out = out_f[send, 3]
    lat_out = (
        interp_many(line.s_m, line.lat_deg, s_out, np.ones(s_out.size, dtype=np.bool_))
        if line.lat_deg is not None
        else np.full(s_out.size, math.nan)
    )
    lon_out = (
        interp_many(line.s_m, line.lon_deg, s_out, np.ones(s_out.size, dtype=np.bool_))
        if line.lon_deg is not None
        else np.full(s_out.size, math.nan)
    )
    link = pipe.link
    start_seq = options.config.link.start_seq
    k_out = int(send.sum())
    seq_out = (start_seq + link.outputs + np.arange(k_out)) & 0xFFFF
    fast_cols = {
        "epoch": out_f[send, 0],
        "arc_length": s_out,
        "seq": seq_out.astype(np.int64),
        "retransmit": np.zeros(k_out, dtype=np.int64),
        "arrival": scan.time_s[mrows[send]],
        "speed": d * out_f[send, 2],
        "sigma": sig_out,
        "interval_low": s_out - z * sig_out,
        "interval_high": s_out + z * sig_out,
        "status": out_i[send, 1].astype(np.int64),
        "line_id": np.full(k_out, line.line_id, dtype=np.int64),
        "lat": lat_out,
        "lon": lon_out,
    }
    int_cols = ("seq", "retransmit", "status", "line_id")
    est = {}
    for i, name in enumerate(ESTIMATE_COLUMNS):
        dtype = np.int64 if name in int_cols else float
        head = np.array([r[i] for r in prefix.est_rows], dtype=dtype)
        est[name] = np.concatenate([head, fast_cols[name].astype(dtype)])

    kinds = np.array([_KIND_NAME[int(k)] for k in kind], dtype=object) if nm else np.array([], dtype=object)
    updates = {
        "t": np.concatenate([np.array([u[0] for u in prefix.upd], dtype=float), t_s]),
        "kind": np.concatenate([np.array([u[1] for u in prefix.upd], dtype=object), kinds]),
        "outcome": np.concatenate([np.array([u[2] for u in prefix.upd], dtype=np.int64), out_i[:, 0]]),
        "nis": np.concatenate([np.array([u[3] for u in prefix.upd], dtype=float), out_f[:, 4]]),
    }
    grows = rows[ok & (st == 3)]
    g_lat, g_lon, g_fq = [], [], []
    for i in grows:
        la, lo, q = _gps_of(dec, int(i))
        g_lat.append(la)
        g_lon.append(lo)
        g_fq.append(q)
    gps = {
        "t": np.concatenate([np.array([g[0] for g in prefix.gps_rows], dtype=float), scan.time_s[grows]]),
        "lat": np.concatenate([np.array([g[1] for g in prefix.gps_rows], dtype=float), np.array(g_lat)]),
        "lon": np.concatenate([np.array([g[2] for g in prefix.gps_rows], dtype=float), np.array(g_lon)]),
        "fix_quality": np.concatenate(
            [np.array([g[3] for g in prefix.gps_rows], dtype=np.int64), np.array(g_fq, dtype=np.int64)]
        ),
    }

    # 6. counters: the pipeline's own objects advanced as the exact replay would have advanced them
    c = pipe.counters
    c["received"] += rows.size
    bad = rows[~ok]
    for i in bad:
        try:
            decode_input(payload(int(i)))
        except DecodeError as exc:
            c["rejected"] += 1
            pipe.rejected[str(exc.reason)] += 1
        else:  # pragma: no cover - the compiled pass rejected what the codec accepts: a bug
            raise AssertionError(f"fast decoder rejected a valid datagram at index {int(i)}")
    types = Counter(int(t) for t in st[ok])
    for t, k in types.items():
        pipe.by_type[_TYPE_NAME.get(t, str(t))] += k
    for i in rows[ok & (st == 9)]:
        ts_strobe = float(dec.values[i, 0])
        pipe.clock.on_strobe(ts_strobe, float(scan.time_s[i]))
    c["strobes"] += types.get(9, 0)
    c["dated_by_epoch"] += nm
    c["processed"] += nm
    from sfa.layout import Outcome

    for (kd, oc), k in Counter(zip(kind.tolist(), out_i[:, 0].tolist(), strict=True)).items():
        c[f"outcome_{_KIND_NAME[kd]}_{Outcome(oc).name.lower()}"] += k
    stopped = bool(stop_rows.size)
    if stopped:
        c["stops"] += 1
    if k_out:
        j = int(np.flatnonzero(send)[-1])
        pipe.last_estimate = _estimate_row(
            filt, line, out_f[j], out_i[j], d, z, float(lat_out[-1]), float(lon_out[-1])
        )
    metrics = pipe.metrics()
    seqm = metrics["sequencing"]
    n_valid = int(ok.sum())
    for k in ("received", "released", "in_order"):
        seqm[k] += n_valid
    metrics["link"]["outputs"] += k_out
    metrics["fast_replay"] = {
        "exact_prefix_datagrams": h,
        "compiled_datagrams": int(rows.size),
        "retransmissions_simulated": "exact prefix only",
    }
    last_frame = int(scan.frame_index[n - 1]) if stopped else scan.frames
    skipped = Counter()
    for frame, code in scan.skipped_at:
        if frame <= last_frame:
            skipped[SKIP_REASONS[int(code)]] += 1
    result = ReplayResult(
        label=options.label,
        estimates=est,
        updates=updates,
        gps=gps,
        metrics=metrics,
        datagrams=n,
        skipped_sensor=0,
    )
    result.capture = {"frames": last_frame, "datagrams": n, "skipped": dict(skipped)}
    return result, _info(True, "", h, int(rows.size))


def _info(used: bool, reason: str, prefix: int, compiled: int = 0) -> FastReplayInfo:
    return FastReplayInfo(used, reason, prefix, compiled)


def _check_sequences(key_all, dec, h, n, options) -> str:
    """Every stream of the compiled part continues its prefix sequence with no gap or reordering."""
    ok_pre = dec.ok[:h]
    last_seq: dict[int, int] = {}
    pk = key_all[:h][ok_pre]
    ps = dec.seq[:h][ok_pre]
    for k, s in zip(pk.tolist(), ps.tolist(), strict=True):
        last_seq[k] = s
    if len(last_seq) > options.config.input.max_streams:
        return "more streams than the listener tracks"
    ok = dec.ok[h:n]
    keys = key_all[h:n][ok]
    seqs = dec.seq[h:n][ok]
    if keys.size == 0:
        return ""
    uniq, inv = np.unique(keys, return_inverse=True)
    for j, k in enumerate(uniq.tolist()):
        if k not in last_seq:
            return "a new sender stream after the start (start-up hold)"
        s = seqs[inv == j]
        first_ok = s[0] == (last_seq[k] + 1) & 0xFFFF
        if not first_ok or np.any((np.diff(s) & 0xFFFF) != 1):
            return "a stream with a gap, a duplicate or reordering (needs the sequence buffer)"
    return ""


def _time_jump_reason(filt, aux, t_s: np.ndarray) -> str:
    """The per-message filter rejects a measurement far ahead of its state unless the next confirms the
    gap (TrackFilter._is_time_jump); the compiled loop does not: any forward gap of half that size or
    more goes to the exact replay (the margin covers a state time behind the newest epoch)."""
    limit = getattr(filt.config, "max_time_jump_s", None)
    if limit is None or t_s.size == 0:
        return ""
    from sfa import layout as L

    newest = np.maximum.accumulate(np.concatenate([[float(aux[L.A_T_STATE])], t_s]))[:-1]
    gaps = t_s - newest
    if np.any(gaps > 0.5 * float(limit)):
        return f"a forward time jump of {float(np.max(gaps)):.1f} s (the filter's time-jump rule)"
    return ""


def _junction_reason(filt, line, s_m: np.ndarray) -> str:
    try:
        jmap = filt._junction_map()
    except AttributeError:
        return "the filter does not expose its junction map"
    entry = jmap.get(line.line_id)
    if entry is None or s_m.size == 0:
        return ""
    window = filt.config.junction_window_m
    lo = float(np.nanmin(s_m)) - window - 1.0
    hi = float(np.nanmax(s_m)) + window + 1.0
    near = [s for s in entry[0] if lo <= s <= hi]
    if near:
        return f"the run passes a junction of line {line.line_id} (s = {near[0]:.1f} m): branch hypotheses"
    return ""


def _estimate_row(filt, line, f, i, d, z, lat, lon):
    """The Estimate the listener holds as its last output (for the metrics snapshot)."""
    from sfa.filter import Estimate
    from sfa.layout import FilterStatus, reasons_from_bits

    s, sig = float(f[1]), float(f[3])
    return Estimate(
        epoch_s=float(f[0]),
        arc_length_m=s,
        speed_mps=float(d * f[2]),
        sigma_s_m=sig,
        interval_low_m=s - z * sig,
        interval_high_m=s + z * sig,
        status=FilterStatus(int(i[1])),
        reasons=reasons_from_bits(int(i[2])),
        line_id=line.line_id,
        lat_deg=lat,
        lon_deg=lon,
        confidence=filt.config.confidence,
        hypotheses=1,
        direction=int(d),
    )


__all__ = ["FastReplayInfo", "fast_replay", "try_fast_replay", "MAX_EXACT_PREFIX"]
