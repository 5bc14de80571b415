"""Fast replay: the exact replay's estimates at compiled speed, on captures that allow it.

``tools.replay.replay_capture`` drives the listener's pipeline object per datagram (a few thousand
datagrams per second). On a clean capture almost all of that work is bookkeeping whose outcome is
known in advance: every stream in order, every measurement dated by its own epoch or by the STROBE
clock at its arrival, the merge releasing each measurement at once (``merge.hold_s = 0``).
:func:`fast_replay` checks that this is so and then runs the capture in compiled code:

1. one compiled pass over the memory-mapped pcap (:mod:`tools.fast_ingest`; classic pcap, Ethernet,
   IPv4, UDP at fixed offsets) walks the records, decodes every INPUT payload against listener.codec's
   own tables (:mod:`tools.fast_decode`), notes the stream table and the datagrams that would need the
   sequence buffer or STROBE dating, and packs the measurements straight into ``sfa.batch`` arrays;
   rejected datagrams get their reason from ``listener.codec`` itself,
2. the start of the capture goes through the exact pipeline, datagram by datagram, only until every
   sender's stream has started and nothing is held (a handful of datagrams),
3. the rest is checked (each stream continues in sequence: the ingest pass's notes; where one does
   not, the listener's own sequence buffers, the prefix pipeline's ``StreamTable``, take every
   datagram as ``Pipeline.receive`` and its timer would, :func:`_sequence`, and their releases go on
   in the merge's order), and one compiled pass advances the listener's own STROBE clock and dates
   the measurements against it (:func:`tools.fast_clock.replay_clock` over
   :meth:`listener.clock.StrobeClock.sensor_times`: the sensor-set "now" of every arrival, which dates a
   measurement without its epoch, and the listener's ``epoch_future`` and stale-output rules; a
   start with measurements before the first STROBE goes through the exact pipeline up to that
   STROBE, which empties the listener's undated queue),
4. GNSS fixes go to the track's frame; rejected measurements are dropped from the packed rows,
5. the filter runs from the exact pipeline's filter object through its public calls: ``TrackFilter.run``
   (its own compiled loop, ``sfa.bank.run_segment``, with the listener's output rule; junction branches
   spawned by the filter itself) and ``TrackFilter.process`` for the measurements the loop stops before
   (a GROUND TRUTH, or one the time-jump rule looks at), ``TrackFilter.emit`` applying the output rule
   after them,
6. the result columns (estimates as sent, per-measurement outcomes and NIS) are written by the filter
   loop itself, straight into the arrays the result hands out (no intermediate per-measurement rows:
   about 50 MB less memory to fault in on a 90 min capture); lat/lon on the line and the counters
   follow in one pass each.

When any condition fails it returns None (and :func:`try_fast_replay` says why): the caller runs the
exact replay instead. What the result does not simulate: retransmissions of the OBCU link after the
exact prefix (the fast path returns new estimates only; retransmissions never change a new
estimate), and link state transitions. Everything else (estimates, per-measurement outcomes and NIS,
GNSS fixes, input/sequencing/clock/filter counters) equals the exact replay's, which
tests/test_fast_replay.py checks field by field, on a capture with junctions too.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import sys
import time
from collections import Counter, deque
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from listener.pipeline import BatchCounts, to_measurement
from sfa.bank import NOST, O_BITS, O_LAST, O_LINE_HI, O_LINE_LO, O_ROW, O_STALE, RunOutput
from sfa.layout import FilterStatus, Outcome

#: datagrams replayed through the exact pipeline at most before the hand-over to compiled code
MAX_EXACT_PREFIX = 200_000
_KIND_NAME = {1: "imu", 2: "odo", 3: "gps", 8: "init"}
_KIND_OBJ = np.array([_KIND_NAME.get(k, "?") for k in range(16)], dtype=object)  # Update.kind by code
_KIND_CODE = {name: code for code, name in _KIND_NAME.items()}


@dataclass(frozen=True)
class FastReplayInfo:
    """How a fast replay went."""

    used: bool  #: True: the result came from the fast path
    reason: str  #: why the exact replay is needed ("" when used)
    exact_prefix: int = 0  #: datagrams that went through the exact pipeline first
    compiled: int = 0  #: datagrams handled in compiled code after the prefix (filter step included)
    python_steps: int = 0  #: measurements after the prefix stepped by TrackFilter.process (junctions)
    timing: dict = field(default_factory=dict)  #: seconds per stage of this run (wall clock)


def fast_replay(capture_path, track, options=None):
    """Replay ``capture_path`` like :func:`tools.replay.replay_capture`, in compiled code.

    Returns a :class:`tools.replay.ReplayResult` (new estimates only after the exact prefix) or None
    when the capture or the options need the exact replay.
    """
    result, _ = try_fast_replay(capture_path, track, options)
    return result


def try_fast_replay(capture_path, track, options=None, filter_inputs: dict | None = None):
    """(ReplayResult or None, FastReplayInfo saying which path and why).

    ``filter_inputs``: a dict that receives the packed measurements the filter is handed after the
    exact prefix (``kind``, ``t``, ``vals``: ``sfa.batch.Packed``'s arrays, dated, sequenced and
    merged), for a benchmark that runs the filter core alone on them."""
    from tools.replay import ReplayOptions

    options = options or ReplayOptions()
    why = _options_reason(options)
    if why:
        return None, FastReplayInfo(False, why)
    from tools.fast_decode import FIELD_HI, FIELD_LO, FORM_SIZE
    from tools.fast_ingest import R_DATAGRAMS, ingest_capture

    t0 = time.perf_counter()
    inp = options.config.input
    got = ingest_capture(
        capture_path,
        options.port,
        inp.per_type_sequence,
        inp.max_streams,
        (FORM_SIZE, FIELD_LO, FIELD_HI),
    )
    ingest_s = time.perf_counter() - t0
    if isinstance(got, str):
        return None, FastReplayInfo(False, f"capture: {got}")
    if got.res[R_DATAGRAMS] == 0:
        return None, FastReplayInfo(False, "no datagram to the listener port")
    result, info = _replay_ingested(got, track, options, ingest_s, filter_inputs)
    if result is not None:
        why = vital_reason(got, result, options, result.metrics["fast_replay"].pop("reason_bits"))
        why = why or resilience_reason(result, track, options)
        if why:
            return None, _info(False, why, info.exact_prefix)
    return result, info


def resilience_reason(result, track, options) -> str:
    """Why the listener's resilience stage (listener.resilience: GROUND TRUTH guard, output guard, clock
    trouble) could have changed what was sent, in which case the exact replay is needed; "" when not.

    The compiled path models none of it, so it is used only when: no STROBE was rejected (the clock
    trouble status), no re-initialisation happened after the first (the GROUND TRUTH guard may hold
    a GROUND TRUTH against a NOMINAL filter), and the output guard passes every new output."""
    cfg = options.config
    if result.metrics["clock"].get("rejected_strobes", 0):
        return "resilience: STROBEs rejected (clock_untrusted status, exact replay)"
    if not cfg.plausibility.enabled:
        return ""
    if result.metrics["filter"]["counters"].get("initialisations", 0) > 1:
        return "resilience: a re-initialisation (the GROUND TRUTH guard runs in the exact replay)"
    from listener.plausibility import OutputGuard, line_limits

    guard = OutputGuard(line_limits(track, cfg.plausibility.max_speed_mps), cfg.plausibility)
    est = result.new_estimates()  # the outputs sent, in order: vetted as the listener vets each
    if guard.first_refused(est["line_id"], est["epoch"], est["arc_length"], est["sigma"]) >= 0:
        return "resilience: an output the plausibility guard would not send"
    return ""


_SLACK_S = 0.01  #: vital_reason errs this much towards the exact replay (the timer's margin is 1 ms) [s]


def vital_reason(got, result, options, bits=None) -> str:
    """Why the listener's vital supervision (listener.vital, run by the exact pipeline on its timer)
    could have changed what was sent, in which case the exact replay is needed; "" when it could not.

    The compiled path has no timer and no decay state, so it is used only when none of these happened:
    a LOST output; a run of non-NOMINAL outputs as long as the fault budget; a DEGRADED output under
    the extended output or ``vital.standard_output = "nominal"`` (the timer would announce or withhold
    it); with those, any sensor silent beyond its time-out; otherwise IMU and odometer both silent
    beyond their time-outs at the same time between two datagrams (LOST on the timer, which latches
    decay), or a sensor whose time-out is a decay reason silent for the fault budget. A silence at the
    very end (after the last datagram of a module, to the end of the capture) changes nothing sent."""
    cfg = options.config
    v = cfg.vital
    if not v.enabled:
        return ""
    status = result.estimates["status"]
    if status.size == 0:
        return ""
    if np.any(status == 3):
        return "vital supervision: a LOST estimate (the decay state runs in the exact replay)"
    degraded = status == 2
    strict = v.standard_output == "nominal" or cfg.link.extended
    if np.any(degraded) and strict:
        return "vital supervision: DEGRADED estimates with the extended output or standard_output = nominal"
    from listener.config import decay_reasons
    from sfa.layout import REASON_NAMES

    if np.any(degraded):
        # a run of outputs carrying a decay reason (bits -1: not recorded, any) as long as the budget;
        # the time-out of a module never heard is not one (listener.pipeline: not fitted, not failed)
        names = set(decay_reasons(v))
        heard = {1: "imu_timeout", 2: "odometer_timeout", 3: "gnss_timeout"}
        for kind, name in heard.items():
            if not np.any(got.kind == kind):
                names.discard(name)
        mask = sum(bit for bit, name in REASON_NAMES.items() if name in names)
        flagged = degraded if bits is None else degraded & ((bits < 0) | ((bits & mask) != 0))
        epoch = result.estimates["epoch"]
        edges = np.flatnonzero(np.diff(np.concatenate(([0], flagged.astype(np.int8), [0]))))
        for a, b in zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True):
            if epoch[min(b, epoch.size - 1)] - epoch[a] >= v.fault_budget_s - _SLACK_S:
                return "vital supervision: a decay reason as long as vital.fault_budget_s (decay may latch)"

    fc = cfg.filter.filter_config(**dict(options.filter_overrides))
    rate = cfg.clock.rate
    timeouts = {1: fc.imu_timeout_s / rate, 2: fc.odo_timeout_s / rate, 3: fc.gps_timeout_s / rate}
    reason_of = {1: "imu_timeout", 2: "odometer_timeout", 3: "gnss_timeout"}
    decay = set(decay_reasons(v))
    silent: dict[int, np.ndarray] = {}  # per SENSOR_TYPE: (gap start + time-out, next arrival) rows
    for kind in (1, 2, 3):
        t = got.m_time[got.kind == kind]
        if t.size < 2:
            silent[kind] = np.zeros((0, 2))
            continue
        gaps = np.diff(t)
        over = np.flatnonzero(gaps > timeouts[kind])
        silent[kind] = np.stack((t[over] + timeouts[kind], t[over + 1]), axis=1)
        if over.size and strict:
            return f"vital supervision: a sensor (type {kind}) silent longer than its time-out"
        longest = float(gaps[over].max()) if over.size else 0.0
        if reason_of[kind] in decay and longest >= timeouts[kind] + v.fault_budget_s - _SLACK_S:
            return f"vital supervision: a sensor (type {kind}) silent for the fault budget"
    a, b = silent[1], silent[2]
    if a.size and b.size:
        lo = np.maximum(a[:, None, 0], b[None, :, 0]) if a.shape[0] * b.shape[0] <= 4_000_000 else None
        if lo is None:
            return "vital supervision: too many IMU and odometer gaps to check"
        hi = np.minimum(a[:, None, 1], b[None, :, 1])
        if np.any(lo < hi + _SLACK_S):
            return "vital supervision: IMU and odometer silent together beyond their time-outs (LOST)"
    return ""


def _options_reason(options) -> str:
    from tools.replay import SENSOR_TYPES

    cfg = options.config
    if sys.byteorder != "little":
        return "big-endian host"
    if set(options.sensors) != set(SENSOR_TYPES):
        return "sensor selection (some sensors disabled)"
    if options.record_measurements:
        return "measurements recorded (baselines)"
    if cfg.auth.enabled:
        return "authenticated links (the compiled ingest reads plain INPUT datagrams)"
    if cfg.merge.hold_s != 0.0:
        return f"merge.hold_s = {cfg.merge.hold_s} (the fast path needs 0)"
    if cfg.clock.rate != 1.0:
        return f"clock.rate = {cfg.clock.rate} (the fast path is checked at the nominal rate 1 only)"
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
        self.reason_rows: list[int] = []  # reason bits of each output row (tools.replay's reasons)
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
        from tools.estimates_schema import reason_bits
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
            self.reason_rows.append(reason_bits(est.reasons))

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
        """Hand-over point: nothing held in the sequence buffers, the merge or the undated queue (the
        filter may be in any state: the fast path runs TrackFilter itself where it must; the sequence
        buffers go on as they are, in the listener's own objects, where the rest needs them)."""
        pipe = self.pipe
        if pipe.stopped or pipe.streams.next_deadline() is not None:
            return False
        held = pipe.streams.stats.totals
        m = pipe.metrics()
        return (
            held.pending == 0
            and held.probation_held == 0
            and held.jump_held == 0
            and m["merge"]["pending"] == 0
            and m["clock"]["undated_pending"] == 0
        )


#: sequence-buffer events the compiled path does not follow: a number given back (``reopen``, after a
#: content rejection); every other decision (reordering, duplicates, losses, late items, restarts and
#: probation, forward jumps held as suspects, overflow) is the buffers' own, taken in _sequence
_SEQ_NOT_FOLLOWED = ("reopened",)


@dataclass(frozen=True)
class _Sequenced:
    """What the listener's sequence buffers released after the prefix, in release order."""

    m_idx: np.ndarray  #: measurement indices (into the ingest's arrays) in release order
    m_pos: np.ndarray  #: their positions in the release order (interleaving with the STROBEs)
    m_now: np.ndarray  #: their release times (arrival, or the end of a hold)
    m_batch: np.ndarray  #: the release (push, timer poll or flush) each came out of
    s_idx: np.ndarray  #: STROBE indices in release order
    s_pos: np.ndarray
    s_batch: np.ndarray

    def merge_reason(self, t_s: np.ndarray, n_future: int) -> str:
        """Why the merge could see the release otherwise than :meth:`merge_order` orders it (a STROBE
        released after measurements of the same release: they are drained on the clock it leaves), or a
        content rejection give a SEQ back (``reopen``); "" when it cannot."""
        if n_future:
            return "epoch_future rejections with sequence repair (the SEQ is given back: exact replay)"
        if not np.all(np.isfinite(t_s)):
            return "a measurement not dated after the hand-over"
        if self.s_batch.size and self.m_batch.size:
            # a STROBE released with measurements before it changes the clock their release is judged on
            ub, first = np.unique(self.m_batch, return_index=True)  # (m_pos ascends: first = smallest)
            at = np.minimum(np.searchsorted(ub, self.s_batch), ub.size - 1)
            shared = ub[at] == self.s_batch
            if np.any(shared & (self.m_pos[first[at]] < self.s_pos)):
                return "a STROBE released after measurements in one release (the stale rule's clock)"
        return ""

    def merge_order(self, t_s: np.ndarray) -> np.ndarray:
        """The filter's order of the released measurements: ``Pipeline._dispatch`` dates a release's
        measurements and ``_drain`` hands them over by (epoch, push order) from the merge's heap, which
        every drain empties (``merge.hold_s = 0``: the horizon is at least the newest epoch); so within
        each release by epoch, ties in release order, releases in turn."""
        return np.lexsort((self.m_pos, t_s, self.m_batch))


def _sequence(got, pipe, h: int, n: int, stopped: bool, per_type: bool):
    """The rest of the capture through the prefix pipeline's own sequence buffers (``pipe.streams``,
    listener.seqbuf.StreamTable), exactly as ``Pipeline.receive`` pushes each valid datagram and its
    timer polls them at their deadlines (the replay fires timers at their own times before the next
    datagram), with the STOP's flush and the flush at the end: a :class:`_Sequenced`, or why the
    exact replay is needed."""
    from listener.seqbuf import stream_key

    streams = pipe.streams
    before = streams.stats
    rows = np.flatnonzero(got.row_code[h:n] >= 0) + h
    inv, sources = got.source_ids(rows)
    number: dict = {}  # stream key -> its number (sources may share a stream)
    kid_of = [number.setdefault(stream_key(addr, stype, per_type), len(number)) for addr, stype in sources]
    kids = np.asarray(kid_of, dtype=np.int64)[inv] if rows.size else np.zeros(0, dtype=np.int64)
    d = got.data
    o = got.row_off[rows]
    seqs = d[o + 1].astype(np.int64) | (d[o + 2].astype(np.int64) << 8)
    times = got.row_t[rows]
    stop = rows.size - 1 if stopped and rows.size and rows[-1] == n - 1 else -1
    if streams.next_deadline() is not None:
        return "the sequence buffers hold datagrams at the hand-over (exact replay)"
    rel_a, rel_t, rel_b, stop_released = streams.run_indexed(list(number), kids, seqs, times, rows, stop)
    batch = int(rel_b[-1]) + 1 if rel_b.size else 0
    if stop_released is False:
        return "a STOP held by a sequence buffer (exact replay)"
    last_t = float(got.row_t[n - 1])  # the STOP's arrival (the last row), or the end's
    out = np.asarray(streams.flush(), dtype=np.int64)  # the STOP's, or the end's (Pipeline.flush)
    rel_a = np.concatenate([rel_a, out])
    rel_t = np.concatenate([rel_t, np.full(out.size, last_t)])
    rel_b = np.concatenate([rel_b, np.full(out.size, batch, dtype=np.int64)])
    after = streams.stats
    if after.evictions != before.evictions:
        return "a sequence-buffer stream evicted (more senders than input.max_streams)"
    for name in _SEQ_NOT_FOLLOWED:
        if getattr(after.totals, name) != getattr(before.totals, name):
            return f"sequence buffers: {name.replace('_', ' ')} (exact replay)"
    pos = np.arange(rel_a.size)
    meas_of = np.full(n, -1, dtype=np.int64)
    meas_of[got.m_row] = np.arange(got.m_row.size)
    strobe_of = np.full(n, -1, dtype=np.int64)
    strobe_of[got.s_row] = np.arange(got.s_row.size)
    m = meas_of[rel_a]
    s = strobe_of[rel_a]
    ism, iss = m >= 0, s >= 0
    return _Sequenced(m[ism], pos[ism], rel_t[ism], rel_b[ism], s[iss], pos[iss], rel_b[iss])


def _senders_reason(got, pipe, h: int) -> str:
    """The sender table (listener.senders) over the rest of the capture: each (source, SENSOR_TYPE)
    pair after the exact prefix goes through the prefix pipeline's own table once, at its first
    datagram, as the exact replay would (a TOFU binding is made there). "" when every pair is
    accepted (then every datagram is: the table's decision depends on the pair only); else why the
    exact replay is needed (it rejects, counts and warns per datagram)."""
    from listener.senders import source_of

    table = pipe.senders
    for row, addr, stype in got.first_sources(h):
        t = float(got.datagram(row)[0])
        if table.check(source_of(addr), stype, t) is not None or table.would_reject:
            return (
                f"sender table: {addr[0]}:{addr[1]} may not send SENSOR_TYPE {stype} "
                "(more than one source per type, or one the table does not allow: the exact replay "
                "rejects and counts them)"
            )
    table.events.clear()
    return ""


# ---------------------------------------------------------------------------------------- result rows
@njit(cache=True, _nrt=False)
def _tally(kind, outcome, pairs):
    """pairs[kind * 16 + outcome] += 1 per measurement (the pipeline's outcome counters)."""
    for i in range(kind.shape[0]):
        pairs[kind[i] * 16 + outcome[i]] += 1


class _Columns:
    """The replay's result columns, allocated once for the prefix's rows and the nm measurements after
    it: the update columns (time, outcome, NIS; ``u_out``/``u_nis`` are the views from the prefix's rows
    on, which the filter writes) and the estimate columns (``e_f`` (7, he + nm): epoch, arc length,
    arrival, speed, sigma, interval low and high; ``e_i`` (4, he + nm): SEQ, status, line id, reason
    bits), of which
    the first ``he`` rows are the prefix's and the rest are written per estimate sent. np.empty: the
    rows never written are never touched."""

    def __init__(self, prefix, nm: int) -> None:
        self.he = he = len(prefix.est_rows)
        hu = len(prefix.upd)
        self.u_t = np.empty(hu + nm)
        self.u_out_all = np.empty(hu + nm, dtype=np.int64)
        self.u_nis_all = np.empty(hu + nm)
        for c_i, arr in ((0, self.u_t), (2, self.u_out_all), (3, self.u_nis_all)):
            arr[:hu] = np.array([u[c_i] for u in prefix.upd], dtype=arr.dtype)
        self.u_out = self.u_out_all[hu:]
        self.u_nis = self.u_nis_all[hu:]
        self.e_f = np.empty((7, he + nm))
        self.e_i = np.empty((4, he + nm), dtype=np.int64)  # row 3: reason bits (vital_reason)
        self.e_i[3, :he] = -1  # the prefix's rows: not recorded, taken as any reason


@njit(cache=True, _nrt=False)
def _latlon(ts, lat, lon, s, line, lid, every, out_lat, out_lon):
    """lat/lon at arc length ``s`` on the line with vertices at ``ts`` (rows of ``line`` == lid, or every
    row): for s within [ts[0], ts[-1]] ``sfa.kernels.interp_at`` for both (the same segment as its binary
    search, found from the previous row's, and the same expression), NaN otherwise (as
    ``sfa.filter.TrackFilter``'s lat/lon)."""
    n = ts.shape[0]
    first = ts[0]
    end = ts[n - 1]
    i = 0
    for r in range(s.shape[0]):
        if not every and line[r] != lid:
            continue
        x = s[r]
        if not (first <= x <= end):
            out_lat[r] = np.nan
            out_lon[r] = np.nan
            continue
        if x <= first:
            out_lat[r] = lat[0]
            out_lon[r] = lon[0]
            continue
        if x >= end:
            out_lat[r] = lat[n - 1]
            out_lon[r] = lon[n - 1]
            continue
        # the segment i with ts[i] <= x < ts[i + 1] (searchsorted(ts, x, "right") - 1 for ts[0] < x < ts[-1])
        if not (ts[i] <= x < ts[i + 1]):
            if i + 2 <= n - 1 and ts[i + 1] <= x < ts[i + 2]:
                i += 1
            else:
                i = np.searchsorted(ts, x, side="right") - 1
                if i < 0:
                    i = 0
                if i > n - 2:
                    i = n - 2
        ds = ts[i + 1] - ts[i]
        if ds <= 0.0:
            out_lat[r] = lat[i]
            out_lon[r] = lon[i]
        else:
            out_lat[r] = lat[i] + (lat[i + 1] - lat[i]) * (x - ts[i]) / ds
            out_lon[r] = lon[i] + (lon[i + 1] - lon[i]) * (x - ts[i]) / ds


# ---------------------------------------------------------------------------------------- main path
def _replay_ingested(got, track, options, ingest_s: float = 0.0, filter_inputs: dict | None = None):
    from listener.codec import DecodeError, decode_input
    from tools.fast_clock import replay_clock
    from tools.fast_ingest import (
        R_BAD,
        R_FRAMES,
        R_LAST_BREAK,
        R_LAST_FIRST,
        R_STOP_FRAME,
        R_STOPPED,
        R_STREAMS,
        R_TYPES,
    )
    from tools.fast_pcap import SKIP_REASONS

    timing = {"ingest": ingest_s}
    tick = time.perf_counter()

    def lap(name: str) -> None:
        nonlocal tick
        now = time.perf_counter()
        timing[name] = timing.get(name, 0.0) + now - tick
        tick = now

    res = got.res
    n = got.rows  # the replay ends at a released STOP
    row_code = got.row_code
    if res[R_STREAMS] < 0:
        return None, _info(False, "more streams than the listener tracks", 0)
    # the exact pipeline runs until every stream has started (start-up hold released)
    min_prefix = int(res[R_LAST_FIRST]) + 1
    # a measurement without its epoch before the first STROBE waits in the listener's undated queue
    # (Pipeline._date, clock.max_pending_undated) until that STROBE dates it: such a start goes through
    # the exact pipeline up to and including the first STROBE (after it the clock always has one)
    undated = np.isnan(got.t_s)
    first_undated = int(got.m_row[int(np.argmax(undated))]) if undated.any() else n
    first_strobe = int(got.s_row[0]) if got.s_row.size else n
    if first_undated < first_strobe:
        min_prefix = max(min_prefix, first_strobe + 1)

    # 1. exact prefix
    prefix = _Prefix(track, options)
    h = 0
    gp = 0  # next GNSS row
    limit = min(n, MAX_EXACT_PREFIX)
    while h < limit:
        gps = None
        if row_code[h] == 3:
            gps = (float(got.g_lat[gp]), float(got.g_lon[gp]), int(got.g_fq[gp]))
            gp += 1
        t, addr, payload = got.datagram(h)
        prefix.feed(t, addr, payload, gps)
        h += 1
        if prefix.pipe.stopped:
            break
        if h >= min_prefix and prefix.ready():
            break
    pipe = prefix.pipe
    lap("exact prefix")
    if pipe.stopped or h >= n:
        why = "the capture ended during the exact prefix"
        return None, _info(False, why, h)
    if not prefix.ready():
        why = f"no hand-over point in the first {limit} datagrams (sequence or merge holds)"
        return None, _info(False, why, h)

    # 2. the rest must be a continuation the pipeline releases at once, in order (the ingest pass noted
    # the last datagram breaking each rule)
    j0 = int(np.searchsorted(got.m_row, h))
    s0 = int(np.searchsorted(got.s_row, h))
    if not pipe.clock.synced and undated[j0:].any():
        # the clock has no STROBE yet (the prefix's were rejected by the sender table, or come later):
        # a measurement without epoch before the next STROBE would wait in the undated queue
        nxt_strobe = int(got.s_row[s0]) if s0 < got.s_row.size else n
        if int(got.m_row[j0 + int(np.argmax(undated[j0:]))]) < nxt_strobe:
            why = "measurements without epoch before any STROBE dates them (the undated queue)"
            return None, _info(False, why, h)
    why = _senders_reason(got, pipe, h)
    if why:
        return None, _info(False, why, h)
    g0 = int(np.searchsorted(got.g_row, h))
    seq = None
    if res[R_LAST_BREAK] >= h:  # a gap, duplicate or reordering: the listener's own sequence buffers
        seq = _sequence(got, pipe, h, n, bool(res[R_STOPPED]), options.config.input.per_type_sequence)
        if isinstance(seq, str):
            return None, _info(False, seq, h)
        undated_rel = np.isnan(got.t_s[seq.m_idx])
        n_by_strobe = int(np.count_nonzero(undated_rel))
        mrows, m_time, kind, t_s = (a[seq.m_idx] for a in (got.m_row, got.m_time, got.kind, got.t_s))
        vals = None  # (taken once, in the filter's order, after the GNSS projection below)
        m_pos, m_now = seq.m_pos, seq.m_now
        s_pos, s_ts, s_time = seq.s_pos, got.s_ts[seq.s_idx], got.s_time[seq.s_idx]
        n_strobes = int(seq.s_idx.size)
    else:
        n_by_strobe = int(np.count_nonzero(undated[j0:]))  # replay_clock dates them (never epoch_future)
        mrows, m_time, kind, t_s, vals = (
            a[j0:] for a in (got.m_row, got.m_time, got.kind, got.t_s, got.vals)
        )
        m_pos, m_now = mrows, m_time
        s_pos, s_ts, s_time = got.s_row[s0:], got.s_ts[s0:], got.s_time[s0:]
        n_strobes = int(s_pos.size)
    lap("checks")

    # 3. the STROBE clock: the sensor-set "now" at every measurement's arrival (epoch_future rejection,
    # the stale-output bound)
    cfg = options.config
    stale_before = cfg.link.max_output_age_s + cfg.merge.hold_s
    clock0 = copy.deepcopy(pipe.clock)  # the clock at the hand-over (for _end_gap)
    fresh_min, future, n_future = replay_clock(
        pipe.clock,
        (s_pos, s_ts, s_time),
        (m_pos, m_time, t_s),
        cfg.clock.max_future_s,
        stale_before,
        m_now,
    )
    if seq is not None:
        why = seq.merge_reason(t_s, n_future)
        if why:
            return None, _info(False, why, h)
        order = seq.merge_order(t_s)
        if np.any(order != np.arange(order.size)):
            seq = dataclasses.replace(seq, m_idx=seq.m_idx[order])
            mrows, m_time, kind, t_s, fresh_min, m_now, future = (
                a[order] for a in (mrows, m_time, kind, t_s, fresh_min, m_now, future)
            )
    lap("clock")

    # GNSS fixes to the track's local frame (fix quality 0 stays (0, 0): the filter counts it as no fix)
    gq = np.flatnonzero(got.g_fq[g0:] != 0.0) + g0
    if gq.size:
        e, nn = track.to_local(got.g_lat[gq], got.g_lon[gq])
        gm = got.g_meas[gq]
        got.vals[gm, 0] = np.asarray(e, dtype=np.float64)
        got.vals[gm, 1] = np.asarray(nn, dtype=np.float64)
    if seq is not None:  # the values in the filter's order, with the projected GNSS fixes
        vals = got.vals[seq.m_idx]
    if n_future:  # Pipeline._date: epoch_future rejection
        keep = ~future
        mrows, m_time, kind, t_s, vals, fresh_min, m_now = (
            a[keep] for a in (mrows, m_time, kind, t_s, vals, fresh_min, m_now)
        )
    nm = mrows.size
    lap("pack")

    # 4. the filter: compiled while its hypotheses share one line, TrackFilter.process otherwise. It
    # writes the result columns itself: the per-measurement updates, and a row per estimate sent
    from tools.replay import ESTIMATE_COLUMNS, ReplayResult

    cols = _Columns(prefix, nm)
    he = cols.he
    hu = len(prefix.upd)
    filt = pipe.filter
    last = pipe.last_estimate
    state = _FilterRun(
        filt,
        -math.inf if last is None else float(last.epoch_s),
        math.nan if last is None else float(last.arc_length_m),
        cols,
        m_now,  # an estimate is sent when its measurement is released (its arrival, or a hold's end)
        fresh_min,
        options.config.link.start_seq + pipe.link.outputs,
    )
    if filter_inputs is not None:
        filter_inputs.update(kind=kind, t=t_s, vals=vals)
    i = 0
    while i < nm:
        j = state.compiled(i, kind, t_s, vals)
        if j >= nm:
            break
        i = j
        msg = decode_input(got.datagram(int(mrows[i]))[2])
        upd = filt.process(to_measurement(msg, float(t_s[i])))  # its epoch, or as the clock dated it
        state.python_row(i, upd)
        i += 1
    lap("filter")

    # 5. the result, as tools.replay builds it: the prefix's rows, then the compiled rows
    ost = state.ost
    k_out = int(ost[O_ROW]) - he
    rows = he + k_out
    e_f, e_i = cols.e_f, cols.e_i
    est = {
        "epoch": e_f[0, :rows],
        "arc_length": e_f[1, :rows],
        "seq": e_i[0, :rows],
        "retransmit": np.zeros(rows, dtype=np.int64),  # the retransmissions are inserted below
        "arrival": e_f[2, :rows],
        "speed": e_f[3, :rows],
        "sigma": e_f[4, :rows],
        "interval_low": e_f[5, :rows],
        "interval_high": e_f[6, :rows],
        "status": e_i[1, :rows],
        "line_id": e_i[2, :rows],
        "lat": np.empty(rows),
        "lon": np.empty(rows),
    }
    assert tuple(est) == ESTIMATE_COLUMNS
    for c_i, name in enumerate(ESTIMATE_COLUMNS):
        est[name][:he] = np.array([r[c_i] for r in prefix.est_rows], dtype=est[name].dtype)
    updates = {"t": cols.u_t, "kind": None, "outcome": cols.u_out_all, "nis": cols.u_nis_all}
    cols.u_t[hu:] = t_s
    pairs = np.zeros(16 * 16, dtype=np.int64)
    _tally(kind, cols.u_out, pairs)
    codes = [_KIND_CODE.get(u[1], -1) for u in prefix.upd]
    if -1 in codes:  # pragma: no cover - TrackFilter's kinds are those of _KIND_NAME
        head = np.array([u[1] for u in prefix.upd], dtype=object)
        updates["kind"] = np.concatenate([head, _KIND_OBJ[kind]])
    else:  # one take over all codes: much cheaper than filling an object array piecewise
        all_codes = np.empty(hu + nm, dtype=np.intp)
        all_codes[:hu] = codes
        all_codes[hu:] = kind
        updates["kind"] = _KIND_OBJ.take(all_codes)
    if k_out:
        s_out = est["arc_length"][he:]
        lines_out = est["line_id"][he:]
        lo_line, hi_line = int(ost[O_LINE_LO]), int(ost[O_LINE_HI])
        lines = [lo_line] if lo_line == hi_line else np.unique(lines_out).tolist()
        arrays = {lid: filt.line_arrays(int(lid)) for lid in lines if lid >= 0}
        if len(lines) > 1 or not arrays or arrays[lines[0]].lat_deg is None:
            est["lat"][he:] = math.nan  # rows no line interpolates (one line: _latlon writes every row)
            est["lon"][he:] = math.nan
        for lid in lines:
            if lid < 0:
                continue
            ln = arrays[lid]
            if ln.lat_deg is not None:
                _latlon(
                    ln.s_m, ln.lat_deg, ln.lon_deg, s_out, lines_out, int(lid), len(lines) == 1,
                    est["lat"][he:], est["lon"][he:],
                )  # fmt: skip
    gsl = slice(g0, None)
    gps = {
        "t": np.concatenate([np.array([g[0] for g in prefix.gps_rows], dtype=float), got.g_time[gsl]]),
        "lat": np.concatenate([np.array([g[1] for g in prefix.gps_rows], dtype=float), got.g_lat[gsl]]),
        "lon": np.concatenate([np.array([g[2] for g in prefix.gps_rows], dtype=float), got.g_lon[gsl]]),
        "fix_quality": np.concatenate(
            [
                np.array([g[3] for g in prefix.gps_rows], dtype=np.int64),
                got.g_fq[gsl].astype(np.int64),
            ]
        ),
    }
    reasons = e_i[3, :rows].copy()
    reasons[:he] = prefix.reason_rows
    retx = _retransmissions(prefix.est_rows, est["arrival"][he:], float(got.row_t[n - 1]), cfg.link)
    retx, why = _end_gap(retx, k_out, got, pipe, clock0, (s_ts, s_time), cfg)
    if why:
        return None, _info(False, why, h)
    if retx.size:  # after row he + after[k]: a resend of that row's estimate at times[k]
        after, times = retx[:, 0].astype(np.int64) + he, retx[:, 1]
        at = after + 1
        est = {k: np.insert(v, at, v[after]) for k, v in est.items()}
        est["retransmit"][at + np.arange(at.size)] = 1
        est["arrival"][at + np.arange(at.size)] = times
        reasons = np.insert(reasons, at, reasons[after])
        bits = np.insert(e_i[3, :rows], at, e_i[3, after])
    else:
        bits = e_i[3, :rows]
    lap("result columns")

    # 6. counters: what happened after the hand-over, booked by the listener's pipeline itself
    # (Pipeline.count_batch: the counters and rules of Pipeline.receive and the stages after it)
    rejected: Counter = Counter()  # reject reason -> datagrams
    if res[R_BAD]:
        for r in (np.flatnonzero(row_code[h:] < 0) + h).tolist():
            try:
                decode_input(got.datagram(r)[2])
            except DecodeError as exc:
                rejected[exc.reason] += 1
            else:  # pragma: no cover - the compiled pass rejected what the codec accepts: a bug
                raise AssertionError(f"fast decoder rejected a valid datagram at index {r}")
    head = row_code[:h]
    types = res[R_TYPES : R_TYPES + 16] - np.bincount(head[head >= 0], minlength=16)  # by SENSOR_TYPE
    stopped = bool(res[R_STOPPED])
    pipe.count_batch(
        BatchCounts(
            received=n - h,
            rejected=rejected,
            by_type={t: int(types[t]) for t in np.flatnonzero(types).tolist()},
            # (else the listener's own sequence buffers took every datagram, _sequence)
            in_order=int(types.sum()) if seq is None else 0,
            strobes=n_strobes,
            stops=int(stopped),
            dated_by_epoch=nm - n_by_strobe,
            dated_by_strobe=n_by_strobe,
            epoch_future=n_future,
            outcomes={
                (_KIND_NAME[code // 16], Outcome(code % 16)): int(pairs[code])
                for code in np.flatnonzero(pairs).tolist()
            },
            stale_not_sent=int(ost[O_STALE]),
            outputs=k_out,
            retransmits=int(retx.shape[0]),
        )
    )
    if k_out:
        pipe.last_estimate = state.last_estimate(float(est["lat"][-1]), float(est["lon"][-1]))
    metrics = pipe.metrics()
    for k in ("state", "state_since", "transitions", "withheld"):  # the prefix's: not simulated after it
        metrics["link"].pop(k, None)
    compiled = (n - h) - state.python_steps
    metrics["fast_replay"] = {
        "exact_prefix_datagrams": h,
        "compiled_datagrams": compiled,
        "python_filter_steps": state.python_steps,
        "handed_back_at_junctions": state.branched,
        "compiled_fraction": compiled / n,
        "retransmissions_added": int(retx.shape[0]),
        # (the pipeline sections the compiled path does not advance: left out, not stale)
        "not_simulated": ["vital", "link.state", "link.state_since", "link.transitions", "link.withheld"],
        "reason_bits": bits,  # taken out again by try_fast_replay (vital_reason; the prefix's rows -1)
    }
    last_frame = int(res[R_STOP_FRAME]) if stopped else int(res[R_FRAMES])
    skipped = Counter()
    for frame, code in got.skipped_at.tolist():
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
        reasons=reasons,
    )
    result.capture = {  # the fast scan refuses a truncated file (the exact reader counts and warns)
        "frames": last_frame, "datagrams": n, "skipped": dict(skipped),
        "truncated_bytes": 0, "truncated_records": 0, "warnings": [],
    }  # fmt: skip
    lap("counters")
    return result, _info(True, "", h, compiled, state.python_steps, timing)


def _end_gap(retx: np.ndarray, k_out: int, got, pipe, clock0, strobes, cfg):
    """The resends of the last estimate sent, after the last measurement (the end of the capture), with
    the vital supervision on: (the resend rows kept, "") or (, why the exact replay is needed).
    ``strobes``: (timestamp, arrival) of the STROBEs after the hand-over, in the order the clock took
    them; ``clock0``: the clock at the hand-over.

    After the last measurement the listener's timer runs at each module's time-out
    (``Pipeline._supervision_deadline``: its last datagram + its time-out / clock.rate + the margin),
    and again every ``_RECHECK_STEP_S`` for up to ``_RECHECK_FOR_S`` while the filter does not show that
    time-out yet; it evaluates the filter's estimate propagated to the sensor time of ``now`` and
    withholds the standard output, the newest estimate's resends included, once that is LOST
    (``Pipeline._supervise``). Here the filter (its final state: no measurement comes later) is asked
    the same question at each time-out, on the STROBE clock as it stood then, and at the end of its
    re-check window where re-checks run (a status that only worsens as the propagation goes on, as the
    time-outs and the growing sigma make it): a resend before the first LOST is sent, one after the
    time-out that saw it is not (the same float expressions as the pipeline's timers: a resend due at
    that time-out comes after it); a resend after a re-check window that ends LOST (the re-checks may
    have stopped before) or the strict output modes are left to the exact replay."""
    from listener.pipeline import _RECHECK_FOR_S, _RECHECK_STEP_S, _TIMEOUT_REASON
    from tools.fast_clock import replay_strobes

    if not cfg.vital.enabled or retx.shape[0] == 0:
        return retx, ""
    end = retx[:, 0] == k_out - 1
    if not end.any():
        return retx, ""
    times = retx[end, 1]
    why = "vital supervision: the link's resends of the last estimate after a module's time-out"
    if cfg.vital.standard_output == "nominal" or cfg.link.extended:
        return retx, why
    fc = pipe.filter.config
    timeout = {1: fc.imu_timeout_s, 2: fc.odo_timeout_s, 3: fc.gps_timeout_s}
    reason = {1: _TIMEOUT_REASON["imu"], 2: _TIMEOUT_REASON["odometer"], 3: _TIMEOUT_REASON["gnss"]}
    last_meas = float(got.m_time.max())
    due = sorted(
        (float(got.m_time[got.kind == k].max()) + timeout[k] / cfg.clock.rate + cfg.vital.timeout_margin_s, k)
        for k in (1, 2, 3) if np.any(got.kind == k)
    )  # fmt: skip
    due = [(d, k) for d, k in due if d > last_meas]  # (earlier ones ran during the capture)

    def status_at(now: float):
        clock = copy.deepcopy(clock0)
        before = strobes[1] < now  # the STROBEs taken before now (in the order the clock took them)
        replay_strobes(clock, strobes[0][before], strobes[1][before])
        t = clock.to_sensor_time(now)
        return None if t is None else pipe.filter.estimate(at_s=t, propagate=True)

    sent_before = math.inf  # resends before this time are sent (no LOST seen by then)
    withheld_after = math.inf  # and from this time on withheld
    for d, k in due:
        if d > times[-1]:
            break
        est = status_at(d)
        if est is None:
            return retx, why
        if est.status == FilterStatus.LOST:
            withheld_after = d
            sent_before = min(sent_before, d)
            break
        if reason[k] not in est.reasons:  # re-checks follow: LOST may come at any of them
            window_end = d + _RECHECK_FOR_S + _RECHECK_STEP_S
            late = status_at(window_end)
            if late is None or late.status == FilterStatus.LOST:  # (re-checks may stop before it)
                sent_before = min(sent_before, d)
                break
    # (the times are the pipeline's own float expressions: a time-out due with a resend runs first)
    kept = times < sent_before
    if not np.all(kept | (times >= withheld_after)):
        return retx, why
    return retx[~end | (retx[:, 1] < sent_before)], ""


def _retransmissions(prefix_rows, created: np.ndarray, t_end: float, link) -> np.ndarray:
    """The OBCU link's retransmissions after the exact prefix, as listener.obcu_link sends them in the
    exact replay: (k, time) rows, a resend of the k-th new estimate after the prefix (-1: the prefix's
    newest) at that time.

    In a replay nothing is ever acked and (``link.max_rate_hz = 0``) every new estimate is sent when it
    is made (``created``: its arrival column). The newest sent estimate is resent by the link's timer at
    ``last_sent + retransmit_interval_s``, at most ``max_retransmits`` times and not once it is older than
    ``max_output_age_s``; the replay fires that timer when it is due at or before the next datagram, so
    before the next new estimate (made at its datagram's arrival), and the final flush at the last
    datagram (the STOP, or the end of the capture) runs the same check once more at that time."""
    interval = float(link.retransmit_interval_s)
    most = int(link.max_retransmits)
    age = float(link.max_output_age_s)
    out: list[tuple[float, float]] = []
    if most <= 0:
        return np.zeros((0, 2))
    if prefix_rows:  # the prefix's newest: its first send, its resends so far, the last send
        seq = prefix_rows[-1][2]
        k0 = len(prefix_rows) - 1
        while k0 > 0 and prefix_rows[k0][3] == 1 and prefix_rows[k0 - 1][2] == seq:
            k0 -= 1
        first = (-1, float(prefix_rows[k0][4]), len(prefix_rows) - 1 - k0, float(prefix_rows[-1][4]))
    else:
        first = None
    count = created.shape[0]
    # the gaps in which a resend can fall: the next estimate (or the end) at least an interval after
    gaps = np.flatnonzero(np.diff(np.append(created, t_end)) >= interval - 1e-9).tolist()
    starts = [first] if first is not None else []
    starts += [(k, float(created[k]), 0, float(created[k])) for k in gaps]
    for k, made, resends, last_sent in starts:
        until = float(created[k + 1]) if k + 1 < count else t_end
        while resends < most:
            due = last_sent + interval  # ObcuLink.next_timer; handle_timer(due) finds it due
            final = due > until  # not before the next datagram: only the final flush may still resend
            if final:
                if k + 1 < count or not t_end - last_sent >= interval - 1e-12:
                    break
                due = t_end
            if due - made > age:
                break
            out.append((k, due))
            resends += 1
            last_sent = due
            if final:
                break
    return np.array(out, dtype=np.float64).reshape(-1, 2)


def _info(used: bool, reason: str, prefix: int, compiled: int = 0, python: int = 0, timing=None):
    return FastReplayInfo(used, reason, prefix, compiled, python, dict(timing or {}))


class _FilterRun:
    """The filter over the packed measurements: ``TrackFilter.run`` (its compiled loop, the output rule
    included) and the rows ``TrackFilter.process`` handles, with the same output rule
    (``TrackFilter.emit``) after them."""

    def __init__(self, filt, last_epoch: float, last_s: float, cols, m_time, fresh_min, seq0: int) -> None:
        """``cols``: the result columns (u_out, u_nis per measurement; e_f (7, .), e_i (4, .) for
        the estimates sent, from row ``cols.he`` on, as ``sfa.bank.run_segment`` writes them)."""
        self.filt = filt
        self.cols = cols
        ost = np.zeros(NOST, dtype=np.int64)
        ost[O_ROW] = cols.he
        ost[O_LAST] = -1
        # (run_segment numbers the rows from the start of the columns)
        self.out = RunOutput(cols.u_out, cols.u_nis, cols.e_f, cols.e_i, fresh_min, m_time,
                             np.array([last_epoch, last_s]), ost, seq0 - cols.he)
        self.ost = ost
        self.python_steps = 0
        self.branched = 0  #: measurements after which TrackFilter spawned branches (junction windows)
        self.python_est: dict[int, object] = {}

    def compiled(self, i: int, kind, t_s, vals) -> int:
        """Run compiled from row i as far as it goes; returns the first row not processed."""
        j, branched = self.filt.run(kind, t_s, vals, i, self.out)
        self.branched += branched
        return j

    def python_row(self, i: int, upd) -> None:
        """Row i went through TrackFilter.process: record it and apply the output rule."""
        self.python_steps += 1
        self.cols.u_nis[i] = math.nan if upd.nis is None else float(upd.nis)
        self.cols.u_out[i] = int(upd.outcome)
        if self.filt.emit(i, self.out):
            self.python_est[i] = self.filt.estimate()

    def last_estimate(self, lat: float, lon: float):
        """The Estimate the listener holds after its last output (for the metrics snapshot), or None."""
        i = int(self.ost[O_LAST])
        if i < 0:
            return None
        est = self.python_est.get(i)
        if est is not None:
            return est
        k = int(self.ost[O_ROW]) - 1
        e_f, e_i = self.cols.e_f, self.cols.e_i
        return _estimate_row(
            self.filt, int(e_i[2, k]), e_f[:, k], int(e_i[1, k]), int(self.ost[O_BITS]), lat, lon
        )


def _estimate_row(filt, line_id: int, f, status: int, bits: int, lat, lon):
    """The Estimate the listener holds as its last output (for the metrics snapshot: status, reasons,
    line), from a compiled row (``f``: a column of run_segment's e_f)."""
    from sfa.filter import Estimate
    from sfa.layout import FilterStatus, reasons_from_bits

    return Estimate(
        epoch_s=float(f[0]),
        arc_length_m=float(f[1]),
        speed_mps=float(f[3]),
        sigma_s_m=float(f[4]),
        interval_low_m=float(f[5]),  # s -+ z sigma, as put_row wrote it
        interval_high_m=float(f[6]),
        status=FilterStatus(status),
        reasons=reasons_from_bits(bits),
        line_id=None if line_id < 0 else line_id,
        lat_deg=lat,
        lon_deg=lon,
        confidence=filt.config.confidence,
    )


__all__ = ["FastReplayInfo", "fast_replay", "try_fast_replay", "MAX_EXACT_PREFIX"]
