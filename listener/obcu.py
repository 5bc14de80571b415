"""Mock OBCU core (sans-I/O): receives OUTPUT_PROTOCOL, acknowledges, records, misbehaves on request.

It stands in for the on-board control unit in tests and in the demo. Misbehaviour is scheduled in
seconds from the start so tests are repeatable:

- ``drop_acks``: windows ``(start_s, duration_s)`` in which outputs are received but never acked;
- ``silent``: windows in which the OBCU neither records nor acks anything (a cut link);
- ``restart_at_s``: times at which it forgets everything (as a rebooted OBCU would).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from listener.codec import DecodeError, decode_output, decode_output_extended, encode_ack
from listener.defaults import DEFAULT_OBCU_PORT
from listener.serial import serial_gt


@dataclass(frozen=True)
class ObcuConfig:
    """Mock OBCU settings."""

    bind: str = "127.0.0.1"  #: address to receive outputs on
    port: int = DEFAULT_OBCU_PORT  #: UDP port [1..65535]
    ack_interval_s: float = 1.0  #: period of acks while outputs arrive [s]
    drop_acks: tuple[tuple[float, float], ...] = ()  #: (start, duration) windows without acks [s]
    silent: tuple[tuple[float, float], ...] = ()  #: (start, duration) windows ignoring everything [s]
    restart_at_s: tuple[float, ...] = ()  #: times at which all state is forgotten [s]
    auth_master_key: bytes | None = None  #: authenticated links (extension): the master key, or None


@dataclass(frozen=True)
class Received:
    """One output as the OBCU received it."""

    time_s: float  #: OBCU time of arrival [s]
    seq: int
    epoch: float  #: sensor-set time of the estimate [s]
    arc_length: float  #: [m]
    size: int  #: datagram length [bytes]
    speed: float | None = None  #: extended form only [m/s]
    interval_low: float | None = None  #: extended form only [m]
    interval_high: float | None = None  #: extended form only [m]
    status: int | None = None  #: extended form only (filter status code)
    line_id: int | None = None  #: extended form only


@dataclass
class ObcuStats:
    received: int = 0  #: valid outputs received
    malformed: int = 0  #: datagrams that are not a valid output
    duplicates: int = 0  #: outputs whose SEQ was not newer than the newest (retransmissions, reorders)
    acks_sent: int = 0
    acks_dropped: int = 0  #: acks withheld by a drop_acks window
    ignored_silent: int = 0  #: datagrams ignored during a silent window
    restarts: int = 0
    auth_rejected: int = 0  #: datagrams failing authentication (extension enabled only)
    by_size: dict[int, int] = field(default_factory=dict)  #: datagram sizes seen


def _inside(t: float, windows: tuple[tuple[float, float], ...]) -> bool:
    return any(start <= t < start + dur for start, dur in windows)


class MockObcu:
    """Receives outputs and says which acks to send, given ``now`` (seconds since start)."""

    def __init__(self, config: ObcuConfig | None = None, start: float = 0.0) -> None:
        self.cfg = config or ObcuConfig()
        self._start = start
        self._restarts_done = 0
        self.stats = ObcuStats()
        self._auth = None
        if self.cfg.auth_master_key is not None:
            import time

            from listener.auth import AuthState, EpochCounter, derive_link_key
            from listener.auth_link import LINK_ACK, LINK_OUTPUT

            key = self.cfg.auth_master_key
            self._auth = (
                derive_link_key(key, LINK_OUTPUT),
                AuthState(),
                derive_link_key(key, LINK_ACK),
                EpochCounter(int(time.time()) & 0xFFFFFFFF),
            )
        self._reset()

    def _reset(self) -> None:
        self.newest_seq: int | None = None
        self.newest: Received | None = None
        self._peer: tuple[str, int] | None = None
        self._received_since_ack = False
        self._next_ack: float | None = None

    def _maybe_restart(self, now: float) -> bool:
        t = now - self._start
        due = sum(1 for r in self.cfg.restart_at_s if r <= t)
        if due > self._restarts_done:
            self._restarts_done = due
            self.stats.restarts += 1
            self._reset()
            return True
        return False

    def receive(self, data: bytes, addr: tuple[str, int], now: float) -> Received | None:
        """One datagram from the listener; returns what was recorded (None if ignored or malformed)."""
        self._maybe_restart(now)
        if _inside(now - self._start, self.cfg.silent):
            self.stats.ignored_silent += 1
            return None
        if self._auth is not None:
            from listener.auth import AuthError, output_seq, unwrap

            try:
                data = unwrap(data, self._auth[0], self._auth[1], addr, seq_of=output_seq)
            except AuthError:
                self.stats.auth_rejected += 1
                return None
        try:
            if len(data) > 18:
                ext = decode_output_extended(data)
                rec = Received(
                    now,
                    ext.seq,
                    ext.epoch,
                    ext.arc_length,
                    len(data),
                    ext.speed,
                    ext.interval_low,
                    ext.interval_high,
                    ext.status,
                    ext.line_id,
                )
            else:
                msg = decode_output(data)
                rec = Received(now, msg.seq, msg.epoch, msg.arc_length, len(data))
        except DecodeError:
            self.stats.malformed += 1
            return None
        msg = rec
        self.stats.received += 1
        self.stats.by_size[len(data)] = self.stats.by_size.get(len(data), 0) + 1
        if self.newest_seq is None or serial_gt(msg.seq, self.newest_seq):
            self.newest_seq = msg.seq
            self.newest = rec
        else:
            self.stats.duplicates += 1
        self._peer = addr
        self._received_since_ack = True
        if self._next_ack is None:
            self._next_ack = now  # first ack right away, then periodically
        return rec

    def next_timer(self) -> float | None:
        return self._next_ack

    def handle_timer(self, now: float) -> list[tuple[bytes, tuple[str, int]]]:
        """Acks due at ``now`` as ``(datagram, address)``."""
        if self._maybe_restart(now):
            return []
        if self._next_ack is None or now < self._next_ack:
            return []
        self._next_ack = now + self.cfg.ack_interval_s
        if not self._received_since_ack or self.newest_seq is None or self._peer is None:
            self._next_ack = None  # nothing received since the last ack: stay quiet until outputs resume
            return []
        self._received_since_ack = False
        t = now - self._start
        if _inside(t, self.cfg.silent):
            return []
        if _inside(t, self.cfg.drop_acks):
            self.stats.acks_dropped += 1
            return []
        self.stats.acks_sent += 1
        ack = encode_ack(self.newest_seq)
        if self._auth is not None:
            from listener.auth import wrap

            ack = wrap(ack, self._auth[2], self._auth[3].epoch_for(self.newest_seq))
        return [(ack, self._peer)]
