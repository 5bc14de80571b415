"""Per-stream sequence buffer (sans-I/O): reorder within a hold time, drop duplicates, report losses.

One :class:`SequenceBuffer` per stream (a sender's socket, optionally per SENSOR_TYPE). Sequence
numbers are 16-bit and compared with RFC 1982 serial arithmetic; internally each number is unwrapped
to an unbounded integer (``ext``), so a stream crossing 65535 -> 0 is seamless. Time is always an
argument (``now``, seconds of any monotonic clock the caller uses); nothing here reads a clock.

Policy (docs/protocol.md, "Sequence buffers"):

* The next expected item goes out at once, with whatever pending items it makes contiguous.
* An item ahead of a gap waits. When the item that has waited longest has waited ``hold_time_s``,
  the gaps below it are declared lost and everything up to it is released in order.
* Duplicates (already released, or already pending) are dropped and counted. Late items (behind
  the release point by at most ``max_backward`` and declared lost, or older than the stream start)
  are dropped and counted.
* A number further than ``max_forward`` ahead or ``max_backward`` behind is a restart candidate: as
  RTP does (RFC 3550 A.1), a new sequence is accepted after ``probation`` consecutive numbers; the
  probation items are held, and released after the resynchronisation, so no valid data is lost.
* A forward jump is not trusted at once (issue 20: one forged datagram with SEQ + 100 must not turn
  the next hundred legitimate ones into "late"). When an item ahead of a gap has waited
  ``hold_time_s`` it is released (and the gap declared lost) only if

  - it is *confirmed*: ``probation - 1`` more items of the stream are held within ``trusted_gap``
    above it (the stream really continues from there: RTP's probation), or
  - nothing arrived in order (or late) since it came, and the silence before it explains the gap: at
    least 3/4 of (missing + 1) of the stream's periods (an average over consecutive in-order arrivals)
    passed since the last in-order or late arrival (a loss burst, an outage; a forgery right behind a
    real datagram would need 75 periods of silence for SEQ + 100), or
  - the gap is small (at most ``trusted_gap`` numbers missing), nothing was released in order since
    it arrived, and the stream's budget of such unconfirmed skips allows it (a token bucket:
    ``gap_budget`` skips, one more every ``gap_refill_s``). This releases a STOP or any last datagram
    after a small gap by the hold timer.

  Otherwise it becomes a *suspect* (``jump_held``), out of the release path: in-order items go on
  being released below it. A later item confirms it (it is then released at once; for a large jump
  only while the stream stayed silent below it, so two forgeries a second apart on a 1 Hz stream do
  not confirm each other), or after ``jump_timeout_s`` it is released if the stream stayed silent
  below it (a legitimate last datagram after a loss) and dropped (``jump_drops``) if the stream went
  on below it (the forged case). When the stream's in-order numbers reach it, the next datagram
  decides: its own number (the suspect was a forgery: dropped) or a higher one (the suspect was the
  real, reordered item: released first); nothing for ``jump_timeout_s``: released. ``flush`` releases
  the suspects the stream stayed silent below and drops the others. ``alerts`` (a list the owner
  passes) receives one record per jump held, dropped or rate-limited, for the pipeline's warnings.
* :meth:`SequenceBuffer.reopen` gives back the number of an item the caller rejected for its content
  after the release (a future epoch...): a later item with that number is accepted, not a duplicate.
* Memory is bounded whatever arrives: at most ``max_pending`` held items (on overflow the lowest
  gap is declared lost and released early), ``probation`` probation items, ``max_suspects`` suspects,
  ``max_backward`` loss records, ``max_reopened`` given-back numbers. A :class:`StreamTable` bounds
  the number of streams (least recently used evicted).

The policy is written once, as compiled kernels over per-stream state arrays
(:mod:`listener.seq_core`); the classes here keep the items (the kernels see an id per item) and
translate. The listener calls them per datagram and per timer; the replay runs a whole recorded
stream through :meth:`StreamTable.run_indexed` (one compiled loop, the same kernels).
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Sequence
from dataclasses import dataclass, fields
from typing import Generic, TypeVar

import numpy as np

from listener import seq_core as core
from listener.errors import ConfigError, SequenceError
from listener.serial import SERIAL_HALF, SERIAL_MASK

__all__ = ["SeqBufferConfig", "SeqStats", "SequenceBuffer", "StreamTable", "StreamTableStats", "stream_key"]

T = TypeVar("T")
K = TypeVar("K", bound=Hashable)
_ALERTS_MAX = 1000  #: an owner's alert list takes no more records than this


@dataclass(frozen=True)
class SeqBufferConfig:
    """Configuration of one stream's sequence buffer."""

    hold_time_s: float = 0.03  #: longest wait of an item behind a gap before the gap is declared lost [s]
    max_pending: int = 256  #: most items held at once [items]; overflow releases the lowest gap early
    max_forward: int = 3000  #: a jump ahead larger than this is a restart candidate [sequence numbers]
    max_backward: int = 100  #: further behind than this is a restart candidate, not late [sequence numbers]
    probation: int = 2  #: consecutive numbers that accept a restarted sequence (RFC 3550 MIN_SEQUENTIAL)
    probation_timeout_s: float = 5.0  #: a probation run with no follower for this long is dropped [s]
    startup_hold: bool = True  #: hold the first items of a stream hold_time_s to find its true start
    #: most numbers missing below an item that the hold timer skips without confirmation [sequence numbers]
    trusted_gap: int = 3
    gap_budget: int = 3  #: unconfirmed skips a stream may make in a burst [count]
    gap_refill_s: float = 10.0  #: one more unconfirmed skip allowed per this long [s]
    #: how long an unconfirmed jump (a suspect) waits for a confirming item; >= the slowest stream's
    #: period (GNSS and STROBE: 1 s), so the legitimate stream's next item can show it was forged [s]
    jump_timeout_s: float = 1.5
    max_suspects: int = 8  #: suspects held per stream at most (the oldest dropped beyond) [items]
    max_reopened: int = 64  #: numbers given back by reopen() kept per stream at most [count]

    def __post_init__(self) -> None:
        def need(ok: bool, what: str) -> None:
            if not ok:
                raise ConfigError(f"SeqBufferConfig: {what}")

        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "startup_hold":
                need(type(value) is bool, f"startup_hold must be a bool, got {value!r}")
            elif f.name.endswith("_s"):
                ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
                need(ok and value >= 0, f"{f.name} must be a finite number >= 0 [s], got {value!r}")
            else:
                need(type(value) is int, f"{f.name} must be an int, got {value!r}")
        need(self.max_pending >= 1, f"max_pending must be >= 1, got {self.max_pending}")
        need(1 <= self.max_forward < SERIAL_HALF, f"max_forward must be in 1..32767, got {self.max_forward}")
        need(0 <= self.max_backward < SERIAL_HALF, f"max_backward must be in 0..32767: {self.max_backward}")
        need(
            1 <= self.probation <= self.max_pending,
            f"probation must be in 1..max_pending ({self.max_pending}), got {self.probation}",
        )
        need(self.probation_timeout_s > 0, "probation_timeout_s must be > 0")
        need(0 <= self.trusted_gap < SERIAL_HALF, f"trusted_gap must be in 0..32767, got {self.trusted_gap}")
        need(self.gap_budget >= 0, f"gap_budget must be >= 0, got {self.gap_budget}")
        need(self.gap_refill_s > 0, "gap_refill_s must be > 0")
        need(self.jump_timeout_s > 0, "jump_timeout_s must be > 0")
        need(self.max_suspects >= 1, f"max_suspects must be >= 1, got {self.max_suspects}")
        need(self.max_reopened >= 0, f"max_reopened must be >= 0, got {self.max_reopened}")


