"""The listener's authenticated links: keys per link and direction, replay state, epoch counters.

Wraps :mod:`listener.auth` (the pure wire functions) for the pipeline. One master key (a file, hex)
gives three link keys, ``derive_link_key(master, name)``:

- ``modules->listener:<id>``: INPUT datagrams of interface module ``id`` (0..255, carried in the
  KEY_ID byte). Each module has its own key, so the KEY_ID is an authenticated sender identity and the
  anti-replay window is kept per module id, not per source address: a datagram captured from one
  module and re-sent from another (spoofed) address is still checked against its own module's window;
- ``listener->obcu``: OUTPUT datagrams, wrapped with the listener's epoch counter (advanced at each SEQ
  wrap, started from the wall-clock second at start so a restart never reuses an (epoch, SEQ) pair);
  a retransmission is the same wrapped datagram;
- ``obcu->listener``: ACKs, verified with their own anti-replay window (a repeated ack of the same
  SEQ is rejected as a replay and changes nothing).
"""

from __future__ import annotations

import math
from typing import Any

from listener.auth import (
    HEADER_BYTES,
    MAGIC,
    MAX_EPOCH,
    AuthConfig,
    AuthReason,
    AuthState,
    EpochCounter,
    ReplayWindow,
    derive_link_key,
    output_seq,
    unwrap,
    wrap,
)
from listener.config import AuthSettings, read_master_key

LINK_INPUT = "modules->listener"
LINK_OUTPUT = "listener->obcu"
LINK_ACK = "obcu->listener"


def input_key(master_key: bytes, module_id: int) -> bytes:
    """The key interface module ``module_id`` (0..255, sent as KEY_ID) wraps its INPUT datagrams with."""
    return derive_link_key(master_key, f"{LINK_INPUT}:{module_id}")


#: on a restore, each anti-replay window skips this times its advance over the last checkpoint interval
#: (+1): what the killed process may have accepted after its last checkpoint (at most about one
#: interval's worth). Larger is not safer: the datagrams a sender sends right after a quick restart fall
#: in the skip and are rejected (as ``auth_replay``); with 1.5 a restart 1 s after the kill lost the first
#: 0.3 s of IMU and odometer samples, and that resumed filter then stayed off by 0.5 m with an interval
#: that did not hold the truth (the trust campaign's auth-replay-after-restart row, seed 3)
RESUME_SKIP_FACTOR = 1.0


