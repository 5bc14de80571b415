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
* Memory is bounded whatever arrives: at most ``max_pending`` held items (on overflow the lowest
  gap is declared lost and released early), ``probation`` probation items, ``max_backward`` loss
  records. A :class:`StreamTable` bounds the number of streams (least recently used evicted).
"""

from __future__ import annotations

import math
from collections import OrderedDict, deque
from collections.abc import Hashable
from dataclasses import dataclass, fields
from typing import Generic, TypeVar

from listener.errors import ConfigError, SequenceError
from listener.serial import SERIAL_HALF, SERIAL_MASK, SERIAL_MOD

__all__ = ["SeqBufferConfig", "SeqStats", "SequenceBuffer", "StreamTable", "StreamTableStats", "stream_key"]

T = TypeVar("T")
K = TypeVar("K", bound=Hashable)


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


@dataclass(frozen=True, slots=True)
class SeqStats:
    """Counters of one stream (or a sum of streams), a snapshot.

    Every received item ends in exactly one of: ``in_order``, ``reordered`` (both "accepted"),
    ``duplicates``, ``late``, ``probation_drops``, or is still ``probation_held``. Every accepted item
    is released exactly once: ``in_order + reordered == released + pending``.
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

    def __add__(self, other: SeqStats) -> SeqStats:
        return SeqStats(*(getattr(self, f.name) + getattr(other, f.name) for f in fields(SeqStats)))


