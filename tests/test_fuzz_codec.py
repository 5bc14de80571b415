"""Fuzzing the wire codec with hypothesis: arbitrary and mutated datagrams never escape as anything
but a DecodeError, and whatever decodes re-encodes to the very same bytes (the format is canonical).

Short in CI. The documented long run (docs/reliability.md):
    SFA_FUZZ_EXAMPLES=200000 pytest -q tests/test_fuzz_codec.py tests/test_fuzz_pipeline.py
"""

from __future__ import annotations

import os

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from listener.codec import (
    DecodeError,
    GpsFix,
    GroundTruth,
    ImuSample,
    OdometerSample,
    Stop,
    Strobe,
    decode_ack,
    decode_header,
    decode_input,
    decode_output_any,
    encode_ack,
    encode_input,
    encode_output,
    encode_output_extended,
)

EXAMPLES = int(os.environ.get("SFA_FUZZ_EXAMPLES", "300"))
FUZZ = settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.too_slow])

seqs = st.integers(0, 65535)
acc = st.floats(-150.0, 150.0)
rate = st.floats(-30.0, 30.0)
epochs = st.none() | st.floats(0.0, 1e10)

valid_messages = st.one_of(
    st.builds(ImuSample, seqs, acc, acc, acc, rate, rate, rate, epochs),
    st.builds(OdometerSample, seqs, st.floats(-150.0, 150.0), st.floats(1e-6, 50.0), epochs),
    # an epoch needs sigma_h (the bracketed GPS fields come in order): give one when an epoch is drawn
    st.builds(lambda s, la, lo, al, q, sh, ep: GpsFix(s, la, lo, al, *q,
                                                      1.0 if sh is None and ep is not None else sh, ep),
              seqs, st.floats(-90.0, 90.0), st.floats(-180.0, 180.0), st.floats(-500.0, 9000.0),
              st.none().map(lambda _: (None, None)) | st.tuples(st.integers(0, 8), st.integers(0, 255)),
              st.none() | st.floats(1e-3, 1e5), epochs),
    st.builds(GroundTruth, seqs, st.floats(-150.0, 150.0), st.floats(-150.0, 150.0), st.floats(-150.0, 150.0),
              st.floats(-1000.0, 1e8), st.none() | st.integers(0, 2**31 - 1), epochs),
    st.builds(Strobe, seqs, st.floats(0.0, 1e10)),
    st.builds(Stop, seqs),
)


def _decode_or_reject(data: bytes):
    try:
        return decode_input(data)
    except DecodeError as exc:
        assert exc.reason and exc.detail
        return None


@FUZZ
@given(st.binary(max_size=80))
def test_arbitrary_bytes_decode_or_reject_and_round_trip(data):
    msg = _decode_or_reject(data)
    if msg is not None:
        assert encode_input(msg) == data
        assert decode_header(data)[1] == msg.seq


@FUZZ
@given(valid_messages)
def test_valid_messages_round_trip(msg):
    data = encode_input(msg)
    assert decode_input(data) == msg


@FUZZ
@given(valid_messages, st.data())
def test_mutated_datagrams_never_escape(msg, data):
    raw = bytearray(encode_input(msg))
    how = data.draw(st.sampled_from(["flip", "cut", "extend", "splice"]))
    if how == "flip":
        for bit in data.draw(st.lists(st.integers(0, 8 * len(raw) - 1), min_size=1, max_size=8)):
            raw[bit // 8] ^= 1 << (bit % 8)
    elif how == "cut":
        raw = raw[: data.draw(st.integers(0, len(raw) - 1))]
    elif how == "extend":
        raw += data.draw(st.binary(min_size=1, max_size=16))
    else:
        at = data.draw(st.integers(0, len(raw)))
        raw[at:at] = data.draw(st.binary(min_size=1, max_size=8))
    out = _decode_or_reject(bytes(raw))
    if out is not None:
        assert encode_input(out) == bytes(raw)


@FUZZ
@given(st.binary(max_size=60))
def test_output_and_ack_decoders_only_raise_decode_error(data):
    for decoder in (decode_output_any, decode_ack):
        try:
            value = decoder(data)
        except DecodeError:
            continue
        if decoder is decode_ack:
            assert encode_ack(value) == data
        elif len(data) == 18:
            assert encode_output(value) == data
        else:
            assert encode_output_extended(value) == data
