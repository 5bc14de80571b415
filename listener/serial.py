"""RFC 1982 serial-number arithmetic on the 16-bit sequence numbers of the wire protocol.

Two serial numbers ``a`` and ``b`` are compared through their signed distance ``a - b`` folded into
``[-32768, 32767]``. RFC 1982 leaves the comparison undefined when the two are exactly 2**15 apart;
this module resolves that case deterministically as "``a`` is behind ``b``" (distance -32768), which
the sequence buffer then treats as a restart candidate, never as fresh data.
"""

SERIAL_BITS = 16
SERIAL_MOD = 1 << SERIAL_BITS  #: 65536
SERIAL_MASK = SERIAL_MOD - 1  #: 0xFFFF
SERIAL_HALF = SERIAL_MOD >> 1  #: 32768


def serial_add(seq: int, n: int) -> int:
    """``seq + n`` modulo 2**16 (RFC 1982 addition; ``n`` may be negative here for convenience)."""
    return (seq + n) & SERIAL_MASK


def serial_diff(a: int, b: int) -> int:
    """Signed serial distance ``a - b`` in ``[-32768, 32767]``: > 0 means ``a`` is newer than ``b``."""
    return ((a - b + SERIAL_HALF) & SERIAL_MASK) - SERIAL_HALF


def serial_lt(a: int, b: int) -> bool:
    """``a`` precedes ``b`` (RFC 1982 ``s1 < s2``; the undefined half-way case counts as "precedes")."""
    return serial_diff(a, b) < 0


def serial_gt(a: int, b: int) -> bool:
    """``a`` follows ``b`` (RFC 1982 ``s1 > s2``)."""
    return serial_diff(a, b) > 0


def serial_unwrap(seq: int, reference_ext: int) -> int:
    """Extend 16-bit ``seq`` to the unbounded integer nearest ``reference_ext`` with the same low 16 bits.

    ``reference_ext`` is an already-unwrapped sequence number; the result differs from it by
    ``serial_diff(seq, reference_ext & 0xFFFF)``, so a stream crossing 65535 -> 0 keeps increasing.
    """
    return reference_ext + serial_diff(seq, reference_ext & SERIAL_MASK)
