"""Datagrams the proxy injects: forged INPUT datagrams (valid-looking or subtly invalid) and garbage.

Forged datagrams are built with :func:`listener.codec.encode_input` from random field values drawn
from the caller's seeded generator: a *valid* forgery is in range and well formed (only an integrity
check can tell it from a real one); an *invalid* one breaks exactly one rule the codec checks (a
value out of range, a NaN, a form no table row allows, a wrong length). Garbage is random bytes.
"""

from __future__ import annotations

import struct

import numpy as np

from listener.codec import GpsFix, GroundTruth, ImuSample, OdometerSample, Stop, Strobe, encode_input

_INVALID_KINDS = ("range", "non_finite", "form", "length", "type")


def forge_valid(rng: np.random.Generator, epoch_s: float | None = None) -> bytes:
    """A well-formed, in-range INPUT datagram with random content (a spoofed sensor sample)."""
    seq = int(rng.integers(0, 65536))
    epoch = None if epoch_s is None else float(epoch_s + rng.uniform(-5.0, 5.0))
    kind = int(rng.integers(0, 5))
    if kind == 0:
        f = rng.uniform(-20.0, 20.0, 3)
        w = rng.uniform(-1.0, 1.0, 3)
        return encode_input(ImuSample(seq, *map(float, f), *map(float, w), epoch))
    if kind == 1:
        speed, sigma = float(rng.uniform(-40.0, 40.0)), float(rng.uniform(0.01, 2.0))
        return encode_input(OdometerSample(seq, speed, sigma, epoch))
    if kind == 2:
        return encode_input(GpsFix(seq, float(rng.uniform(-89.0, 89.0)), float(rng.uniform(-179.0, 179.0)),
                                   float(rng.uniform(0.0, 500.0)), 1, int(rng.integers(4, 20)),
                                   float(rng.uniform(0.5, 10.0)), epoch))
    if kind == 3:
        return encode_input(GroundTruth(seq, float(rng.uniform(0.0, 30.0)), 0.0, 0.0,
                                        float(rng.uniform(0.0, 20000.0)), None, epoch))
    return encode_input(Strobe(seq, float(rng.uniform(0.0, 1e9) if epoch is None else epoch)))


def forge_targeted(
    rng: np.random.Generator, kind: str, last: bytes | None = None, offset: int = 100
) -> bytes | None:
    """A well-formed forgery of ``kind`` (Impairments.forge_kind other than "random"): a GROUND TRUTH at a
    random arc length, a STOP, or ``last`` (the real sender's newest datagram) with SEQ + ``offset``
    (None when there is no ``last`` yet)."""
    seq = int(rng.integers(0, 65536))
    if kind == "ground_truth":
        return encode_input(GroundTruth(seq, float(rng.uniform(0.0, 30.0)), 0.0, 0.0,
                                        float(rng.uniform(0.0, 20000.0)), None, None))
    if kind == "stop":
        return encode_input(Stop(seq))
    if kind == "seq_jump":
        if last is None or len(last) < 5:
            return None
        s = ((last[1] | last[2] << 8) + offset) & 0xFFFF
        return last[:1] + struct.pack("<H", s) + last[3:]
    raise ValueError(f"forge kind {kind!r}")


def forge_invalid(rng: np.random.Generator) -> bytes:
    """An INPUT datagram that breaks exactly one codec rule (so a correct listener rejects it)."""
    seq = int(rng.integers(0, 65536))
    how = _INVALID_KINDS[int(rng.integers(0, len(_INVALID_KINDS)))]
    if how == "range":
        return encode_input(OdometerSample(seq, float(rng.uniform(151.0, 1e6)), 0.1), validate=False)
    if how == "non_finite":
        bad = float(rng.choice([np.nan, np.inf, -np.inf]))
        return encode_input(ImuSample(seq, bad, 0.0, -9.81, 0.0, 0.0, 0.0), validate=False)
    if how == "form":  # an ODOMETER header announcing 5 doubles: no table row allows it
        return struct.pack("<BHBB5d", 2, seq, 0, 5, *rng.uniform(0.0, 1.0, 5))
    if how == "length":  # a valid header, one byte missing
        return encode_input(OdometerSample(seq, 1.0, 0.1))[:-1]
    sensor = int(rng.choice([0, 4, 5, 6, 7, 11, 255]))  # "type": an unknown SENSOR_TYPE
    return struct.pack("<BHBB2d", sensor, seq, 0, 2, 1.0, 0.1)


