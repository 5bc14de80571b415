"""Tests of listener.serial: RFC 1982 arithmetic on 16-bit sequence numbers."""

from hypothesis import given
from hypothesis import strategies as st

from listener.serial import SERIAL_HALF, serial_add, serial_diff, serial_gt, serial_lt, serial_unwrap

SEQ = st.integers(0, 0xFFFF)


def test_rfc1982_examples_on_16_bits():
    assert serial_diff(0, 65535) == 1  # wrap: 0 follows 65535
    assert serial_diff(65535, 0) == -1
    assert serial_gt(0, 65535) and serial_lt(65535, 0)
    assert serial_diff(100, 50) == 50 and serial_diff(50, 100) == -50
    assert serial_diff(32767, 0) == 32767  # the largest "ahead"
    assert serial_diff(32768, 0) == -32768  # undefined in RFC 1982: resolved as "behind"
    assert serial_diff(0, 32768) == -32768
    assert not serial_gt(32768, 0) and not serial_gt(0, 32768)
    assert serial_add(65535, 1) == 0 and serial_add(0, -1) == 65535 and serial_add(65000, 1000) == 464


@given(SEQ, st.integers(-SERIAL_HALF + 1, SERIAL_HALF - 1))
def test_diff_inverts_add(a, n):
    assert serial_diff(serial_add(a, n), a) == n
    assert serial_gt(serial_add(a, n), a) == (n > 0)
    assert serial_lt(serial_add(a, n), a) == (n < 0)


@given(SEQ, SEQ)
def test_diff_is_antisymmetric_except_half_way(a, b):
    d = serial_diff(a, b)
    assert -SERIAL_HALF <= d < SERIAL_HALF
    if d != -SERIAL_HALF:
        assert serial_diff(b, a) == -d
    assert (serial_lt(a, b), serial_gt(a, b)).count(True) <= 1


@given(st.integers(0, 2**40), st.integers(-SERIAL_HALF + 1, SERIAL_HALF - 1))
def test_unwrap_recovers_the_unbounded_number(reference, offset):
    target = reference + offset
    assert serial_unwrap(target & 0xFFFF, reference) == target


def test_unwrap_across_several_wraps_is_monotonic():
    ext = 65530
    seqs = [(65530 + i) & 0xFFFF for i in range(3 * 65536)]
    for i, seq in enumerate(seqs[1:], start=1):
        ext = serial_unwrap(seq, ext)
        assert ext == 65530 + i
