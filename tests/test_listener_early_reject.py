"""The batched reader's early checks give exactly the reasons the full path gives (codec and auth)."""

from __future__ import annotations

import struct

import numpy as np

from listener.auth import AuthError, wrap
from listener.auth_link import LinkAuth
from listener.codec import INPUT_FORMS, DecodeError, ImuSample, decode_input, encode_input
from listener.service import RECV_BUFFER_BYTES, early_reject_reason
from tools.faults.forge import forge_invalid, garbage_batch


def _codec_reason(data: bytes) -> str | None:
    try:
        decode_input(data)
    except DecodeError as exc:
        return str(exc.reason)
    return None


def _candidates(rng: np.random.Generator) -> list[bytes]:
    out = garbage_batch(rng, 3000, 64)  # the flood the campaign sends
    out += [forge_invalid(rng) for _ in range(500)]  # each breaks one codec rule
    valid = encode_input(ImuSample(7, 0.1, 0.0, 9.81, 0.0, 0.0, 0.01, epoch=12.5))
    out.append(valid)
    for t, n_int, n_double in INPUT_FORMS:  # every form: right length, one byte short, one too long
        body = bytes(rng.integers(0, 256, 4 * n_int + 8 * n_double, dtype=np.uint8))
        dgram = struct.pack("<BHBB", int(t), 1, n_int, n_double) + body
        out += [dgram, dgram[:-1], dgram + b"\x00"]
    for _ in range(2000):  # random headers: known and unknown types, any N_INT / N_DOUBLE, any length
        t = int(rng.choice([1, 2, 3, 8, 9, 10, 0, 4, 200]))
        n_int, n_double = int(rng.integers(0, 8)), int(rng.integers(0, 8))
        n = int(rng.integers(0, 80))
        head = struct.pack("<BHBB", t, 0, n_int, n_double)
        out.append((head + bytes(rng.integers(0, 256, 80, dtype=np.uint8)))[:n])
    out.append(b"\x01" * 3065)  # N_INT = N_DOUBLE = 1 type IMU, far too long
    return out


def test_early_reason_equals_the_codec_reason_on_header_failures():
    rng = np.random.default_rng(20261122)
    cases = _candidates(rng)
    early_rejected = 0
    for data in cases:
        buf = bytearray(RECV_BUFFER_BYTES)
        buf[: len(data)] = data
        early = early_reject_reason(buf, len(data))
        full = _codec_reason(data)
        if early is None:
            # only the header passed: the full decode may still reject a value, never the header
            assert full not in ("short", "type", "length", "form"), (data.hex(), full)
        else:
            early_rejected += 1
            assert early == full, (data.hex(), early, full)
    assert early_rejected > 3000  # the flood and the broken forms were all caught early
    assert early_reject_reason(bytearray(b"\x01\x00"), 2) == "short"
    assert early_reject_reason(bytearray(8), 0) == "short"


def test_auth_precheck_counts_like_unwrap_and_never_rejects_a_wrapped_datagram():
    master = bytes(range(32))
    early_side, full_side = LinkAuth(master), LinkAuth(master)
    rng = np.random.default_rng(5)
    payload = encode_input(ImuSample(3, 0.1, 0.0, 9.81, 0.0, 0.0, 0.01, epoch=1.0))
    good = wrap(payload, early_side.input_key(2), 0, key_id=2)
    cases = garbage_batch(rng, 2000, 64) + [good, good[:-1], b"\xa5" * 30, b"\xa5\x02", b""]
    for data in cases:
        buf = bytearray(RECV_BUFFER_BYTES)
        buf[: len(data)] = data
        early = early_side.precheck_input(buf, len(data))
        try:
            full_side.open_input(data, ("127.0.0.1", 1))
            full = None
        except AuthError as exc:
            full = str(exc.reason)
        if early is not None:
            assert early == full
        else:
            assert full not in ("auth_short", "auth_magic")
    assert early_side.precheck_input(bytearray(good), len(good)) is None
    # both sides counted the early reasons the same way
    for reason in ("auth_short", "auth_magic"):
        assert early_side.input_state.rejected.get(reason, 0) == full_side.input_state.rejected.get(reason, 0)
        assert full_side.input_state.rejected.get(reason, 0) > 0


def test_every_allowed_form_passes_the_early_check():
    for t, ni, nd in INPUT_FORMS:
        n = 5 + 4 * ni + 8 * nd
        buf = bytearray(struct.pack("<BHBB", int(t), 0, ni, nd) + bytes(n - 5))
        assert early_reject_reason(buf, n) is None, (t, ni, nd)
    assert len(INPUT_FORMS) >= 6