@dataclass(frozen=True, slots=True)
class SeqStats:
    """Counters of one stream (or a sum of streams), a snapshot.

    Every received item ends in exactly one of: ``in_order``, ``reordered`` (both "accepted"),
    ``duplicates``, ``late``, ``probation_drops``, ``jump_drops``, or is still ``probation_held`` or
    ``jump_held``. Every accepted item is released exactly once: ``in_order + reordered == released +
    pending``. (A suspect is not counted accepted while it is held; released, it is.)
    """

    received: int = 0  #: push() calls
    released: int = 0  #: items handed back (push, poll, flush)
    in_order: int = 0  #: accepted, arrived after every lower number (possibly after a gap)
    reordered: int = 0  #: accepted, arrived after a higher number of the same sequence
    duplicates: int = 0  #: dropped: that number was already released, pending, or in probation
    lost: int = 0  #: sequence numbers skipped (declared lost) when releasing past a gap
    late: int = 0  #: dropped: arrived after its number was declared lost, or older than the stream start
    resyncs: int = 0  #: restarts accepted after probation
    overflow: int = 0  #: early releases forced by max_pending
    probation_drops: int = 0  #: probation items dropped (run broken, timed out, or stream flushed)
    pending: int = 0  #: items held now (gauge)
    probation_held: int = 0  #: probation items held now (gauge)
    jumps_held: int = 0  #: forward jumps not trusted at the hold timer (items that became suspects)
    jump_drops: int = 0  #: suspects dropped (the stream went on below them, or was flushed)
    gap_limited: int = 0  #: small gaps the budget did not let the hold timer skip (became suspects)
    reopened: int = 0  #: numbers given back (content rejections) and then accepted again
    jump_held: int = 0  #: suspects held now (gauge)

    def __add__(self, other: SeqStats) -> SeqStats:
        return SeqStats(*(getattr(self, f.name) + getattr(other, f.name) for f in fields(SeqStats)))


