"""Authenticated links (listener.auth): forged, replayed, bit-flipped and truncated datagrams all fail."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from listener.auth import (
    HEADER_BYTES,
    AuthConfig,
    AuthError,
    AuthReason,
    AuthState,
    EpochCounter,
    ReplayWindow,
    derive_link_key,
    output_seq,
    unwrap,
    wrap,
)
from listener.codec import DecodeError, ImuSample, OutputMessage, decode_input, encode_input, encode_output
from listener.errors import ConfigError, ListenerError

KEY = derive_link_key(b"0123456789abcdef-master", "modules->listener")
OTHER = derive_link_key(b"0123456789abcdef-master", "listener->obcu")
SENDER = ("127.0.0.1", 47001)


def imu(seq: int) -> bytes:
    return encode_input(ImuSample(seq, 0.1, 0.0, -9.81, 0.0, 0.0, 0.01))


def test_round_trip_and_layout():
    payload = imu(7)
    wrapped = wrap(payload, KEY, 3)
    assert len(wrapped) == HEADER_BYTES + len(payload) + 16
    assert wrapped[0] == 0xA5 and wrapped[HEADER_BYTES:-16] == payload
    state = AuthState()
    assert unwrap(wrapped, KEY, state, SENDER) == payload
    assert state.accepted == 1 and state.rejected == {}


def test_per_link_keys_differ_and_wrong_key_fails():
    assert KEY != OTHER and len(KEY) == 32
    state = AuthState()
    with pytest.raises(AuthError) as info:
        unwrap(wrap(imu(1), OTHER, 0), KEY, state, SENDER)
    assert info.value.reason is AuthReason.TAG
    assert isinstance(info.value, ListenerError)


def test_wrapped_datagram_is_rejected_by_a_receiver_without_the_extension():
    with pytest.raises(DecodeError):
        decode_input(wrap(imu(1), KEY, 0))


def test_replay_is_rejected_and_state_unchanged_by_rejections():
    state = AuthState()
    first = wrap(imu(10), KEY, 0)
    unwrap(first, KEY, state, SENDER)
    with pytest.raises(AuthError) as info:
        unwrap(first, KEY, state, SENDER)
    assert info.value.reason is AuthReason.REPLAY
    # a forged datagram with a fresh number does not consume that number
    forged = bytearray(wrap(imu(11), KEY, 0))
    forged[-1] ^= 0x01
    with pytest.raises(AuthError):
        unwrap(bytes(forged), KEY, state, SENDER)
    assert unwrap(wrap(imu(11), KEY, 0), KEY, state, SENDER) == imu(11)
    assert state.rejected == {"auth_replay": 1, "auth_tag": 1}


def test_replays_across_a_sequence_wrap_fail():
    """Datagrams of epoch 0 replayed after the SEQ wrapped (epoch 1) are rejected, same SEQ or not."""
    counter = EpochCounter()
    state = AuthState(AuthConfig(window=4096))
    sent = {}
    seqs = list(range(65000, 65536)) + list(range(0, 600))
    for seq in seqs:
        dgram = wrap(imu(seq), KEY, counter.epoch_for(seq))
        sent.setdefault(seq, []).append(dgram)
        assert unwrap(dgram, KEY, state, SENDER) == imu(seq)
    assert counter.epoch == 1
    old = sent[65100][0]
    with pytest.raises(AuthError) as info:
        unwrap(old, KEY, state, SENDER)
    assert info.value.reason in (AuthReason.REPLAY, AuthReason.OLD)
    # a datagram whose SEQ (100) reappears in the new epoch: the epoch-1 copy was accepted once, so
    # its replay fails; an epoch-0 datagram carrying SEQ 100 would need a tag we cannot make
    with pytest.raises(AuthError):
        unwrap(sent[100][0], KEY, state, SENDER)


def test_window_rejects_too_old_and_accepts_late_in_window():
    w = ReplayWindow(8)
    for ext in (100, 98, 101):
        assert w.check(ext) is None
        w.accept(ext)
    assert w.check(99) is None  # late but inside the window, never seen
    assert w.check(98) is AuthReason.REPLAY
    assert w.check(93) is AuthReason.OLD
    w.accept(200)
    assert w.check(101) is AuthReason.OLD


def test_output_and_ack_direction():
    out = encode_output(OutputMessage(5, 1.0e9, 1234.5))
    state = AuthState()
    assert unwrap(wrap(out, OTHER, 0), OTHER, state, "listener", seq_of=output_seq) == out
    with pytest.raises(AuthError):
        unwrap(wrap(out, OTHER, 0), OTHER, state, "listener", seq_of=output_seq)


def test_key_rotation_by_key_id():
    keys = {0: KEY, 1: OTHER}
    state = AuthState()
    assert unwrap(wrap(imu(1), OTHER, 0, key_id=1), keys, state, SENDER) == imu(1)
    with pytest.raises(AuthError) as info:
        unwrap(wrap(imu(2), OTHER, 0, key_id=2), keys, state, SENDER)
    assert info.value.reason is AuthReason.KEY_ID


@pytest.mark.parametrize(
    "kwargs", [{"key": b"short"}, {"epoch_counter": -1}, {"epoch_counter": 2**32}, {"tag_bytes": 8},
               {"tag_bytes": 33}, {"key_id": 256}]
)
def test_bad_parameters_are_config_errors(kwargs):
    args = {"payload": imu(1), "key": KEY, "epoch_counter": 0, **kwargs}
    with pytest.raises(ConfigError):
        wrap(**args)


def test_every_single_bit_flip_is_rejected():
    """All 8*n single-bit corruptions of one datagram: none accepted (exhaustive, not sampled)."""
    dgram = wrap(imu(42), KEY, 9)
    accepted = 0
    for bit in range(8 * len(dgram)):
        bad = bytearray(dgram)
        bad[bit // 8] ^= 1 << (bit % 8)
        try:
            unwrap(bytes(bad), KEY, AuthState(), SENDER)
            accepted += 1
        except AuthError:
            pass
    assert accepted == 0


def test_forged_stream_is_fully_rejected():
    """10,000 random forgeries (random header, payload and tag) are all rejected."""
    rng = np.random.default_rng(5)
    state = AuthState()
    for _ in range(10_000):
        n = int(rng.integers(0, 90))
        data = bytearray(rng.integers(0, 256, n, dtype=np.uint8).tobytes())
        if n and rng.random() < 0.5:
            data[0] = 0xA5  # looks like a wrapped datagram
        with pytest.raises(AuthError):
            unwrap(bytes(data), KEY, state, SENDER)
    assert state.accepted == 0 and sum(state.rejected.values()) == 10_000


@settings(max_examples=200, deadline=None)
@given(payload=st.binary(min_size=3, max_size=80), epoch=st.integers(0, 2**32 - 1),
       tag_bytes=st.integers(16, 32), cut=st.integers(1, 200))
def test_truncated_wrapped_datagrams_are_rejected(payload, epoch, tag_bytes, cut):
    dgram = wrap(payload, KEY, epoch, tag_bytes=tag_bytes)
    state = AuthState(AuthConfig(tag_bytes=tag_bytes))
    with pytest.raises(AuthError):
        unwrap(dgram[: max(0, len(dgram) - cut)], KEY, state, SENDER)
    assert unwrap(dgram, KEY, state, SENDER) == payload