def garbage(rng: np.random.Generator, max_bytes: int) -> bytes:
    """Random bytes, 0..max_bytes long, that never form a valid INPUT datagram.

    The first byte is forced to an unknown SENSOR_TYPE (valid types are 1, 2, 3, 8, 9, 10), so the
    count of garbage the proxy sent equals what a correct listener must reject.
    """
    n = int(rng.integers(0, max_bytes + 1))
    data = bytearray(rng.integers(0, 256, n, dtype=np.uint8).tobytes())
    if n:
        data[0] = int(rng.choice([0, 4, 5, 6, 7, 11, 12, 128, 255]))
    return bytes(data)


_BAD_TYPES = np.array([0, 4, 5, 6, 7, 11, 12, 128, 255], dtype=np.uint8)


def garbage_batch(rng: np.random.Generator, count: int, max_bytes: int) -> list[bytes]:
    """``count`` garbage datagrams as :func:`garbage` makes them, drawn in three vectorised calls
    (a flood of 50,000 per second is then cheap to produce)."""
    lengths = rng.integers(0, max_bytes + 1, count)
    block = rng.integers(0, 256, int(lengths.sum()), dtype=np.uint8)
    starts = np.concatenate(([0], np.cumsum(lengths)[:-1])).astype(np.int64)
    firsts = _BAD_TYPES[rng.integers(0, _BAD_TYPES.size, count)]
    nonempty = lengths > 0
    block[starts[nonempty]] = firsts[nonempty]
    raw = block.tobytes()
    return [raw[s : s + n] for s, n in zip(starts.tolist(), lengths.tolist(), strict=True)]


def flip_bits(rng: np.random.Generator, data: bytes, n_bits: int) -> bytes:
    """``data`` with ``n_bits`` distinct random bits inverted (all of them if it has fewer)."""
    total = 8 * len(data)
    if total == 0:
        return data
    picks = rng.choice(total, size=min(n_bits, total), replace=False)
    out = bytearray(data)
    for bit in picks:
        out[int(bit) // 8] ^= 1 << (int(bit) % 8)
    return bytes(out)


def truncate(rng: np.random.Generator, data: bytes) -> bytes:
    """``data`` cut to a random length in 0..len-1 (an empty datagram stays empty)."""
    if not data:
        return data
    return data[: int(rng.integers(0, len(data)))]


_MAGIC = 0xA5  #: first byte of an authenticated datagram (listener.auth)
_AUTH_HEADER = 6  #: MAGIC, KEY_ID, epoch counter (4 bytes)


def inner_payload(data: bytes) -> bytes | None:
    """The INPUT datagram inside ``data``: ``data`` itself, or, for an authenticated datagram, the
    payload after its header (tag included: only its first 3 bytes are read); None when too short."""
    if data[:1] == bytes([_MAGIC]):
        inner = data[_AUTH_HEADER:]
        return inner if len(inner) >= 3 else None
    return data if len(data) >= 3 else None


def with_seq(payload: bytes, seq: int) -> bytes:
    """An INPUT datagram with its SEQ (bytes 1..2) set to ``seq`` (mod 2^16)."""
    return payload[:1] + struct.pack("<H", seq & 0xFFFF) + payload[3:]


def module_signer(master_key: bytes, tag_bytes: int = 16):
    """``sign(payload, template)``: ``payload`` wrapped as the authenticated ``template`` was, with the
    key of the template's KEY_ID and its epoch counter (an attacker holding that module's key: a
    cross-key forgery the sender table, not the MAC, must refuse)."""
    from listener.auth import HEADER, wrap
    from listener.auth_link import input_key

    def sign(payload: bytes, template: bytes) -> bytes:
        _, kid, epoch = HEADER.unpack_from(template)
        return wrap(payload, input_key(master_key, kid), epoch, key_id=kid, tag_bytes=tag_bytes)

    return sign
