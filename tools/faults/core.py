"""The fault proxy's core (sans-I/O): a datagram in, the datagrams to emit and when, every action counted.

``FaultCore.forward(data, sender, now)`` takes one datagram from a client (``sender`` is any hashable
key: the client's address live, the source port in replay) and returns ``[(send_time, datagram,
sender), ...]``. ``reply`` does the same for the other direction (upstream -> client), where only
blackouts apply unless the profile sets ``impair_replies``. Injections (forged datagrams, garbage)
and the release of held datagrams are due at ``next_timer()``; ``handle_timer(now)`` returns them.
Nothing reads a clock, opens a socket or sleeps; the generator is a seeded ``numpy.random.Generator``,
so the same datagrams at the same times give the same output, every time.

Order of decisions for a forwarded datagram: blackout, Gilbert-Elliott burst loss, Bernoulli loss,
bit flips, truncation, delay + jitter (kept in order per sender), reordering (held until the next
datagram of the same sender has gone out, or ``reorder_max_s``), duplication, replay of an earlier
datagram of the same sender. Emitted datagrams of one sender never overtake each other except where
a reorder or a replay was counted.
"""

from __future__ import annotations

import math
import struct
from collections import Counter, OrderedDict, deque
from collections.abc import Callable, Hashable
from dataclasses import dataclass, field

import numpy as np

from listener.codec import Strobe, encode_input
from tools.faults.config import SENSOR_NAMES, Impairments
from tools.faults.forge import (
    flip_bits,
    forge_invalid,
    forge_targeted,
    forge_valid,
    garbage_batch,
    inner_payload,
    truncate,
    with_seq,
)

FORGE_SENDER = ("forge", 0)  #: sender key of injected datagrams that do not pose as a real sender
FAULT_SENDER_ADDR = ("127.0.0.1", 40999)  #: where the replay path says such datagrams come from
_EPS_S = 1e-6  #: spacing of datagrams emitted together, keeping their order on an ordered link [s]

Emit = tuple[float, bytes, Hashable]

#: every counter the core keeps (all present in :meth:`FaultCore.stats`, zero when unused)
COUNTERS = (
    "received", "forwarded", "dropped_loss", "dropped_burst", "dropped_blackout", "bitflipped",
    "truncated", "duplicated", "reordered", "reorder_expired", "replayed", "forged_valid",
    "forged_invalid", "forged_foreign", "forged_jump", "forged_masquerade", "forge_unsigned", "stop_gapped",
    "burst_replayed", "garbage", "replies_received", "replies_forwarded",
    "replies_dropped_blackout",
    "replies_dropped_loss", "replies_duplicated", "replies_bitflipped", "replies_truncated",
    "senders_evicted", "emitted", "leading_drops",
)


@dataclass
class _Sender:
    last_send: float = -math.inf  #: send time of the newest datagram emitted for this sender
    held: tuple[bytes, float, bool] | None = None  #: (datagram, deadline, valid) held for a reorder
    history: deque = field(default_factory=deque)  #: earlier datagrams, for replays
    forwarded: bool = False  #: whether any datagram of this sender went out yet
    drops_since_forward: int = 0  #: datagrams dropped since the last one that went out
    last: bytes | None = None  #: the newest valid datagram forwarded (seq_jump forgeries copy it)
    types: set = field(default_factory=set)  #: SENSOR_TYPEs it has sent (forge_as picks the sender by them)
    seq: int | None = None  #: newest INPUT SEQ seen or forged on this stream (masquerades take the next)
    record: list = field(default_factory=list)  #: its first datagrams, for the replay burst


