"""Test oracle: the sequence buffers as they were written in Python before the policy moved into
compiled kernels (listener/seq_core.py); not shipped. tests/test_seqbuf_oracle.py compares the
listener's classes with these on random schedules. The policy is the one listener/seqbuf.py's module
docstring states.
"""

from __future__ import annotations

import math
from collections import OrderedDict, deque
from collections.abc import Hashable
from typing import Generic, TypeVar

from listener.errors import ConfigError, SequenceError
from listener.seqbuf import SeqBufferConfig, SeqStats, StreamTableStats, stream_key
from listener.serial import SERIAL_HALF, SERIAL_MASK, SERIAL_MOD

__all__ = ["SeqBufferConfig", "SeqStats", "SequenceBuffer", "StreamTable", "StreamTableStats", "stream_key"]

T = TypeVar("T")
_PERIOD_MAX_S = 10.0  #: inter-arrivals longer than this do not enter a stream's period estimate [s]
_RATE_SLACK = 0.75  #: a jump is explained by the silence before it if that lasted this share of its periods
K = TypeVar("K", bound=Hashable)


class SequenceBuffer(Generic[T]):
    """Reorders one stream's items by their 16-bit sequence number. Pure: ``now`` is always an argument.

    ``now`` is clamped to be non-decreasing (a caller's clock stepping back never releases early).
    """

    __slots__ = (
        "_cfg", "_hold", "_ref", "_expected", "_start", "_max_ext", "_pending", "_arrivals",
        "_lost_set", "_lost_order", "_prob", "_prob_t", "_now",
        "_received", "_released", "_in_order", "_reordered", "_duplicates", "_lost", "_late",
        "_resyncs", "_overflow", "_prob_drops",
        "_suspects", "_tokens", "_tok_t", "_reopen", "_jumps_held", "_jump_drops", "_gap_limited",
        "_reopened", "_flow", "_last_ext", "_last_t", "_period", "alerts", "key",
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
        #: suspects: ext -> (item, deadline, _flow when it arrived, counted in order when accepted, reached
        #: by the stream from below)
        self._suspects: dict[int, tuple[T, float, int, bool, bool]] = {}
        self._tokens = float(self._cfg.gap_budget)
        self._tok_t = -math.inf
        self._reopen: deque[int] = deque()  # ext given back by reopen(), oldest first
        self._jumps_held = self._jump_drops = self._gap_limited = self._reopened = 0
        self._flow = 0  # arrivals of exactly the expected number (the stream going on in order)
        self._last_ext = -1  # number and arrival of the last such arrival, and the stream's period from
        self._last_t = -math.inf  # them (an exponential average over consecutive numbers) [s]
        self._period: float | None = None
        self.alerts: list[dict] | None = None  #: the owner's list for jump/rate-limit records (or None)
        self.key: Hashable = None  #: the stream's key (for the alerts)

    # ------------------------------------------------------------------------------------------ API

    @property
    def config(self) -> SeqBufferConfig:
        return self._cfg

    @property
    def stats(self) -> SeqStats:
        return SeqStats(
            self._received, self._released, self._in_order, self._reordered, self._duplicates, self._lost,
            self._late, self._resyncs, self._overflow, self._prob_drops, len(self._pending), len(self._prob),
            self._jumps_held, self._jump_drops, self._gap_limited, self._reopened, len(self._suspects),
        )  # fmt: skip

    @property
    def pending_count(self) -> int:
        """Items held now (behind a gap, during the startup hold, in probation, or suspects)."""
        return len(self._pending) + len(self._prob) + len(self._suspects)

    @property
    def footprint(self) -> int:
        """Entries stored now (held items, timer records, loss records, probation items, suspects,
        given-back numbers).

        Bounded whatever arrives: at most ``2 * max_pending + max_forward + max_backward + probation +
        max_suspects + max_reopened``.
        """
        return (
            len(self._pending) + len(self._arrivals) + len(self._lost_order) + len(self._prob)
            + len(self._suspects) + len(self._reopen)
        )  # fmt: skip

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
        if self._arrivals or self._prob or self._suspects:
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
        if self._suspects and expected is not None and expected in self._suspects:
            # the stream reached a suspect from below: the next datagram says which it was
            if ext == expected:  # its number's own datagram: the suspect was the forgery
                del self._suspects[ext]
                self._jump_drops += 1
                self._alert("sequence_jump_dropped", now, ext, why="its number came from the stream")
            elif ext > expected:  # the stream went past it: it was the real one (a reordered item)
                self._unsuspect(expected, out)
                expected = self._expected
                d = ext - self._ref
        if d == 0 and expected is not None:  # the next expected number: the common case
            self._flow += 1
            if ext == self._last_ext + 1:
                dt = now - self._last_t
                if dt < _PERIOD_MAX_S:
                    p = self._period
                    self._period = dt if p is None else p + 0.125 * (dt - p)
            self._last_ext = ext
            self._last_t = now
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
            if ext in self._pending or ext in self._suspects:
                self._duplicates += 1
            else:
                self._hold_item(ext, item, now, out)
                if self._suspects:
                    self._confirm(ext, out)
        elif -cfg.max_backward <= d < 0:
            if self._reopen and ext in self._reopen:
                self._reopen.remove(ext)  # given back after a content rejection: a second chance
                self._reopened += 1
                self._reordered += 1
                self._released += 1
                out.append(item)
            elif ext < self._start or ext in self._lost_set:
                self._lost_set.discard(ext)  # a second copy of a late item is a duplicate
                self._late += 1
                self._flow += 1  # the stream is alive below the release point: no jump is silent
                self._last_t = now
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
        if self._suspects:
            sus = min(v[1] for v in self._suspects.values())
            deadline = sus if deadline is None else min(deadline, sus)
        return deadline

    def reopen(self, seq: int) -> bool:
        """Give back the number of a released item the caller rejected for its content (a future epoch,
        a value the pipeline refuses): a later item with ``seq`` is then accepted instead of being a
        duplicate, so a forged datagram cannot use up a legitimate one's number. True if given back."""
        if self._ref is None or self._expected is None or self._cfg.max_reopened == 0:
            return False
        if type(seq) is not int or not 0 <= seq <= SERIAL_MASK:
            raise SequenceError(f"seq must be an int in 0..65535, got {seq!r}")
        d = ((seq - self._ref + SERIAL_HALF) & SERIAL_MASK) - SERIAL_HALF
        ext = self._ref + d
        if not (-self._cfg.max_backward <= d < 0) or ext < self._start or ext in self._reopen:
            return False
        self._reopen.append(ext)
        while len(self._reopen) > self._cfg.max_reopened:
            self._reopen.popleft()
        return True

    def flush(self) -> list[T]:
        """Release everything held, in order (gaps declared lost); drop (and count) probation items.

        For a clean stop (STOP, shutdown) and for stream eviction.
        """
        out: list[T] = []
        for ext in sorted(self._suspects):  # as at their time-out: kept if the stream stayed silent below
            item, _, e0, in_order, _ = self._suspects.pop(ext)
            if self._flow == e0 and (self._expected is None or ext >= self._expected):
                self._pending[ext] = item
                if in_order or ext > self._max_ext:
                    self._in_order += 1
                else:
                    self._reordered += 1
                self._max_ext = max(self._max_ext, ext)
            else:
                self._jump_drops += 1
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
        in_order = ext > self._max_ext
        self._accept_count(ext)
        self._pending[ext] = item
        self._arrivals.append((now + self._hold, ext, self._flow, in_order))
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
        self._reopen.clear()

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
            deadline, ext, e0, in_order = arrivals[0]
            if ext not in pending:
                arrivals.popleft()  # released already (lazy deletion)
            elif deadline <= now:
                arrivals.popleft()
                if self._trusted(ext, e0, now, arrived=deadline - self._hold):
                    self._release_through(ext, out)
                else:
                    self._suspect(ext, e0, in_order, now)
            else:
                break
        if self._suspects:
            self._expire_suspects(now, out)
        if self._prob and now >= self._prob_t + self._cfg.probation_timeout_s:
            self._prob_drops += len(self._prob)
            self._prob.clear()

    # ------------------------------------------------------------------ forward jumps (issue 20)

    def _confirmed(self, ext: int) -> bool:
        """``probation - 1`` more items are held within ``trusted_gap`` above ``ext``."""
        need = self._cfg.probation - 1
        if need <= 0:
            return True
        top = ext + self._cfg.trusted_gap + 1
        n = 0
        for k in self._pending:
            if ext < k <= top:
                n += 1
                if n >= need:
                    return True
        return False

    def _trusted(
        self, ext: int, e0: int, now: float, limited_alert: bool = True, arrived: float | None = None
    ) -> bool:
        """Whether the hold timer may release ``ext`` (declaring the gap below it lost)."""
        expected = self._expected
        if expected is None or ext <= expected:  # the startup hold; or nothing is skipped
            return True
        small = ext - expected <= self._cfg.trusted_gap
        # a large jump is confirmed only while the stream stayed silent below it: on a 1 Hz stream two
        # forgeries a second apart (SEQ + 100, then + 101) would otherwise confirm each other
        if (small or self._flow == e0) and self._confirmed(ext):
            return True
        if self._flow != e0:
            return False  # the stream went on in order below it since it arrived
        period = self._period
        if arrived is not None and period is not None:
            # the numbers missing are what the sender's rate explains for the silence before it (a loss
            # burst, an outage): (missing + 1) periods, at least 3/4 of them, passed since the last
            # in-order (or late) arrival. A forgery right behind a real datagram would need 75 periods
            # of a silent stream for SEQ + 100
            if arrived - self._last_t >= _RATE_SLACK * (ext - expected + 1) * period:
                return True
        if not small:
            return False
        cfg = self._cfg
        self._tokens = min(float(cfg.gap_budget), self._tokens + (now - self._tok_t) / cfg.gap_refill_s)
        self._tok_t = now
        if self._tokens >= 1.0:
            self._tokens -= 1.0
            return True
        if limited_alert:
            self._gap_limited += 1
            self._alert("sequence_gap_rate_limited", now, ext, missing=ext - expected)
        return False

    def _suspect(self, ext: int, e0: int, in_order: bool, now: float) -> None:
        """Take ``ext`` out of the release path until it is confirmed or its time-out."""
        item = self._pending.pop(ext)
        if in_order:
            self._in_order -= 1
        else:
            self._reordered -= 1
        self._jumps_held += 1
        self._suspects[ext] = (item, now + self._cfg.jump_timeout_s, e0, in_order, False)
        self._alert("sequence_jump_held", now, ext, missing=ext - (self._expected or ext))
        while len(self._suspects) > self._cfg.max_suspects:
            oldest = next(iter(self._suspects))
            del self._suspects[oldest]
            self._jump_drops += 1
        self._reset_max()

    def _reset_max(self) -> None:
        """The highest accepted number without the suspects (so the in-order count stays honest)."""
        top = (self._expected or 0) - 1
        if self._pending:
            top = max(top, max(self._pending))
        if top < self._max_ext:
            self._max_ext = top

    def _unsuspect(self, ext: int, out: list[T]) -> None:
        """Release suspect ``ext`` now (confirmed, or its stream stayed silent below it)."""
        item, _, _, in_order, _ = self._suspects.pop(ext)
        if in_order or ext > self._max_ext:
            self._in_order += 1
        else:
            self._reordered += 1
        self._max_ext = max(self._max_ext, ext)
        self._pending[ext] = item
        self._release_through(ext, out)

    def _confirm(self, ext: int, out: list[T]) -> None:
        """A newly held ``ext`` may confirm suspects below it."""
        span = self._cfg.trusted_gap + 1
        for s in sorted(self._suspects):
            entry = self._suspects.get(s)
            if entry is None or not s < ext <= s + span or not self._confirmed(s):
                continue
            expected = self._expected
            if expected is None or s - expected <= self._cfg.trusted_gap or self._flow == entry[2]:
                self._unsuspect(s, out)

    def _expire_suspects(self, now: float, out: list[T]) -> None:
        expected = self._expected
        for s in sorted(self._suspects):
            entry = self._suspects.get(s)
            if entry is None:
                continue
            item, deadline, e0, in_order, front = entry
            if expected is not None and s == expected and self._flow != e0:
                # the stream reached it from below: its number's own datagram, if the suspect was a
                # forgery, comes next (push drops the suspect then); nothing for jump_timeout_s: keep it
                if not front:
                    self._suspects[s] = (item, now + self._cfg.jump_timeout_s, e0, in_order, True)
                elif deadline <= now:
                    self._unsuspect(s, out)
            elif expected is not None and s < expected:  # the stream's in-order numbers passed it
                del self._suspects[s]
                self._jump_drops += 1
                self._alert("sequence_jump_dropped", now, s, why="passed by the stream")
            elif deadline <= now:
                if self._flow == e0:  # silent below it since it arrived: a last item after a loss
                    self._unsuspect(s, out)
                else:
                    del self._suspects[s]
                    self._jump_drops += 1
                    self._alert("sequence_jump_dropped", now, s, why="the stream went on below it")
            elif self._trusted(s, e0, now, limited_alert=False):  # e.g. the gap below it shrank
                self._unsuspect(s, out)
            expected = self._expected

    def _alert(self, kind: str, now: float, ext: int, **fields) -> None:
        if self.alerts is not None and len(self.alerts) < 1000:
            expected = self._expected
            self.alerts.append(
                {"event": kind, "at": now, "stream": self.key, "seq": ext & SERIAL_MASK,
                 "expected": None if expected is None else expected & SERIAL_MASK, **fields}
            )  # fmt: skip

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
        self._reopen.clear()
        if self._suspects:
            self._jump_drops += len(self._suspects)
            self._suspects.clear()
        self._resyncs += 1


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
        #: jump / rate-limit records of every stream (SequenceBuffer.alerts); the owner empties it
        self.alerts: list[dict] = []

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
            buf.alerts = self.alerts
            buf.key = key
        else:
            streams.move_to_end(key)
        released = buf.push(seq, item, now)
        if out:
            out.extend(released)
        else:
            out = released
        if buf._pending or buf._prob or buf._suspects:  # buf.pending_count, without the call
            self._active.add(key)
        else:
            self._active.discard(key)
        return out

    def run(self, keys, seqs, items, times, stop_item=None):
        """Take a recorded stream as the listener does live: before each datagram (key ``keys[i]``,
        number ``seqs[i]``, item ``items[i]``, arrival ``times[i]``), :meth:`poll` at every deadline due by
        its arrival (the listener's timer fires at :meth:`next_deadline`), then :meth:`push` it. Stops
        after pushing ``stop_item`` (a STOP: the caller flushes then).

        Returns (released items, the time each was released at, the release each came out of, numbered
        from 0 in order, and for ``stop_item``: None if it was not pushed, else whether its own push
        released it)."""
        rel: list[T] = []
        rel_t: list[float] = []
        rel_b: list[int] = []
        batch = 0
        active = self._active
        push, poll, next_deadline = self.push, self.poll, self.next_deadline
        stop_released = None
        for key, seq, item, t in zip(keys, seqs, items, times, strict=True):
            if active:  # (else next_deadline() is None)
                nd = next_deadline()
                while nd is not None and nd <= t:
                    out = poll(nd)
                    if out:
                        rel.extend(out)
                        rel_t.extend([nd] * len(out))
                        rel_b.extend([batch] * len(out))
                        batch += 1
                    nd = next_deadline()
            out = push(key, seq, item, t)
            if out:
                if len(out) == 1:
                    rel.append(out[0])
                    rel_t.append(t)
                    rel_b.append(batch)
                else:
                    rel.extend(out)
                    rel_t.extend([t] * len(out))
                    rel_b.extend([batch] * len(out))
                batch += 1
            if stop_item is not None and item == stop_item:
                stop_released = stop_item in out
                break
        return rel, rel_t, rel_b, stop_released

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
