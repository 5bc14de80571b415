"""OUTPUT_PROTOCOL link to the OBCU: sequence numbers, rate cap, acks, retransmission, link state.

Sans-I/O: every entry point takes ``now`` (listener monotonic seconds) and returns the datagrams to
send; the asyncio layer only moves bytes.

Policy (documented in docs/listener.md):
- Every new filter estimate gets the next SEQ (wrapping 65535 -> 0) and is sent at once, unless the
  rate cap (``max_rate_hz``) says it is too soon; then it waits as the *freshest* pending estimate and
  goes out when the cap allows (older pending ones are superseded, never queued).
- An ACK carries the newest SEQ the OBCU received. It is accepted if it names a SEQ we sent within the
  last half of the serial space and is not older than the last accepted ack; otherwise it is counted
  as bogus and ignored.
- Link state: IDLE until the first output; then UP while the last ack (or, before any ack, the first
  output) is younger than ``degraded_after_s``, DEGRADED up to ``down_after_s``, DOWN beyond. Every
  transition is recorded with its time.
- Retransmission: when the newest sent estimate is not acked and nothing newer was sent for
  ``retransmit_interval_s``, it is sent again with the same SEQ (it is the same estimate), at most
  ``max_retransmits`` times and never once it is older than ``max_output_age_s``. The OBCU only needs
  the freshest estimate, so older ones are never resent. Retransmission never delays a new estimate.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from listener.codec import DecodeError, OutputMessage, decode_ack, encode_output
from listener.config import LinkConfig
from listener.serial import serial_diff, serial_gt


class LinkState(StrEnum):
    IDLE = "idle"
    UP = "up"
    DEGRADED = "degraded"
    DOWN = "down"


@dataclass
class _Sent:
    seq: int
    payload: bytes
    created: float  #: listener time the estimate was produced [s]
    last_sent: float  #: listener time of its last (re)transmission [s]
    resends: int = 0


@dataclass(frozen=True)
class LinkStats:
    outputs: int  #: new estimates sent
    superseded: int  #: estimates replaced by a fresher one before the rate cap let them out
    retransmits: int  #: resends of an unacked estimate
    acks: int  #: acks accepted
    bogus_acks: int  #: acks naming a SEQ never sent, or older than the last accepted one
    bad_acks: int  #: datagrams on the output socket that are not a 2-byte ACK
    last_acked_seq: int | None
    state: str
    state_since: float | None


class ObcuLink:
    """The listener's side of the OBCU link."""

    def __init__(self, config: LinkConfig | None = None, encoder=None) -> None:
        self._cfg = config or LinkConfig()
        self._encode = encoder or (lambda seq, est: encode_output(OutputMessage(seq, est[0], est[1])))
        self._next_seq = self._cfg.start_seq & 0xFFFF
        self._min_interval = 1.0 / self._cfg.max_rate_hz if self._cfg.max_rate_hz > 0 else 0.0
        self._last_new_send: float | None = None
        self._pending: tuple[object, float] | None = None  # (estimate, created)
        self._newest: _Sent | None = None
        self._first_output: float | None = None
        self._last_ack_time: float | None = None
        self._last_acked: int | None = None
        self._state = LinkState.IDLE
        self._state_since: float | None = None
        self.transitions: list[tuple[float, str]] = []  #: (time, new state), most recent 1000
        self.transitions_total = 0  #: state changes since start (``transitions`` keeps the last 1000)
        self.withheld = 0  #: estimates the pipeline withheld (:meth:`withhold`)
        self.outputs = 0
        self.superseded = 0
        self.retransmits = 0
        self.acks = 0
        self.bogus_acks = 0
        self.bad_acks = 0

    @property
    def next_seq(self) -> int:
        """SEQ the next new output will carry."""
        return self._next_seq

    def continue_at(self, seq: int) -> None:
        """Number the next new output ``seq`` (a resumed listener continues past the SEQs it sent)."""
        self._next_seq = int(seq) & 0xFFFF

    # ------------------------------------------------------------------ estimates
    def send_estimate(self, estimate, now: float) -> list[bytes]:
        """A new estimate from the filter (``(epoch, arc_length, ...)``); returns datagrams to send."""
        if self._pending is not None:
            self.superseded += 1
        self._pending = (estimate, now)
        return self._flush_pending(now)

    def _flush_pending(self, now: float) -> list[bytes]:
        if self._pending is None:
            return []
        if self._last_new_send is not None and now - self._last_new_send < self._min_interval - 1e-12:
            return []
        estimate, created = self._pending
        self._pending = None
        seq = self._next_seq
        self._next_seq = (seq + 1) & 0xFFFF
        payload = self._encode(seq, estimate)
        self._newest = _Sent(seq, payload, created, now)
        self._last_new_send = now
        self.outputs += 1
        if self._first_output is None:
            self._first_output = now
        self._update_state(now)
        return [payload]

    def count_sent(self, outputs: int, retransmits: int = 0) -> None:
        """Count ``outputs`` new estimates and ``retransmits`` resends sent outside :meth:`send_estimate`
        and :meth:`handle_timer` (a replay that computed them, ``tools.fast_replay``) as those count
        theirs; the next new output is numbered after them."""
        self.outputs += outputs
        self.retransmits += retransmits
        self._next_seq = (self._next_seq + outputs) & 0xFFFF

    def withhold(self, now: float) -> None:
        """Send nothing more of what was produced so far: the pending estimate is dropped and the newest
        sent one is never resent (vital supervision: a position that can no longer be vouched for)."""
        self.withheld += 1
        self._pending = None
        if self._newest is not None:
            self._newest.resends = self._cfg.max_retransmits
        self._update_state(now)

    # ------------------------------------------------------------------ acks
    def receive_ack(self, data: bytes, now: float) -> None:
        """An ACK datagram from the OBCU."""
        try:
            seq = decode_ack(data)
        except DecodeError:
            self.bad_acks += 1
            return
        newest = self._newest
        if newest is None:
            self.bogus_acks += 1
            return
        # must be a SEQ we have sent: not newer than the newest, and no further behind it than the
        # number of outputs so far (capped at half the serial space)
        back = -serial_diff(seq, newest.seq)
        if back < 0 or back >= min(self.outputs, 0x8000):
            self.bogus_acks += 1
            return
        if self._last_acked is not None and serial_gt(self._last_acked, seq):
            self.bogus_acks += 1  # older than what was already acknowledged
            return
        self._last_acked = seq
        self._last_ack_time = now
        self.acks += 1
        self._update_state(now)

    # ------------------------------------------------------------------ timers
    def next_timer(self) -> float | None:
        """Listener time at which :meth:`handle_timer` has something to do."""
        times: list[float] = []
        if self._pending is not None and self._last_new_send is not None:
            times.append(self._last_new_send + self._min_interval)
        if self._state is not LinkState.IDLE:
            ref = self._ack_reference()
            if ref is not None:
                if self._state is LinkState.UP:
                    times.append(ref + self._cfg.degraded_after_s)
                elif self._state is LinkState.DEGRADED:
                    times.append(ref + self._cfg.down_after_s)
        if self._needs_resend_candidate():
            assert self._newest is not None
            times.append(self._newest.last_sent + self._cfg.retransmit_interval_s)
        return min(times) if times else None

    def handle_timer(self, now: float) -> list[bytes]:
        """Rate-capped sends, retransmissions and state changes due at ``now``."""
        out = self._flush_pending(now)
        self._update_state(now)
        if not out and self._needs_resend_candidate():
            newest = self._newest
            assert newest is not None
            if now - newest.last_sent >= self._cfg.retransmit_interval_s - 1e-12:
                if now - newest.created <= self._cfg.max_output_age_s:
                    newest.resends += 1
                    newest.last_sent = now
                    self.retransmits += 1
                    out.append(newest.payload)
                else:
                    newest.resends = self._cfg.max_retransmits  # too old: never again
        return out

    def _needs_resend_candidate(self) -> bool:
        newest = self._newest
        if newest is None or self._pending is not None:
            return False
        if self._last_acked == newest.seq:
            return False
        return newest.resends < self._cfg.max_retransmits

    # ------------------------------------------------------------------ state
    def _ack_reference(self) -> float | None:
        return self._last_ack_time if self._last_ack_time is not None else self._first_output

    def _update_state(self, now: float) -> None:
        ref = self._ack_reference()
        if ref is None:
            new = LinkState.IDLE
        else:
            quiet = now - ref
            if quiet < self._cfg.degraded_after_s:
                new = LinkState.UP
            elif quiet < self._cfg.down_after_s:
                new = LinkState.DEGRADED
            else:
                new = LinkState.DOWN
        if new is not self._state:
            self._state = new
            self._state_since = now
            self.transitions.append((now, new.value))
            self.transitions_total += 1
            del self.transitions[:-1000]

    @property
    def state(self) -> LinkState:
        return self._state

    def stats(self) -> LinkStats:
        return LinkStats(
            outputs=self.outputs,
            superseded=self.superseded,
            retransmits=self.retransmits,
            acks=self.acks,
            bogus_acks=self.bogus_acks,
            bad_acks=self.bad_acks,
            last_acked_seq=self._last_acked,
            state=self._state.value,
            state_since=self._state_since,
        )