class FaultCore:
    """One direction's impairments (plus blackouts on the replies), deterministic for a seed."""

    def __init__(self, impairments: Impairments, seed: int, start: float | None = None,
                 sign: Callable[[bytes, bytes], bytes] | None = None) -> None:
        """``sign(payload, template)``: an authenticated stream's forgery signed as ``template`` (the
        posed-as sender's newest datagram) is signed, with that sender's key (``forge.module_signer``);
        None: such forgeries are skipped (counted ``forge_unsigned``)."""
        self.imp = impairments.validate()
        self.sign = sign
        self._burst_done = False
        self._strobe: tuple[float, float] | None = None  #: the newest real STROBE (timestamp, arrival)
        self.seed = seed
        self._rng = np.random.default_rng(seed)
        self._inj_rng = np.random.default_rng([seed, 1])  # injections never shift the forwarding draws
        self.start = start
        self.counters: Counter[str] = Counter()
        self._senders: OrderedDict[Hashable, _Sender] = OrderedDict()
        self._bad = False  # Gilbert-Elliott state
        self._forged = 0
        self._garbage = 0
        self._next_forge: float | None = None
        self._next_garbage: float | None = None
        if start is not None:
            self._arm(start)

    # ------------------------------------------------------------------ helpers
    def _arm(self, start: float) -> None:
        self.start = start
        imp = self.imp
        t0 = start + imp.inject_start_s
        self._next_forge = t0 if imp.forge_rate_hz > 0 else None
        self._next_garbage = t0 if imp.garbage_rate_hz > 0 else None

    def _started(self, now: float) -> None:
        if self.start is None:
            self._arm(now)

    def in_blackout(self, now: float) -> bool:
        """Whether ``now`` falls in a blackout window."""
        if self.start is None:
            return False
        t = now - self.start
        return any(a <= t < a + d for a, d in self.imp.blackouts)

    def _sender(self, key: Hashable) -> _Sender:
        st = self._senders.get(key)
        if st is None:
            st = _Sender(history=deque(maxlen=self.imp.replay_window))
            self._senders[key] = st
            if len(self._senders) > self.imp.max_senders:
                self._senders.popitem(last=False)
                self.counters["senders_evicted"] += 1
        else:
            self._senders.move_to_end(key)
        return st

    def _emit(self, out: list[Emit], t: float, data: bytes, sender: Hashable, st: _Sender | None,
              valid: bool = True, advance: bool = True) -> float:
        """Emit ``data`` at ``t`` or later (after the sender's previous emission).

        ``advance``: the datagram is the newest of its sender in sequence order, so drops counted so far
        lie before it and a receiver sees them as gaps. Not so for a held datagram released later (its
        place was settled when it was held), a replay, or a copy."""
        if st is not None:
            if valid and advance:
                self._settle(st)
            t = max(t, st.last_send + _EPS_S)
            st.last_send = t
        out.append((t, data, sender))
        self.counters["emitted"] += 1
        return t

    @staticmethod
    def _settle(st: _Sender) -> None:
        """A valid datagram of ``st`` will go out: the drops before it in sequence order are visible."""
        st.forwarded = True
        st.drops_since_forward = 0

    # ------------------------------------------------------------------ client -> upstream
    def forward(self, data: bytes, sender: Hashable, now: float) -> list[Emit]:
        """One datagram from a client at ``now``; returns what to send upstream and when."""
        self._started(now)
        imp, rng, c = self.imp, self._rng, self.counters
        c["received"] += 1
        out: list[Emit] = []
        st = self._sender(sender)
        if st.held is not None and st.held[1] <= now:  # a reorder hold that expired unnoticed
            out.extend(self._release_expired(sender, st, st.held[1]))
        if self.in_blackout(now):
            return self._drop(st, "dropped_blackout", out)
        if imp.ge_p_good_bad > 0.0:
            self._bad = rng.random() < (1.0 - imp.ge_p_bad_good if self._bad else imp.ge_p_good_bad)
            if rng.random() < (imp.ge_loss_bad if self._bad else imp.ge_loss_good):
                return self._drop(st, "dropped_burst", out)
        if imp.loss > 0.0 and rng.random() < imp.loss:
            return self._drop(st, "dropped_loss", out)
        original = bytes(data)
        if imp.stop_seq_gap and original[:1] == b"\x0a" and len(original) >= 3:  # a STOP (unauthenticated)
            original = with_seq(original, (original[1] | original[2] << 8) + imp.stop_seq_gap)
            c["stop_gapped"] += 1
        inner = inner_payload(original)
        if inner is not None:
            st.types.add(inner[0])
            from listener.serial import serial_gt

            s_in = inner[1] | inner[2] << 8
            if st.seq is None or serial_gt(s_in, st.seq):
                st.seq = s_in
        if inner is not None and inner[0] == 9 and inner is original and len(original) >= 13:  # a STROBE
            self._strobe = (struct.unpack_from("<d", original, 5)[0], now)  # its timestamp, when it passed
        if imp.replay_burst and len(st.record) < imp.replay_burst:
            st.record.append(original)
        payload = original
        if imp.bitflip > 0.0 and rng.random() < imp.bitflip:
            payload = flip_bits(rng, payload, imp.bitflip_bits)
            c["bitflipped"] += 1
        if imp.truncate > 0.0 and rng.random() < imp.truncate:
            payload = truncate(rng, payload)
            c["truncated"] += 1
        valid = len(payload) == len(original)
        if not valid:  # truncated: always rejected, so for the receiver's sequence it is a gap
            self._gap(st)
        t = now + imp.delay_s + (rng.uniform(0.0, imp.jitter_s) if imp.jitter_s > 0.0 else 0.0)
        if st.held is None and imp.reorder > 0.0 and rng.random() < imp.reorder:
            st.held = (payload, now + imp.reorder_max_s, valid)
            if valid:  # it goes out later, but its place in the sender's sequence is here
                self._settle(st)
        else:
            c["forwarded"] += 1
            t = self._emit(out, t, payload, sender, st, valid)
            if st.held is not None:  # the held datagram goes out right behind this one: a reorder
                held, _, held_valid = st.held
                st.held = None
                c["forwarded"] += 1
                c["reordered"] += 1
                t = self._emit(out, t, held, sender, st, held_valid, advance=False)
            if imp.duplicate > 0.0 and rng.random() < imp.duplicate:
                c["duplicated"] += 1
                t = self._emit(out, t + imp.duplicate_gap_s, payload, sender, st, valid, advance=False)
        if imp.replay > 0.0 and st.history and rng.random() < imp.replay:
            old = st.history[int(rng.integers(0, len(st.history)))]
            c["replayed"] += 1
            self._emit(out, t, old, sender, st, advance=False)
        if imp.replay > 0.0:
            st.history.append(original)
        if (imp.forge_kind == "seq_jump" or imp.forge_on_stream) and valid:
            st.last = original
        return out

    def _drop(self, st: _Sender, counter: str, out: list[Emit]) -> list[Emit]:
        self.counters[counter] += 1
        self._gap(st)
        return out

    def _gap(self, st: _Sender) -> None:
        """A datagram of ``st`` the receiver will not accept: leading, or pending as trailing."""
        if st.forwarded:
            st.drops_since_forward += 1
        else:
            self.counters["leading_drops"] += 1

    def _release_expired(self, sender: Hashable, st: _Sender, at: float) -> list[Emit]:
        assert st.held is not None
        held, _, valid = st.held
        st.held = None
        self.counters["forwarded"] += 1
        self.counters["reorder_expired"] += 1
        out: list[Emit] = []
        self._emit(out, at, held, sender, st, valid, advance=False)
        return out

    # ------------------------------------------------------------------ upstream -> client
    def reply(self, data: bytes, sender: Hashable, now: float) -> list[Emit]:
        """A datagram from upstream for the client ``sender``: blackouts, and impairments if configured."""
        self._started(now)
        imp, rng, c = self.imp, self._rng, self.counters
        c["replies_received"] += 1
        if self.in_blackout(now):
            c["replies_dropped_blackout"] += 1
            return []
        payload = bytes(data)
        out: list[Emit] = []
        if imp.impair_replies:
            if imp.loss > 0.0 and rng.random() < imp.loss:
                c["replies_dropped_loss"] += 1
                return []
            if imp.bitflip > 0.0 and rng.random() < imp.bitflip:
                payload = flip_bits(rng, payload, imp.bitflip_bits)
                c["replies_bitflipped"] += 1
            if imp.truncate > 0.0 and rng.random() < imp.truncate:
                payload = truncate(rng, payload)
                c["replies_truncated"] += 1
        t = now + imp.delay_s
        out.append((t, payload, sender))
        c["replies_forwarded"] += 1
        c["emitted"] += 1
        if imp.impair_replies and imp.duplicate > 0.0 and rng.random() < imp.duplicate:
            c["replies_duplicated"] += 1
            c["emitted"] += 1
            out.append((t + imp.duplicate_gap_s, payload, sender))
        return out

    # ------------------------------------------------------------------ timers
    def next_timer(self) -> float | None:
        """When :meth:`handle_timer` has something to do (None: nothing scheduled)."""
        times = [st.held[1] for st in self._senders.values() if st.held is not None]
        times += [t for t in (self._next_forge, self._next_garbage) if t is not None]
        if self.imp.bursts and not self._burst_done and self.start is not None:
            times.append(self.start + self.imp.replay_burst_at_s)
        return min(times) if times else None

    def handle_timer(self, now: float) -> list[Emit]:
        """Expired reorder holds and the injections due at ``now`` (at most ``max_batch`` of them)."""
        self._started(now)
        out: list[Emit] = []
        for key, st in list(self._senders.items()):
            if st.held is not None and st.held[1] <= now:
                out.extend(self._release_expired(key, st, st.held[1]))
        imp = self.imp
        assert self.start is not None
        if imp.bursts and not self._burst_done and now >= self.start + imp.replay_burst_at_s:
            self._burst_done = True  # every sender's recorded datagrams, from its own socket, in order
            t_burst = self.start + imp.replay_burst_at_s
            for key, st in list(self._senders.items()):
                for data in st.record:
                    self.counters["burst_replayed"] += 1
                    self._emit(out, t_burst, data, key, st, advance=False)
        end = self.start + imp.inject_end_s
        budget = imp.max_batch
        while self._next_forge is not None and self._next_forge <= now and budget > 0:
            t = self._next_forge
            if t >= end or (imp.forge_count and self._forged >= imp.forge_count):
                self._next_forge = None
                break
            budget -= 1
            self._forged += 1
            self._next_forge = self.start + imp.inject_start_s + self._forged / imp.forge_rate_hz
            if self.in_blackout(t):
                continue
            rng = self._inj_rng
            sender = self._forge_sender()
            valid = rng.random() < imp.forge_valid_fraction
            if valid and imp.forge_kind != "random":
                # issue 20's trust attacks: valid datagrams the sender table (GROUND TRUTH, STOP from
                # their own source) or the sequence buffer (a jump on a real sender's stream) must stop
                st = self._senders.get(sender) if sender is not None and sender != FORGE_SENDER else None
                whole = ("ground_truth", "stop", "strobe_shift")  # new datagrams, not a copy
                if sender is None or (st is not None and imp.forge_kind in whole and st.last is None):
                    continue  # forge_as: no such sender (yet)
                if imp.forge_kind == "strobe_shift":
                    if self._strobe is None:
                        continue  # no STROBE seen yet: the stream's clock is not known
                    ts, seen = self._strobe
                    shift = imp.forge_shift_s if rng.random() < 0.5 else -imp.forge_shift_s
                    data = encode_input(Strobe(int(rng.integers(0, 65536)), ts + (t - seen) + shift))
                else:
                    data = forge_targeted(rng, imp.forge_kind, None if st is None else st.last,
                                          imp.forge_seq_offset)  # fmt: skip
                if data is None:
                    continue
                kind = "forged_jump" if imp.forge_kind == "seq_jump" else "forged_foreign"
                if st is not None and imp.forge_kind in whole:
                    data = self._on_stream(st, data)
                    if data is None:
                        self.counters["forge_unsigned"] += 1
                        continue
                    # posing as the control module (the sender GROUND TRUTH and STOP are bound to): only
                    # plausibility stands in the way; posing as another module: the sender table
                    bound = SENSOR_NAMES["ground_truth"]  # the control module's socket: its own types
                    kind = "forged_masquerade" if bound in st.types else "forged_foreign"
                    self._emit(out, t, data, sender, st, advance=False)  # in order with the stream
                    self.counters[kind] += 1
                    continue
            elif valid:
                data, kind = forge_valid(rng), "forged_valid"
            else:
                data, kind = forge_invalid(rng), "forged_invalid"
            self.counters[kind] += 1
            out.append((t, data, sender))
            self.counters["emitted"] += 1
        if self._next_garbage is not None and self._next_garbage <= now and budget > 0:
            # the k-th garbage datagram is due at start + inject_start + k / rate: all due ones at once
            t0 = self.start + imp.inject_start_s
            # candidates computed exactly as _next_garbage is (no rounding can stall the timer)
            n = max(1, min(budget, math.ceil((now - t0) * imp.garbage_rate_hz) + 2 - self._garbage))
            times = t0 + (self._garbage + np.arange(n)) / imp.garbage_rate_hz
            k = int(np.count_nonzero((times <= now) & (times < end)))  # a prefix: times increase
            times = times[:k]
            self._garbage += k
            nxt = t0 + self._garbage / imp.garbage_rate_hz
            self._next_garbage = nxt if nxt < end else None
            datagrams = garbage_batch(self._inj_rng, k, imp.garbage_max_bytes) if k else []
            for t, data in zip(times.tolist(), datagrams, strict=True):
                if self.in_blackout(t):
                    continue
                self.counters["garbage"] += 1
                self.counters["emitted"] += 1
                out.append((t, data, FORGE_SENDER))
        return out

    def _forge_sender(self) -> Hashable | None:
        """Who a forgery leaves as: a real sender (forge_on_stream; the one of SENSOR_TYPE ``forge_as``
        when given, None while there is none), else the forger's own socket."""
        if self.imp.forge_as:
            want = SENSOR_NAMES[self.imp.forge_as]
            keys = [k for k, st in self._senders.items() if want in st.types]
            return keys[0] if keys else None
        if self.imp.forge_on_stream and self._senders:
            keys = list(self._senders)
            return keys[int(self._inj_rng.integers(0, len(keys)))]
        return FORGE_SENDER

    def _on_stream(self, st: _Sender, payload: bytes) -> bytes | None:
        """``payload`` (a GROUND TRUTH or STOP) as the next datagram of ``st``'s stream: the next SEQ,
        and on an authenticated stream signed as its newest datagram (None without ``sign``)."""
        assert st.last is not None
        seq = ((st.seq if st.seq is not None else -1) + 1) & 0xFFFF
        st.seq = seq
        payload = with_seq(payload, seq)
        if inner_payload(st.last) is st.last:
            return payload
        return None if self.sign is None else self.sign(payload, st.last)

    # ------------------------------------------------------------------ counters
    def stats(self) -> dict[str, int]:
        """A snapshot of every counter (all of :data:`COUNTERS`, zeros included) and the ``held`` gauge.

        Every received datagram is dropped (``dropped_*``), forwarded, or ``held`` now, so
        ``received == dropped_loss + dropped_burst + dropped_blackout + forwarded + held``.
        ``leading_drops`` (before a sender's first valid datagram went out) and ``trailing_drops`` (after
        its last one, so far) are the drops a receiver cannot see as gaps in the sequence numbers; a
        truncated datagram (always rejected) counts as a drop for these two.
        """
        out = {name: int(self.counters.get(name, 0)) for name in COUNTERS}
        out["held"] = sum(1 for st in self._senders.values() if st.held is not None)
        out["trailing_drops"] = sum(st.drops_since_forward for st in self._senders.values())
        return out