class _Core:
    """The kernels' state of a table of ``nslots`` streams and the items they hold (by id)."""

    __slots__ = ("cfg", "si", "sf", "k", "tb", "out", "drop", "al", "items", "next_id")

    def __init__(self, cfg: SeqBufferConfig, nslots: int) -> None:
        self.cfg = cfg
        self.si, self.sf, self.k, self.tb = core.new_state(cfg, nslots)
        cap = core.slot_capacity(cfg) * (nslots + 1)
        self.out = np.empty(cap, dtype=np.int64)
        self.drop = np.empty(cap, dtype=np.int64)
        self.al = np.empty((_ALERTS_MAX, core.A_W))
        self.items: dict[int, object] = {}
        self.next_id = 0

    def begin(self, alerts: list | None) -> None:
        """Before a call: how many alert records the owner's list takes (the kernels reset the counts)."""
        self.tb[core.T_ALERT_CAP] = 0 if alerts is None else max(0, _ALERTS_MAX - len(alerts))

    def add(self, item: object) -> int:
        iid = self.next_id
        self.next_id = iid + 1
        self.items[iid] = item
        return iid

    def finish(self, alerts: list | None, key_of) -> list:
        """The items released by the last call (in order); forget the dropped ones; the alerts."""
        n, nd, na = self.tb[core.T_NOUT : core.T_NALERT + 1].tolist()
        pop = self.items.pop
        if n == 1 and not nd and not na:  # the common case: one item out
            return [pop(int(self.out[0]))]
        out = [pop(i) for i in self.out[:n].tolist()] if n else []
        if nd:
            for i in self.drop[:nd].tolist():
                pop(i, None)
        if na and alerts is not None:
            alerts.extend(_alert_record(row, key_of) for row in self.al[:na].tolist())
        return out

    def counters(self, slot: int) -> list[int]:
        return self.si[slot, core.S_CNT : core.S_CNT + core.N_COUNTERS].tolist()


def _alert_record(row: list[float], key_of) -> dict:
    kind, at, kid, seq, expected, missing, why = row
    rec = {"event": core.ALERT_KINDS[int(kind)], "at": at, "stream": key_of(int(kid)), "seq": int(seq),
           "expected": None if expected < 0 else int(expected)}  # fmt: skip
    if why >= 0:
        rec["why"] = core.ALERT_WHYS[int(why)]
    else:
        rec["missing"] = int(missing)
    return rec


def _check_seq(seq: object) -> None:
    if type(seq) is not int or not 0 <= seq <= SERIAL_MASK:
        raise SequenceError(f"seq must be an int in 0..65535, got {seq!r}")


