"""Authenticated links (protocol extension, off by default): a truncated HMAC-SHA256 per datagram.

For untrusted networks (EN 50159 category 3) each datagram of a link can be wrapped with a tag that
only holders of the link's key can compute, and an epoch counter that, with the 16-bit SEQ already
in the payload, makes a 48-bit extended sequence number so a replay is rejected even after the SEQ
has wrapped. The thesis's unauthenticated format stays the default; nothing here is used unless a
link is configured with a key. Pure functions and a small state object: no clock, no socket.

Wire form of a wrapped datagram (little-endian)::

    offset 0   1 byte   MAGIC 0xA5      (not an INPUT SENSOR_TYPE, and a wrapped OUTPUT or ACK has
                                    the wrong length: a receiver without the extension rejects it)
    offset 1   1 byte   KEY_ID      which of the link's keys (rotation); 0..255
    offset 2   4 bytes  EPOCH       uint32, +1 each time the sender's SEQ wraps 65535 -> 0 or the
                                    sender restarts (a sender keeps it across restarts)
    offset 6   n bytes  PAYLOAD     the unchanged INPUT / OUTPUT / ACK datagram
    offset 6+n t bytes  TAG         HMAC-SHA256(key, bytes 0 .. 6+n-1) truncated to t bytes
                                    (t = 16 by default: 128 bits; 16..32 allowed)

Receiver (``unwrap``): length, magic, key id, then the tag (constant-time compare), and only for an
authentic datagram the replay window of its sender, keyed on ``(EPOCH << 16) | SEQ`` (an
anti-replay sliding window as in IPsec ESP, RFC 4303 section 3.4.3): a number already seen, or
further behind the newest than the window, is rejected. A rejected datagram never changes state.
"""

from __future__ import annotations

import hashlib
import hmac
import struct
from collections import OrderedDict
from collections.abc import Callable, Hashable
from dataclasses import dataclass
from enum import StrEnum

from listener.errors import ConfigError, ListenerError

MAGIC = 0xA5
HEADER = struct.Struct("<BBI")  #: MAGIC, KEY_ID, EPOCH
HEADER_BYTES = HEADER.size  #: 6
MIN_TAG_BYTES = 16  #: 128 bits, the least the extension allows
MAX_TAG_BYTES = 32  #: the full HMAC-SHA256
MIN_KEY_BYTES = 16  #: shorter keys are refused
MAX_EPOCH = 0xFFFFFFFF


class AuthReason(StrEnum):
    """Why an authenticated datagram was rejected (a stable metric label)."""

    SHORT = "auth_short"  #: shorter than header + tag (+ the 2 bytes a SEQ needs)
    MAGIC = "auth_magic"  #: first byte is not 0xA5: not a wrapped datagram
    KEY_ID = "auth_key_id"  #: no key with that id on this link
    TAG = "auth_tag"  #: the tag does not match: forged, corrupted or wrong key
    REPLAY = "auth_replay"  #: its (epoch, seq) was already accepted from this sender
    OLD = "auth_old"  #: further behind the sender's newest (epoch, seq) than the replay window