class LinkAuth:
    """Keys and state of the listener's three authenticated directions."""

    def __init__(
        self, master_key: bytes, tag_bytes: int = 16, window: int = 1024, start_epoch: int = 0
    ) -> None:
        self.tag_bytes = tag_bytes
        self._master = master_key
        self._input_keys: dict[int, bytes] = {}
        self.key_output = derive_link_key(master_key, LINK_OUTPUT)
        self.key_ack = derive_link_key(master_key, LINK_ACK)
        cfg = AuthConfig(tag_bytes=tag_bytes, window=window)
        self.input_state = AuthState(cfg)
        self.ack_state = AuthState(cfg)
        self.output_epoch = EpochCounter(start_epoch)
        self._input_min_bytes = HEADER_BYTES + 3 + tag_bytes  # header, INPUT SEQ, tag: unwrap's bound
        self.last_key_id: int | None = None  #: KEY_ID of the last authentic INPUT datagram
        self._exported: dict[tuple[str, Any], int | None] = {}  #: each window's newest at the last export

    @classmethod
    def from_config(cls, settings: AuthSettings, start_epoch: int = 0) -> LinkAuth:
        return cls(read_master_key(settings.key_file), settings.tag_bytes, settings.window, start_epoch)

    def input_key(self, module_id: int) -> bytes:
        """The INPUT link key of interface module ``module_id`` (what that module wraps with)."""
        key = self._input_keys.get(module_id)
        if key is None:
            key = self._input_keys[module_id] = input_key(self._master, module_id)
        return key

    def open_input(self, datagram: bytes, sender: Any) -> bytes:
        """The INPUT payload of an authentic, fresh datagram; raises AuthError otherwise.

        ``sender`` (the source address) is not trusted: the replay window is the module id's.
        """
        module_id = datagram[1] if len(datagram) > 1 else 0
        payload = unwrap(datagram, {module_id: self.input_key(module_id)}, self.input_state, module_id)
        self.last_key_id = module_id  # the authenticated sender identity (listener.senders)
        return payload

    def precheck_input(self, buf: bytes | bytearray, n: int) -> str | None:
        """The checks :meth:`open_input` makes before the HMAC, on ``buf[:n]``: the reason (counted, as
        ``unwrap`` counts it) if the datagram is too short or its first byte is not MAGIC, else None.

        For the service's batched reader: a flood of garbage is rejected without a copy or a tag.
        """
        if n < self._input_min_bytes:
            reason = AuthReason.SHORT
        elif buf[0] != MAGIC:
            reason = AuthReason.MAGIC
        else:
            return None
        rejected = self.input_state.rejected
        label = str(reason)
        rejected[label] = rejected.get(label, 0) + 1
        return label

    def open_ack(self, datagram: bytes) -> bytes:
        """The ACK payload of an authentic, fresh datagram; raises AuthError otherwise."""
        return unwrap(datagram, self.key_ack, self.ack_state, "obcu", seq_of=output_seq)

    def seal_output(self, payload: bytes, seq: int) -> bytes:
        return wrap(payload, self.key_output, self.output_epoch.epoch_for(seq), tag_bytes=self.tag_bytes)

    def export_state(self) -> dict[str, Any]:
        """The anti-replay windows and the output epoch counter, JSON-serialisable (a checkpoint).

        Each window row is ``[sender, newest, bits, advance]``: ``advance`` is how far its newest moved
        since the previous export (one checkpoint interval: the sender's rate per interval). A process
        killed between two checkpoints may have accepted about that many more; :meth:`restore_state`
        treats them as accepted (:data:`RESUME_SKIP_FACTOR`), so none of them is accepted twice."""
        def windows(name: str, state: AuthState) -> list[list[Any]]:
            rows = []
            for k, w in state.windows.items():
                prev = self._exported.get((name, k))
                advance = 0 if prev is None or w.newest is None else max(0, w.newest - prev)
                self._exported[(name, k)] = w.newest
                rows.append([k, *w.export(), advance])
            return rows

        return {"input": windows("input", self.input_state), "ack": windows("ack", self.ack_state),
                "output_epoch": self.output_epoch.epoch}

    def restore_state(self, data: dict[str, Any]) -> None:
        """Take back what :meth:`export_state` saved: the windows, and an output epoch past the saved one
        (never lower than the one this process started with). ValueError on a malformed state."""
        for name, state in (("input", self.input_state), ("ack", self.ack_state)):
            rows = data.get(name, [])
            if not isinstance(rows, list):
                raise ValueError(f"auth.{name}: not a list")
            for row in rows[-state.cfg.max_senders:]:
                if not (isinstance(row, list) and len(row) in (3, 4) and isinstance(row[2], str)):
                    raise ValueError(f"auth.{name}: malformed window {row!r}")
                advance = row[3] if len(row) == 4 else 0
                if isinstance(advance, bool) or not isinstance(advance, int) or advance < 0:
                    raise ValueError(f"auth.{name}: window advance {advance!r}: not a count")
                w = ReplayWindow.restore(state.cfg.window, row[1], row[2])
                w.skip(math.ceil(advance * RESUME_SKIP_FACTOR) + (1 if advance else 0))
                state.windows[row[0]] = w
        epoch = data.get("output_epoch", 0)
        if isinstance(epoch, bool) or not isinstance(epoch, int) or not 0 <= epoch < MAX_EPOCH:
            raise ValueError(f"auth.output_epoch {epoch!r}: not an epoch counter")
        self.output_epoch.epoch = max(self.output_epoch.epoch, epoch + 1)

    def stats(self) -> dict[str, Any]:
        return {
            "input_accepted": self.input_state.accepted,
            "input_rejected": dict(sorted(self.input_state.rejected.items())),
            "ack_accepted": self.ack_state.accepted,
            "ack_rejected": dict(sorted(self.ack_state.rejected.items())),
            "output_epoch": self.output_epoch.epoch,
        }


def main(argv: list[str] | None = None) -> int:
    """``python -m listener.auth_link MASTER_KEY_FILE KEY_ID``: print interface module KEY_ID's key (hex).

    A deployment gives each interface module only its own key (``sfa sim --live --auth-module-key
    NAME=KEY_ID:FILE``), never the master key, which would let it pose as any module, the listener or
    the OBCU.
    """
    import sys

    from listener.errors import ConfigError

    args = sys.argv[1:] if argv is None else argv
    if len(args) != 2 or not args[1].isdigit() or not 0 <= int(args[1]) <= 255:
        print("usage: python -m listener.auth_link MASTER_KEY_FILE KEY_ID (0..255)", file=sys.stderr)
        return 2
    try:
        print(input_key(read_master_key(args[0]), int(args[1])).hex())
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