class SequenceBuffer(Generic[T]):
    """Reorders one stream's items by their 16-bit sequence number. Pure: ``now`` is always an argument.

    ``now`` is clamped to be non-decreasing (a caller's clock stepping back never releases early).
    A buffer made here has its own state; :meth:`StreamTable.get` gives a view of a table's stream
    (valid while the stream is in the table).
    """

    __slots__ = ("_core", "_slot", "_gen", "alerts", "key")

    def __init__(self, config: SeqBufferConfig | None = None) -> None:
        c = _Core(config if config is not None else SeqBufferConfig(), 1)
        core.init_slot(c.si, c.sf, c.k, c.tb, 0)
        self._core = c
        self._slot = 0
        self._gen = int(c.si[0, core.S_GEN])
        self.alerts: list[dict] | None = None  #: the owner's list for jump/rate-limit records (or None)
        self.key: Hashable = None  #: the stream's key (for the alerts)

    @classmethod
    def _view(cls, c: _Core, slot: int, key: Hashable, alerts: list[dict]) -> SequenceBuffer:
        buf = cls.__new__(cls)
        buf._core = c
        buf._slot = slot
        buf._gen = int(c.si[slot, core.S_GEN])
        buf.alerts = alerts
        buf.key = key
        return buf

    def _live(self) -> _Core:
        c = self._core
        if c.si[self._slot, core.S_GEN] != self._gen or not c.si[self._slot, core.S_USED]:
            raise SequenceError("this stream was evicted from its table")
        return c

    # ------------------------------------------------------------------------------------------ API

    @property
    def config(self) -> SeqBufferConfig:
        return self._core.cfg

    @property
    def stats(self) -> SeqStats:
        return SeqStats(*self._live().counters(self._slot))

    @property
    def pending_count(self) -> int:
        """Items held now (behind a gap, during the startup hold, in probation, or suspects)."""
        row = self._live().si[self._slot]
        return int(row[core.C_PENDING] + row[core.C_PROB_HELD] + row[core.C_JUMP_HELD])

    @property
    def footprint(self) -> int:
        """Entries stored now (held items, their timer entries, loss records, probation items, suspects,
        given-back numbers).

        Bounded whatever arrives: at most ``2 * max_pending + max_forward + max_backward + probation +
        max_suspects + max_reopened``.
        """
        c = self._live()
        return int(core.footprint(c.si, c.k, self._slot))

    @property
    def expected(self) -> int | None:
        """The next sequence number (16-bit) to be released, None while the stream start is unknown."""
        row = self._live().si[self._slot]
        return int(row[core.S_EXP]) & SERIAL_MASK if row[core.S_HAS_EXP] else None

    def _key_of(self, kid: int) -> Hashable:
        return self.key

    def push(self, seq: int, item: T, now: float) -> list[T]:
        """Accept one item; return the items released by it (and by the passage of time), in order."""
        _check_seq(seq)
        c = self._live()
        if now != now:
            raise SequenceError("now must be a number of seconds, got NaN")
        c.begin(self.alerts)
        core.push(c.si, c.sf, c.k, c.tb, c.out, c.drop, c.al, self._slot, seq, c.add(item), float(now))
        return c.finish(self.alerts, self._key_of)

    def poll(self, now: float) -> list[T]:
        """Release what the passage of time makes due (gaps older than hold_time_s are declared lost)."""
        if now != now:
            raise SequenceError("now must be a number of seconds, got NaN")
        c = self._live()
        c.begin(self.alerts)
        core.poll(c.si, c.sf, c.k, c.tb, c.out, c.drop, c.al, self._slot, float(now))
        return c.finish(self.alerts, self._key_of)

    def next_deadline(self) -> float | None:
        """The earliest ``now`` at which :meth:`poll` has something to do, or None (nothing held)."""
        c = self._live()
        d = core.next_deadline(c.si, c.sf, c.k, self._slot)
        return None if d != d else d

    def reopen(self, seq: int) -> bool:
        """Give back the number of a released item the caller rejected for its content (a future epoch,
        a value the pipeline refuses): a later item with ``seq`` is then accepted instead of being a
        duplicate, so a forged datagram cannot use up a legitimate one's number. True if given back."""
        c = self._live()
        row = c.si[self._slot]
        if not row[core.S_HAS_REF] or not row[core.S_HAS_EXP] or c.cfg.max_reopened == 0:
            return False
        _check_seq(seq)
        return bool(core.reopen(c.si, c.k, self._slot, seq))

    def flush(self) -> list[T]:
        """Release everything held, in order (gaps declared lost); drop (and count) probation items.

        For a clean stop (STOP, shutdown) and for stream eviction.
        """
        c = self._live()
        c.begin(None)
        core.flush(c.si, c.sf, c.k, c.tb, c.out, c.drop, self._slot)
        return c.finish(None, self._key_of)


