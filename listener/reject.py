"""The closed set of reasons a datagram (or a message to encode) is rejected by the wire codec.

A ``StrEnum``: each value is a short, stable label that callers use as a metric key
(``rejected[err.reason] += 1``). The set is closed: adding a member is a protocol-documentation change
(docs/protocol.md, "Reject reasons").
"""

from enum import StrEnum


class RejectReason(StrEnum):
    NOT_BYTES = "not_bytes"  #: the object is not bytes-like (bytes, bytearray, memoryview)
    SHORT = "short"  #: INPUT datagram shorter than its 5-byte header
    TYPE = "type"  #: unknown SENSOR_TYPE
    LENGTH = "length"  #: length differs from 5 + 4*N_INT + 8*N_DOUBLE (or from the fixed OUTPUT/ACK size)
    FORM = "form"  #: (N_INT, N_DOUBLE) is not a form the type allows, or optional fields given out of order
    NON_FINITE = "non_finite"  #: a float64 field is NaN or infinite
    RANGE = "range"  #: a field is finite but outside its physical or wire range (see listener.limits)