class SequenceBuffer(Generic[T]):
    """Reorders one stream's items by their 16-bit sequence number. Pure: ``now`` is always an argument.

    ``now`` is clamped to be non-decreasing (a caller's clock stepping back never releases early).
    """

    __slots__ = (
        "_cfg", "_hold", "_ref", "_expected", "_start", "_max_ext", "_pending", "_arrivals",
        "_lost_set", "_lost_order", "_prob", "_prob_t", "_now",
        "_received", "_released", "_in_order", "_reordered", "_duplicates", "_lost", "_late",
        "_resyncs", "_overflow", "_prob_drops",
    )  # fmt: skip

    def __init__(self, config: SeqBufferConfig | None = None) -> None:
        self._cfg = config if config is not None else SeqBufferConfig()
        self._hold = float(self._cfg.hold_time_s)
        self._ref: int | None = None  # ext the next number is unwrapped against (expected, or the first seen)
        self._expected: int | None = None  # ext of the next number to release; None until the start is known
        self._start = 0  # ext of the first number released (or to be released) in this sequence
        self._max_ext = 0  # highest ext accepted in this sequence
        self._pending: dict[int, T] = {}  # ext -> item, ahead of a gap (or during the startup hold)
        self._arrivals: deque[tuple[float, int]] = deque()  # (deadline, ext) in arrival order; lazy deletion
        self._lost_set: set[int] = set()  # ext declared lost, the last max_backward of them
        self._lost_order: deque[int] = deque()  # same, increasing, for pruning
        self._prob: list[tuple[int, T]] = []  # restart candidates (seq16, item), consecutive
        self._prob_t = 0.0  # arrival of the newest probation item
        self._now = -math.inf
        self._received = self._released = self._in_order = self._reordered = 0
        self._duplicates = self._lost = self._late = self._resyncs = self._overflow = self._prob_drops = 0

    # ------------------------------------------------------------------------------------------ API

    @property
    def config(self) -> SeqBufferConfig:
        return self._cfg

    @property
    def stats(self) -> SeqStats:
        return SeqStats(
            self._received, self._released, self._in_order, self._reordered, self._duplicates, self._lost,
            self._late, self._resyncs, self._overflow, self._prob_drops, len(self._pending), len(self._prob),
        )  # fmt: skip

    @property
    def pending_count(self) -> int:
        """Items held now (behind a gap, during the startup hold, or in probation)."""
        return len(self._pending) + len(self._prob)

    @property
    def footprint(self) -> int:
        """Entries stored now (held items, timer records, loss records, probation items).

        Bounded whatever arrives: at most ``2 * max_pending + max_forward + max_backward + probation``.
        """
        return len(self._pending) + len(self._arrivals) + len(self._lost_order) + len(self._prob)

    @property
    def expected(self) -> int | None:
        """The next sequence number (16-bit) to be released, None while the stream start is unknown."""
        return None if self._expected is None else self._expected & SERIAL_MASK

    def push(self, seq: int, item: T, now: float) -> list[T]:
        """Accept one item; return the items released by it (and by the passage of time), in order."""
        if type(seq) is not int or not 0 <= seq <= SERIAL_MASK:
            raise SequenceError(f"seq must be an int in 0..65535, got {seq!r}")
        if now > self._now:
            self._now = now
        elif now != now:
            raise SequenceError("now must be a number of seconds, got NaN")
        else:
            now = self._now
        out: list[T] = []
        if self._arrivals or self._prob:
            self._expire(now, out)
        self._received += 1
        ref = self._ref
        if ref is None:
            self._first(seq, item, now, out)
            if self._arrivals:
                self._expire(now, out)  # hold_time_s == 0 releases at once
            return out
        d = ((seq - ref + SERIAL_HALF) & SERIAL_MASK) - SERIAL_HALF  # serial_diff(seq, ref), inlined
        ext = ref + d
        expected = self._expected
        if d == 0 and expected is not None:  # the next expected number: the common case
            if ext > self._max_ext:
                self._max_ext = ext
                self._in_order += 1
            else:
                self._reordered += 1
            out.append(item)
            self._released += 1
            self._expected = self._ref = ext + 1
            if self._pending:
                self._release_run(out)
            return out
        cfg = self._cfg
        if expected is None:  # startup hold: the start of the stream is not known yet
            if -cfg.max_backward <= d <= cfg.max_forward:
                if ext in self._pending:
                    self._duplicates += 1
                else:
                    self._hold_item(ext, item, now, out)
            else:
                self._probation(seq, item, now, out)
        elif 0 < d <= cfg.max_forward:
            if ext in self._pending:
                self._duplicates += 1
            else:
                self._hold_item(ext, item, now, out)
        elif -cfg.max_backward <= d < 0:
            if ext < self._start or ext in self._lost_set:
                self._lost_set.discard(ext)  # a second copy of a late item is a duplicate
                self._late += 1
            else:
                self._duplicates += 1
        else:
            self._probation(seq, item, now, out)
        if self._arrivals:
            self._expire(now, out)  # hold_time_s == 0 releases at once
        return out

    def poll(self, now: float) -> list[T]:
        """Release what the passage of time makes due (gaps older than hold_time_s are declared lost)."""
        now = self._advance(now)
        out: list[T] = []
        self._expire(now, out)
        return out

    def next_deadline(self) -> float | None:
        """The earliest ``now`` at which :meth:`poll` has something to do, or None (nothing held)."""
        arrivals = self._arrivals
        pending = self._pending
        while arrivals and arrivals[0][1] not in pending:
            arrivals.popleft()
        deadline = arrivals[0][0] if arrivals else None
        if self._prob:
            prob_deadline = self._prob_t + self._cfg.probation_timeout_s
            deadline = prob_deadline if deadline is None else min(deadline, prob_deadline)
        return deadline

    def flush(self) -> list[T]:
        """Release everything held, in order (gaps declared lost); drop (and count) probation items.

        For a clean stop (STOP, shutdown) and for stream eviction.
        """
        out: list[T] = []
        self._release_all(out)
        self._prob_drops += len(self._prob)
        self._prob.clear()
        return out

    # ------------------------------------------------------------------------------------------ internals

    def _advance(self, now: float) -> float:
        if now != now:  # NaN
            raise SequenceError("now must be a number of seconds, got NaN")
        if now > self._now:
            self._now = now
        return self._now

    def _first(self, seq: int, item: T, now: float, out: list[T]) -> None:
        ext = SERIAL_MOD + seq  # any base works; one cycle up keeps "behind the first" non-negative
        self._ref = ext
        self._start = ext
        self._max_ext = ext - 1
        if self._cfg.startup_hold:
            self._hold_item(ext, item, now, out)
        else:
            self._expected = ext + 1
            self._ref = ext + 1
            self._max_ext = ext
            self._in_order += 1
            self._released += 1
            out.append(item)

    def _accept_count(self, ext: int) -> None:
        if ext > self._max_ext:
            self._max_ext = ext
            self._in_order += 1
        else:
            self._reordered += 1

    def _hold_item(self, ext: int, item: T, now: float, out: list[T]) -> None:
        self._accept_count(ext)
        self._pending[ext] = item
        self._arrivals.append((now + self._hold, ext))
        if self._expected is None and ext < self._start:
            self._start = ext
        while len(self._pending) > self._cfg.max_pending:
            self._overflow += 1
            self._release_through(min(self._pending), out)

    def _release_run(self, out: list[T]) -> None:
        """Release the pending items contiguous with the expected number."""
        pending = self._pending
        e = self._expected
        n = 0
        while e in pending:
            out.append(pending.pop(e))
            e += 1
            n += 1
        self._released += n
        self._expected = self._ref = e

    def _release_through(self, last: int, out: list[T]) -> None:
        """Release every pending item up to ``last`` (declaring the gaps lost), then the contiguous run."""
        pending = self._pending
        if self._expected is None:  # end of the startup hold: the lowest number seen is the start
            self._expected = self._ref = self._start = min(pending)
        e = self._expected
        for k in sorted(k for k in pending if k <= last):
            if k > e:
                self._declare_lost(e, k)
            out.append(pending.pop(k))
            self._released += 1
            e = k + 1
        self._expected = self._ref = e
        self._release_run(out)

    def _release_all(self, out: list[T]) -> None:
        if self._pending:
            self._release_through(max(self._pending), out)
        self._arrivals.clear()

    def _declare_lost(self, first: int, end: int) -> None:
        """Numbers ``first .. end - 1`` are lost; keep the last max_backward of them (late vs duplicate)."""
        self._lost += end - first
        keep = self._cfg.max_backward
        lost_set, lost_order = self._lost_set, self._lost_order
        for e in range(max(first, end - keep), end):
            lost_set.add(e)
            lost_order.append(e)
        floor = end - keep
        while lost_order and lost_order[0] < floor:
            lost_set.discard(lost_order.popleft())

    def _expire(self, now: float, out: list[T]) -> None:
        arrivals = self._arrivals
        pending = self._pending
        while arrivals:
            deadline, ext = arrivals[0]
            if ext not in pending:
                arrivals.popleft()  # released already (lazy deletion)
            elif deadline <= now:
                arrivals.popleft()
                self._release_through(ext, out)
            else:
                break
        if self._prob and now >= self._prob_t + self._cfg.probation_timeout_s:
            self._prob_drops += len(self._prob)
            self._prob.clear()

    def _probation(self, seq: int, item: T, now: float, out: list[T]) -> None:
        prob = self._prob
        if prob and seq == (prob[-1][0] + 1) & SERIAL_MASK:
            prob.append((seq, item))
        elif prob and any(s == seq for s, _ in prob):
            self._duplicates += 1
            return
        else:
            self._prob_drops += len(prob)
            prob.clear()
            prob.append((seq, item))
        self._prob_t = now
        if len(prob) >= self._cfg.probation:
            self._resync(out)

    def _resync(self, out: list[T]) -> None:
        """Accept the probation run as the new sequence: flush the old one, then release the run."""
        self._release_all(out)
        prob = self._prob
        top = max(self._max_ext, self._ref if self._ref is not None else 0)
        base = ((top >> 16) + 2) << 16  # a fresh cycle: the old numbers can never be mistaken for new ones
        first = base + prob[0][0]
        for _, item in prob:
            out.append(item)
        n = len(prob)
        prob.clear()
        self._released += n
        self._in_order += n
        self._start = first
        self._expected = self._ref = first + n
        self._max_ext = first + n - 1
        self._lost_set.clear()
        self._lost_order.clear()
        self._resyncs += 1


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
        self._streams: OrderedDict[K, SequenceBuffer[T]] = OrderedDict()
        self._active: set[K] = set()  # keys whose buffer holds something (has a deadline)
        self._evictions = 0
        self._evicted_totals = SeqStats()

    def __len__(self) -> int:
        return len(self._streams)

    def __contains__(self, key: object) -> bool:
        return key in self._streams

    def get(self, key: K) -> SequenceBuffer[T] | None:
        """The buffer of ``key`` (no LRU update), or None."""
        return self._streams.get(key)

    def push(self, key: K, seq: int, item: T, now: float) -> list[T]:
        """Push into ``key``'s buffer (created on first use); return released items.

        The list holds, first, the flushed items of a stream evicted to make room (if any), then the
        items of ``key``; each stream's items are in sequence order.
        """
        streams = self._streams
        buf = streams.get(key)
        out: list[T] = []
        if buf is None:
            if len(streams) >= self._max_streams:
                old_key, old = streams.popitem(last=False)
                self._active.discard(old_key)
                out.extend(old.flush())
                self._evicted_totals = self._evicted_totals + old.stats
                self._evictions += 1
            buf = streams[key] = SequenceBuffer(self._cfg)
        else:
            streams.move_to_end(key)
        released = buf.push(seq, item, now)
        if out:
            out.extend(released)
        else:
            out = released
        if buf.pending_count:
            self._active.add(key)
        else:
            self._active.discard(key)
        return out

    def poll(self, now: float) -> list[T]:
        """Release what is due in every stream (each stream's items in order, streams in no set order)."""
        out: list[T] = []
        for key in list(self._active):
            buf = self._streams[key]
            deadline = buf.next_deadline()
            if deadline is not None and deadline <= now:
                out.extend(buf.poll(now))
            if not buf.pending_count:
                self._active.discard(key)
        return out

    def next_deadline(self) -> float | None:
        """The earliest deadline over all streams, or None."""
        best: float | None = None
        for key in self._active:
            deadline = self._streams[key].next_deadline()
            if deadline is not None and (best is None or deadline < best):
                best = deadline
        return best

    def flush(self) -> list[T]:
        """Release everything held in every stream (for STOP and shutdown)."""
        out: list[T] = []
        for key in list(self._active):
            out.extend(self._streams[key].flush())
        self._active.clear()
        return out

    @property
    def stats(self) -> StreamTableStats:
        totals = self._evicted_totals
        for buf in self._streams.values():
            totals = totals + buf.stats
        return StreamTableStats(len(self._streams), self._evictions, totals)