class AuthError(ListenerError):
    """An authenticated datagram was rejected. ``reason`` is an :class:`AuthReason`, ``detail`` a sentence."""

    __slots__ = ("reason", "detail")

    def __init__(self, reason: AuthReason, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail

    def __reduce__(self):
        return (type(self), (self.reason, self.detail))


def input_seq(payload: bytes) -> int:
    """SEQ of an INPUT_PROTOCOL datagram (bytes 1..2, little-endian)."""
    return payload[1] | (payload[2] << 8)


def output_seq(payload: bytes) -> int:
    """SEQ of an OUTPUT_PROTOCOL datagram or an ACK (bytes 0..1, little-endian)."""
    return payload[0] | (payload[1] << 8)


_SEQ_END = {input_seq: 3, output_seq: 2}


def derive_link_key(master_key: bytes, link: str) -> bytes:
    """A per-link key from one master secret: HMAC-SHA256(master, "sfa-link:" + link) (32 bytes)."""
    _check_key(master_key)
    return hmac.new(master_key, b"sfa-link:" + link.encode("utf-8"), hashlib.sha256).digest()


def _check_key(key: bytes) -> None:
    if not isinstance(key, bytes | bytearray) or len(key) < MIN_KEY_BYTES:
        raise ConfigError(f"authentication key: at least {MIN_KEY_BYTES} bytes required")


def _check_tag_bytes(tag_bytes: int) -> None:
    if isinstance(tag_bytes, bool) or not isinstance(tag_bytes, int) or not (
        MIN_TAG_BYTES <= tag_bytes <= MAX_TAG_BYTES
    ):
        raise ConfigError(f"tag_bytes: an integer in {MIN_TAG_BYTES}..{MAX_TAG_BYTES}, got {tag_bytes!r}")


def _tag(key: bytes, message: bytes, tag_bytes: int) -> bytes:
    return hmac.digest(key, message, "sha256")[:tag_bytes]


def wrap(payload: bytes, key: bytes, epoch_counter: int, *, key_id: int = 0, tag_bytes: int = 16) -> bytes:
    """The authenticated form of ``payload`` under ``key``, with the sender's ``epoch_counter``."""
    _check_key(key)
    _check_tag_bytes(tag_bytes)
    if isinstance(epoch_counter, bool) or not isinstance(epoch_counter, int) or not (
        0 <= epoch_counter <= MAX_EPOCH
    ):
        raise ConfigError(f"epoch_counter: an integer in 0..{MAX_EPOCH}, got {epoch_counter!r}")
    if isinstance(key_id, bool) or not isinstance(key_id, int) or not 0 <= key_id <= 255:
        raise ConfigError(f"key_id: an integer in 0..255, got {key_id!r}")
    message = HEADER.pack(MAGIC, key_id, epoch_counter) + bytes(payload)
    return message + _tag(key, message, tag_bytes)


class EpochCounter:
    """The sender's side: the epoch to put in each datagram, advanced when its SEQ wraps.

    ``epoch_for(seq)`` returns the epoch for the next datagram with ``seq``; a SEQ lower than or equal
    to the previous one (65535 -> 0, or a restart from 0) starts a new epoch. Persist ``epoch`` across
    sender restarts (start from the stored value + 1) so a restarted sender never reuses an epoch.
    """

    def __init__(self, epoch: int = 0) -> None:
        if not 0 <= epoch <= MAX_EPOCH:
            raise ConfigError(f"epoch: must be in 0..{MAX_EPOCH}")
        self.epoch = epoch
        self._last_seq: int | None = None

    def epoch_for(self, seq: int) -> int:
        if self._last_seq is not None and seq <= self._last_seq:
            if self.epoch >= MAX_EPOCH:
                raise ConfigError("epoch counter exhausted: the link needs a new key")
            self.epoch += 1
        self._last_seq = seq
        return self.epoch


class ReplayWindow:
    """Anti-replay sliding window over extended sequence numbers (``(epoch << 16) | seq``)."""

    __slots__ = ("size", "newest", "_bits")

    def __init__(self, size: int = 1024) -> None:
        if size < 1:
            raise ConfigError("replay window: size must be >= 1")
        self.size = size
        self.newest: int | None = None
        self._bits = 0  # bit i set: newest - i was accepted

    def check(self, ext: int) -> AuthReason | None:
        """Why ``ext`` must be rejected, or None if it is acceptable (state unchanged)."""
        if self.newest is None or ext > self.newest:
            return None
        back = self.newest - ext
        if back >= self.size:
            return AuthReason.OLD
        if (self._bits >> back) & 1:
            return AuthReason.REPLAY
        return None

    def accept(self, ext: int) -> None:
        """Record ``ext`` as accepted (call only after :meth:`check` returned None)."""
        if self.newest is None:
            self.newest, self._bits = ext, 1
        elif ext > self.newest:
            shift = ext - self.newest
            self._bits = ((self._bits << shift) | 1) & ((1 << self.size) - 1) if shift < self.size else 1
            self.newest = ext
        else:
            self._bits |= 1 << (self.newest - ext)

    def export(self) -> tuple[int | None, str]:
        """(newest, accepted bits as hex) for a checkpoint (:meth:`restore` reads it back)."""
        return self.newest, format(self._bits, "x")

    def skip(self, n: int) -> None:
        """Treat the next ``n`` extended sequence numbers as accepted (and every one in the window before
        them): after a restart from a checkpoint, the ones the lost process may have accepted since."""
        if self.newest is not None and n > 0:
            self.newest += n
            self._bits = (1 << self.size) - 1

    @classmethod
    def restore(cls, size: int, newest: int | None, bits_hex: str) -> ReplayWindow:
        """A window as :meth:`export` saved it (bits beyond ``size`` dropped); ValueError on bad values."""
        w = cls(size)
        if newest is not None:
            if isinstance(newest, bool) or not isinstance(newest, int) or newest < 0:
                raise ValueError(f"replay window newest {newest!r}: not a non-negative integer")
            w.newest = newest
            w._bits = int(bits_hex, 16) & ((1 << size) - 1)
        return w


@dataclass(frozen=True)
class AuthConfig:
    """Receiver settings of one authenticated link."""

    tag_bytes: int = 16  #: tag length [bytes], 16..32 (16 = 128 bits)
    window: int = 1024  #: replay window [extended sequence numbers]
    max_senders: int = 256  #: senders tracked; the least recently accepted is forgotten beyond [count]

    def validate(self) -> AuthConfig:
        _check_tag_bytes(self.tag_bytes)
        if self.window < 1 or self.max_senders < 1:
            raise ConfigError("window and max_senders must be >= 1")
        return self


class AuthState:
    """The receiver's per-sender replay windows and rejection counters of one link."""

    def __init__(self, config: AuthConfig | None = None) -> None:
        self.cfg = (config or AuthConfig()).validate()
        self.windows: OrderedDict[Hashable, ReplayWindow] = OrderedDict()
        self.accepted = 0
        self.rejected: dict[str, int] = {}
        self.evicted = 0

    def _reject(self, reason: AuthReason, detail: str) -> AuthError:
        self.rejected[str(reason)] = self.rejected.get(str(reason), 0) + 1
        return AuthError(reason, detail)


def unwrap(
    datagram: bytes,
    key: bytes | dict[int, bytes],
    state: AuthState,
    sender: Hashable = None,
    *,
    seq_of: Callable[[bytes], int] = input_seq,
) -> bytes:
    """The payload of an authentic, fresh datagram from ``sender``; else raises :class:`AuthError`.

    ``key`` is the link's key, or ``{key_id: key}`` during a key rotation. ``seq_of`` reads the SEQ
    from the payload (:func:`input_seq` for INPUT datagrams, :func:`output_seq` for OUTPUT and ACK).
    """
    tag_bytes = state.cfg.tag_bytes
    need = HEADER_BYTES + _SEQ_END.get(seq_of, 3) + tag_bytes
    if not isinstance(datagram, bytes | bytearray | memoryview):
        raise state._reject(AuthReason.SHORT, f"not bytes-like: {type(datagram).__name__}")
    data = bytes(datagram)
    if len(data) < need:
        raise state._reject(AuthReason.SHORT, f"{len(data)} bytes, at least {need} needed")
    magic, key_id, epoch = HEADER.unpack_from(data)
    if magic != MAGIC:
        raise state._reject(AuthReason.MAGIC, f"first byte 0x{magic:02x}, expected 0x{MAGIC:02x}")
    if isinstance(key, dict):
        link_key = key.get(key_id)
        if link_key is None:
            raise state._reject(AuthReason.KEY_ID, f"no key with id {key_id}")
    elif key_id != 0:
        raise state._reject(AuthReason.KEY_ID, f"no key with id {key_id}")
    else:
        link_key = key
    message, tag = data[:-tag_bytes], data[-tag_bytes:]
    if not hmac.compare_digest(_tag(link_key, message, tag_bytes), tag):
        raise state._reject(AuthReason.TAG, "tag mismatch")
    payload = message[HEADER_BYTES:]
    ext = (epoch << 16) | seq_of(payload)
    window = state.windows.get(sender)
    if window is None:
        window = ReplayWindow(state.cfg.window)
    why = window.check(ext)
    if why is not None:
        raise state._reject(why, f"epoch {epoch} seq {ext & 0xFFFF} from {sender!r}")
    window.accept(ext)
    state.windows[sender] = window
    state.windows.move_to_end(sender)
    if len(state.windows) > state.cfg.max_senders:
        state.windows.popitem(last=False)
        state.evicted += 1
    state.accepted += 1
    return payload