def stream_key(address: Hashable, sensor_type: int, per_type: bool = False) -> Hashable:
    """The key of a datagram's stream: its sender address, or (address, SENSOR_TYPE) when ``per_type``."""
    return (address, int(sensor_type)) if per_type else address


@dataclass(frozen=True, slots=True)
class StreamTableStats:
    """Counters of a :class:`StreamTable`: live streams, evictions, and the sum over all streams ever seen."""

    streams: int
    evictions: int
    totals: SeqStats


class StreamTable(Generic[K, T]):
    """Sequence buffers by stream key, at most ``max_streams`` of them (least recently used evicted).

    A flood of spoofed source ports cannot exhaust memory: a new key beyond ``max_streams`` evicts the
    stream that has gone longest without a datagram; its held items are flushed (released, with its
    gaps counted as lost) and its counters are kept in the totals.
    """

    def __init__(self, config: SeqBufferConfig | None = None, max_streams: int = 256) -> None:
        if type(max_streams) is not int or max_streams < 1:
            raise ConfigError(f"StreamTable: max_streams must be an int >= 1, got {max_streams!r}")
        self._cfg = config if config is not None else SeqBufferConfig()
        self._max_streams = max_streams
        self._core = _Core(self._cfg, max_streams)
        self._slot_of: dict[K, int] = {}
        self._keys: list = [None] * max_streams  # slot -> key
        #: jump / rate-limit records of every stream (SequenceBuffer.alerts); the owner empties it
        self.alerts: list[dict] = []
        self._taken: np.ndarray | None = None  # counters of items taken without push (count_in_order)

    def __len__(self) -> int:
        return len(self._slot_of)

    def __contains__(self, key: object) -> bool:
        return key in self._slot_of

    def get(self, key: K) -> SequenceBuffer[T] | None:
        """The buffer of ``key`` (no LRU update), or None."""
        slot = self._slot_of.get(key)
        return None if slot is None else SequenceBuffer._view(self._core, slot, key, self.alerts)

    def push(self, key: K, seq: int, item: T, now: float) -> list[T]:
        """Push into ``key``'s buffer (created on first use); return released items.

        The list holds, first, the flushed items of a stream evicted to make room (if any), then the
        items of ``key``; each stream's items are in sequence order.
        """
        _check_seq(seq)
        if now != now:
            raise SequenceError("now must be a number of seconds, got NaN")
        c = self._core
        slot = self._slot_of.get(key, -1)
        alerts = self.alerts
        c.tb[core.T_ALERT_CAP] = max(0, _ALERTS_MAX - len(alerts))  # (c.begin, inlined: per datagram)
        iid = c.next_id
        c.next_id = iid + 1
        c.items[iid] = item
        s = core.table_push(c.si, c.sf, c.k, c.tb, c.out, c.drop, c.al, slot, -1, seq, iid, float(now))
        if slot < 0:
            if c.tb[core.T_EVICTED_KID] >= 0:
                del self._slot_of[self._keys[s]]
            self._slot_of[key] = s
            self._keys[s] = key
        return c.finish(self.alerts, self._keys.__getitem__)

    def run(self, keys, seqs, items, times, stop_item=None):
        """Take a recorded stream as the listener does live: before each datagram (key ``keys[i]``,
        number ``seqs[i]``, item ``items[i]``, arrival ``times[i]``), :meth:`poll` at every deadline due by
        its arrival (the listener's timer fires at :meth:`next_deadline`), then :meth:`push` it. Stops
        after pushing ``stop_item`` (a STOP: the caller flushes then).

        Returns (released items, the time each was released at, the release each came out of, numbered
        from 0 in order, and for ``stop_item``: None if it was not pushed, else whether its own push
        released it). One compiled loop (:func:`listener.seq_core.run`)."""
        items = list(items)
        number: dict = {}
        kids = np.fromiter((number.setdefault(k, len(number)) for k in keys), np.int64, count=len(items))
        stop = -1
        if stop_item is not None:
            stop = next((i for i, x in enumerate(items) if x == stop_item), -1)
        for s in seqs:
            _check_seq(s)
        seqs_a = np.asarray(seqs, dtype=np.int64)
        times_a = np.asarray(times, dtype=np.float64)
        ids, rel_t, rel_b, stop_released, base = self._run(list(number), kids, seqs_a, times_a, stop)
        c = self._core
        pop = c.items.pop
        for i in self._held_ids(base):
            c.items[i] = items[i - base]
        rel = [items[i - base] if i >= base else pop(i) for i in ids.tolist()]
        return rel, rel_t.tolist(), rel_b.tolist(), None if stop_released < 0 else bool(stop_released)

    def run_indexed(
        self,
        keys: Sequence,
        kids: np.ndarray,
        seqs: np.ndarray,
        times: np.ndarray,
        values: np.ndarray,
        stop: int = -1,
    ):
        """:meth:`run` over arrays, for a table that holds nothing: datagram ``i`` of stream
        ``keys[kids[i]]`` with 16-bit number ``seqs[i]``, arrival ``times[i]`` and item ``values[i]`` (an
        int); stops after datagram ``stop`` (-1: none). Returns (released items, their release times,
        their release numbers: arrays; for ``stop``: None if not pushed, else whether its push released
        it). Items still held afterwards are kept as ints, as :meth:`push` keeps items."""
        c = self._core
        if int(c.tb[core.T_NACTIVE]):
            raise SequenceError("run_indexed needs a table that holds nothing")
        seqs = np.ascontiguousarray(seqs, dtype=np.int64)
        if seqs.size and (int(seqs.min()) < 0 or int(seqs.max()) > SERIAL_MASK):
            raise SequenceError("seq must be an int in 0..65535")
        values = np.ascontiguousarray(values, dtype=np.int64)
        ids, rel_t, rel_b, stop_released, base = self._run(
            list(keys), np.ascontiguousarray(kids, dtype=np.int64), seqs,
            np.ascontiguousarray(times, dtype=np.float64), stop)  # fmt: skip
        for i in self._held_ids(base):
            c.items[i] = int(values[i - base])
        return values[ids - base], rel_t, rel_b, None if stop_released < 0 else bool(stop_released)

    def _run(self, keys: list, kids: np.ndarray, seqs: np.ndarray, times: np.ndarray, stop: int):
        c = self._core
        n = int(kids.size)
        if seqs.size != n or times.size != n:
            raise ValueError("run: keys, seqs, items and times differ in length")
        keys = list(keys)
        si = c.si
        used = np.flatnonzero(si[:, core.S_USED]).tolist()
        number = {k: i for i, k in enumerate(keys)}
        for slot in used:  # the streams already in the table, by their number in this run
            key = self._keys[slot]
            if key not in number:
                number[key] = len(keys)
                keys.append(key)
            si[slot, core.S_KID] = number[key]
        kid_slot = np.full(len(keys), -1, dtype=np.int64)
        for slot in used:
            kid_slot[si[slot, core.S_KID]] = slot
        held = int(si[:, [core.C_PENDING, core.C_PROB_HELD, core.C_JUMP_HELD]].sum())
        cap = n + held + 1
        out = np.empty(cap, dtype=np.int64)
        out_t = np.empty(cap)
        out_b = np.empty(cap, dtype=np.int64)
        drop = np.empty(cap, dtype=np.int64)
        base = c.next_id
        c.next_id += n
        ids = np.arange(base, base + n, dtype=np.int64)
        c.begin(self.alerts)  # (the compiled loop adds to the counts: it starts them from 0)
        pushed, stop_released, _ = core.run(
            si, c.sf, c.k, c.tb, out, out_t, out_b, drop, c.al, kid_slot, kids, seqs, ids, times, stop
        )
        nout = int(c.tb[core.T_NOUT])
        for i in drop[: int(c.tb[core.T_NDROP])].tolist():
            if i < base:
                c.items.pop(i, None)
        na = int(c.tb[core.T_NALERT])
        if na:
            self.alerts.extend(_alert_record(row, keys.__getitem__) for row in c.al[:na].tolist())
        # the table's keys by slot again (streams were created and evicted on the way)
        self._slot_of = {}
        for slot in np.flatnonzero(si[:, core.S_USED]).tolist():
            key = keys[si[slot, core.S_KID]]
            self._keys[slot] = key
            self._slot_of[key] = slot
            si[slot, core.S_KID] = slot
        if pushed == -2:
            raise SequenceError("now must be a number of seconds, got NaN")
        return out[:nout], out_t[:nout], out_b[:nout], int(stop_released), base

    def _held_ids(self, base: int) -> list[int]:
        """Ids of the items held now from ``base`` on."""
        c = self._core
        si, k = c.si, c.k
        got: list[int] = []
        for slot in np.flatnonzero(si[:, core.S_USED]).tolist():
            row = si[slot]
            p = int(k[core.K_OFF_P])
            got += row[p + core.P_ID : p + core.P_W * int(row[core.C_PENDING]) : core.P_W].tolist()
            p = int(k[core.K_OFF_PROB])
            got += row[p + 1 : p + 2 * int(row[core.C_PROB_HELD]) : 2].tolist()
            p = int(k[core.K_OFF_U])
            got += row[p + core.U_ID : p + core.U_W * int(row[core.C_JUMP_HELD]) : core.U_W].tolist()
        return [i for i in got if i >= base]

    def poll(self, now: float) -> list[T]:
        """Release what is due in every stream (each stream's items in order, streams in no set order)."""
        c = self._core
        c.begin(self.alerts)
        core.table_poll(c.si, c.sf, c.k, c.tb, c.out, c.drop, c.al, float(now))
        return c.finish(self.alerts, self._keys.__getitem__)

    def next_deadline(self) -> float | None:
        """The earliest deadline over all streams, or None."""
        c = self._core
        if not c.tb[core.T_NACTIVE]:
            return None
        d = core.table_next_deadline(c.si, c.sf, c.k, c.tb)
        return None if d != d else d

    def flush(self) -> list[T]:
        """Release everything held in every stream (for STOP and shutdown)."""
        c = self._core
        c.begin(None)
        core.table_flush(c.si, c.sf, c.k, c.tb, c.out, c.drop)
        return c.finish(None, self._keys.__getitem__)

    def count_in_order(self, n: int) -> None:
        """Count ``n`` items that each continued their stream in order and were released at once, taken
        without :meth:`push` (a replay that checked so, ``tools.fast_replay``): in the totals as
        :meth:`push` counts such an item (received, in order, released). The streams' state (expected
        numbers, per-stream counters) does not move."""
        if n:
            if self._taken is None:
                self._taken = np.zeros(core.N_COUNTERS, dtype=np.int64)
            for k in (core.C_RECEIVED, core.C_IN_ORDER, core.C_RELEASED):
                self._taken[k - core.S_CNT] += n

    @property
    def stats(self) -> StreamTableStats:
        c = self._core
        used = np.flatnonzero(c.si[:, core.S_USED])
        totals = c.tb[core.T_EVICTED : core.T_EVICTED + core.N_COUNTERS].copy()
        if used.size:
            totals += c.si[used, core.S_CNT : core.S_CNT + core.N_COUNTERS].sum(axis=0)
        if self._taken is not None:
            totals += self._taken
        return StreamTableStats(len(self._slot_of), int(c.tb[core.T_EVICTIONS]), SeqStats(*totals.tolist()))
