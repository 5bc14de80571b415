"""Compiled INPUT_PROTOCOL decoding of many datagrams at once, driven by listener.codec's own tables.

The allowed forms (``INPUT_FORMS``), their field order (``input_layout``) and every field's range
(``FIELD_RANGES``) are read from :mod:`listener.codec` when this module is imported, so the compiled
check cannot drift from the codec: exact length for the form, then every field inside its range
(NaN and infinities fail the comparison, as in the codec's chained comparisons). An open lower bound
``lo < x`` is checked as the closed ``nextafter(lo, +inf) <= x``, the same set of doubles (a branch-free
check: one table lookup and two comparisons per field). A datagram the
compiled pass rejects is handed to ``listener.codec.decode_input`` for its exact reason, so the
rejection counters are those of the listener by construction; the compiled pass only has to never
accept what the codec rejects (checked by tests/test_fast_replay.py with hypothesis).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from listener.codec import FIELD_RANGES, INPUT_FORMS, input_layout
from tools.fast_ingest import MAX_FIELDS, decode_many  # compiled with the fast replay's single pass

_TABLE = 16 * 8 * 8  #: index = type * 64 + n_int * 8 + n_double (type < 16, n_int < 8, n_double < 8)


def _build_tables():
    size = np.zeros(_TABLE, dtype=np.int64)  # 0: no such form
    lo = np.zeros((_TABLE, MAX_FIELDS))  # inclusive lower bound
    hi = np.zeros((_TABLE, MAX_FIELDS))
    for stype, n_int, n_double in INPUT_FORMS:
        idx = int(stype) * 64 + n_int * 8 + n_double
        size[idx] = 5 + 4 * n_int + 8 * n_double
        for j, name in enumerate(input_layout(stype, n_int, n_double)):
            r = FIELD_RANGES[name]
            lo[idx, j] = _inclusive(float(r.lo)) if r.lo_open else r.lo
            hi[idx, j] = r.hi
    return size, lo, hi


def _inclusive(lo: float) -> float:
    """The smallest double x with lo < x (no double is above +inf: NaN, which no x reaches)."""
    return math.nan if lo == math.inf else math.nextafter(lo, math.inf)


FORM_SIZE, FIELD_LO, FIELD_HI = _build_tables()  #: FIELD_LO: inclusive (open bounds moved up one double)


@dataclass(frozen=True)
class DecodedBatch:
    """Per datagram: accepted by the compiled pass, header fields and payload values in wire order."""

    ok: np.ndarray  #: bool
    stype: np.ndarray  #: SENSOR_TYPE byte (int64; -1 when shorter than the header)
    seq: np.ndarray  #: SEQ (int64)
    n_int: np.ndarray  #: N_INT (int64)
    n_double: np.ndarray  #: N_DOUBLE (int64)
    values: np.ndarray  #: (n, MAX_FIELDS) float64: ints then doubles, wire order; NaN beyond the form


def decode_batch(data: np.ndarray, offset: np.ndarray, length: np.ndarray) -> DecodedBatch:
    """Run :func:`decode_many` over the datagrams of a scanned capture (or any byte buffer)."""
    n = offset.shape[0]
    ok = np.zeros(n, dtype=np.bool_)
    stype = np.zeros(n, dtype=np.int64)
    seq = np.zeros(n, dtype=np.int64)
    ni = np.zeros(n, dtype=np.int64)
    nd = np.zeros(n, dtype=np.int64)
    values = np.empty((n, MAX_FIELDS))
    decode_many(data, offset, length, FORM_SIZE, FIELD_LO, FIELD_HI, ok, stype, seq, ni, nd, values)
    return DecodedBatch(ok, stype, seq, ni, nd, values)


def decode_bytes(payloads: list[bytes]) -> DecodedBatch:
    """Convenience for tests and small inputs: decode a list of payloads."""
    lengths = np.array([len(p) for p in payloads], dtype=np.int64)
    offsets = np.zeros(len(payloads), dtype=np.int64)
    if len(payloads) > 1:
        offsets[1:] = np.cumsum(lengths)[:-1]
    data = np.frombuffer(b"".join(payloads) or b"\0", dtype=np.uint8)
    return decode_batch(data, offsets, lengths)
