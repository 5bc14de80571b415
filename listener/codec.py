"""Sans-I/O codec of the SFA wire protocol: INPUT_PROTOCOL, OUTPUT_PROTOCOL (and its extension), ACK.

Pure functions over ``bytes``; no sockets, no clocks. Every rejection raises one exception type per
direction, carrying a closed :class:`RejectReason` and a human-readable detail:

* :class:`DecodeError` -- the peer broke the protocol (a received datagram);
* :class:`EncodeError` -- we broke it (a message we were asked to send).

Byte order is little-endian, as the protocol specifies; every function takes ``byteorder=">"`` for the
optional big-endian variant (off by default). See docs/protocol.md for the byte-level description.

Performance: each allowed (type, N_INT, N_DOUBLE) form has one precompiled ``struct.Struct`` covering
the whole datagram (header included) and one generated validate-and-build function, found by a single
dict lookup on the header bytes. The range checks are chained comparisons, which are False for NaN
and for infinities, so finiteness costs nothing on the accepting path; only a rejected datagram pays
for the field-by-field diagnosis.
"""

from __future__ import annotations

import math
import numbers
import struct
from collections.abc import Callable
from dataclasses import dataclass, fields
from enum import IntEnum
from typing import Final

from listener import limits as L
from listener.errors import ConfigError, DecodeError, EncodeError
from listener.reject import RejectReason

__all__ = [
    "SensorType",
    "RejectReason",
    "DecodeError",
    "EncodeError",
    "ImuSample",
    "OdometerSample",
    "GpsFix",
    "GroundTruth",
    "Strobe",
    "Stop",
    "InputMessage",
    "OutputMessage",
    "OutputExtended",
    "HEADER_SIZE",
    "OUTPUT_SIZE",
    "OUTPUT_EXTENDED_SIZE",
    "ACK_SIZE",
    "BYTEORDERS",
    "INPUT_FORMS",
    "FieldRange",
    "FIELD_RANGES",
    "input_layout",
    "sensor_type_of",
    "encode_input",
    "decode_input",
    "decode_header",
    "encode_output",
    "decode_output",
    "encode_output_extended",
    "decode_output_extended",
    "decode_output_any",
    "encode_ack",
    "decode_ack",
]


class SensorType(IntEnum):
    """SENSOR_TYPE byte of INPUT_PROTOCOL."""

    IMU = 1
    ODOMETER = 2
    GPS = 3
    GROUND_TRUTH = 8
    STROBE = 9
    STOP = 10


# --------------------------------------------------------------------------------------------------
# Messages. Field names follow the wire protocol; units in the docstrings (SI, degrees for lat/lon).


@dataclass(frozen=True, slots=True)
class ImuSample:
    """IMU (1): specific force ax, ay, az [m/s^2] and rates gx, gy, gz [rad/s] in the FRD body frame."""

    seq: int
    ax: float
    ay: float
    az: float
    gx: float
    gy: float
    gz: float
    epoch: float | None = None  #: sampling time [s, sensor-set timebase]; None: dated by arrival


@dataclass(frozen=True, slots=True)
class OdometerSample:
    """ODOMETER (2): signed speed [m/s, > 0 forward] and its 1-sigma [m/s, > 0]."""

    seq: int
    speed: float
    sigma: float
    epoch: float | None = None  #: sampling time [s]


@dataclass(frozen=True, slots=True)
class GpsFix:
    """GPS (3): lat, lon [deg WGS84], alt [m above MSL]; optional NMEA fix quality, satellites, sigma_h."""

    seq: int
    lat: float
    lon: float
    alt: float
    fix_quality: int | None = None  #: NMEA GGA 0..8 (with num_sv: both or neither)
    num_sv: int | None = None  #: satellites used, 0..255
    sigma_h: float | None = None  #: horizontal 1-sigma per axis [m, > 0]
    epoch: float | None = None  #: sampling time [s]; requires sigma_h (bracketed fields come in order)


@dataclass(frozen=True, slots=True)
class GroundTruth:
    """GROUND TRUTH (8): body velocity vx, vy, vz [m/s] and arc length [m]; (re)initialises the filter."""

    seq: int
    vx: float
    vy: float
    vz: float
    arc_length: float
    line_id: int | None = None  #: track database line; None: the database's default line
    epoch: float | None = None  #: time [s]


@dataclass(frozen=True, slots=True)
class Strobe:
    """STROBE (9): the sensor-set time [s] at which it was sent."""

    seq: int
    timestamp: float


@dataclass(frozen=True, slots=True)
class Stop:
    """STOP (10): asks the listener to flush and exit."""

    seq: int


InputMessage = ImuSample | OdometerSample | GpsFix | GroundTruth | Strobe | Stop


@dataclass(frozen=True, slots=True)
class OutputMessage:
    """OUTPUT_PROTOCOL (18 bytes): estimate number ``seq``, its epoch [s] and arc length [m]."""

    seq: int
    epoch: float
    arc_length: float


@dataclass(frozen=True, slots=True)
class OutputExtended:
    """Extended OUTPUT (47 bytes, project extension, off by default): the 18 standard bytes followed by
    speed [m/s], confidence interval low/high [m] around arc_length, filter status code, line id."""

    seq: int
    epoch: float
    arc_length: float
    speed: float
    interval_low: float
    interval_high: float
    status: int  #: filter status code, 0..255 (the filter's FilterStatus value)
    line_id: int | None = None  #: track line of the estimate; None is sent as -1


# --------------------------------------------------------------------------------------------------
# Ranges: one table drives the accepting fast path, the rejection diagnosis and docs/protocol.md.


@dataclass(frozen=True, slots=True)
class FieldRange:
    """Allowed values of one wire field: ``lo <= x <= hi`` (``lo < x`` when ``lo_open``)."""

    lo: float
    hi: float
    unit: str
    lo_open: bool = False
    integer: bool = False

    def describe(self) -> str:
        left = "(" if self.lo_open else "["
        fmt = "d" if self.integer else ".10g"
        return f"{left}{self.lo:{fmt}}, {self.hi:{fmt}}] {self.unit}".rstrip()


_ACC = FieldRange(-L.ACCEL_MAX_MPS2, L.ACCEL_MAX_MPS2, "m/s^2")
_RATE = FieldRange(-L.RATE_MAX_RADPS, L.RATE_MAX_RADPS, "rad/s")
_VEL = FieldRange(-L.SPEED_MAX_MPS, L.SPEED_MAX_MPS, "m/s")
_EPOCH = FieldRange(L.EPOCH_MIN_S, L.EPOCH_MAX_S, "s")

FIELD_RANGES: Final[dict[str, FieldRange]] = {
    "ax": _ACC, "ay": _ACC, "az": _ACC,
    "gx": _RATE, "gy": _RATE, "gz": _RATE,
    "speed": _VEL,
    "sigma": FieldRange(0.0, L.ODO_SIGMA_MAX_MPS, "m/s", lo_open=True),
    "lat": FieldRange(L.LAT_MIN_DEG, L.LAT_MAX_DEG, "deg"),
    "lon": FieldRange(L.LON_MIN_DEG, L.LON_MAX_DEG, "deg"),
    "alt": FieldRange(L.ALT_MIN_M, L.ALT_MAX_M, "m"),
    "sigma_h": FieldRange(0.0, L.GPS_SIGMA_H_MAX_M, "m", lo_open=True),
    "fix_quality": FieldRange(L.FIX_QUALITY_MIN, L.FIX_QUALITY_MAX, "", integer=True),
    "num_sv": FieldRange(L.NUM_SV_MIN, L.NUM_SV_MAX, "", integer=True),
    "vx": _VEL, "vy": _VEL, "vz": _VEL,
    "arc_length": FieldRange(L.ARC_LENGTH_MIN_M, L.ARC_LENGTH_MAX_M, "m"),
    "line_id": FieldRange(L.LINE_ID_MIN, L.LINE_ID_MAX, "", integer=True),
    "epoch": _EPOCH,
    "timestamp": _EPOCH,
}  # fmt: skip
"""Range of every INPUT_PROTOCOL payload field, by name (ints and doubles)."""


# --------------------------------------------------------------------------------------------------
# Forms: per type, the allowed int tuples and the double fields (base + optional suffixes in order).


@dataclass(frozen=True)
class _TypeLayout:
    cls: type
    int_options: tuple[tuple[str, ...], ...]
    doubles: tuple[str, ...]
    n_required_doubles: int


_LAYOUTS: Final[dict[SensorType, _TypeLayout]] = {
    SensorType.IMU: _TypeLayout(ImuSample, ((),), ("ax", "ay", "az", "gx", "gy", "gz", "epoch"), 6),
    SensorType.ODOMETER: _TypeLayout(OdometerSample, ((),), ("speed", "sigma", "epoch"), 2),
    SensorType.GPS: _TypeLayout(
        GpsFix, ((), ("fix_quality", "num_sv")), ("lat", "lon", "alt", "sigma_h", "epoch"), 3
    ),
    SensorType.GROUND_TRUTH: _TypeLayout(
        GroundTruth, ((), ("line_id",)), ("vx", "vy", "vz", "arc_length", "epoch"), 4
    ),
    SensorType.STROBE: _TypeLayout(Strobe, ((),), ("timestamp",), 1),
    SensorType.STOP: _TypeLayout(Stop, ((),), (), 0),
}

HEADER_SIZE: Final = 5
OUTPUT_SIZE: Final = 18
OUTPUT_EXTENDED_SIZE: Final = 47
ACK_SIZE: Final = 2
BYTEORDERS: Final = ("<", ">")

_TYPE_BY_VALUE: Final[dict[int, SensorType]] = {int(t): t for t in SensorType}
_TYPE_BY_CLASS: Final[dict[type, SensorType]] = {lay.cls: t for t, lay in _LAYOUTS.items()}


def _forms_of(layout: _TypeLayout) -> list[tuple[tuple[str, ...], tuple[str, ...]]]:
    out = []
    for ints in layout.int_options:
        for nd in range(layout.n_required_doubles, len(layout.doubles) + 1):
            out.append((ints, layout.doubles[:nd]))
    return out


INPUT_FORMS: Final[tuple[tuple[SensorType, int, int], ...]] = tuple(
    (t, len(ints), len(dbls)) for t, lay in _LAYOUTS.items() for ints, dbls in _forms_of(lay)
)
"""Every allowed (SENSOR_TYPE, N_INT, N_DOUBLE) form, in protocol order."""


def input_layout(sensor_type: SensorType, n_int: int, n_double: int) -> tuple[str, ...]:
    """Payload field names in wire order (ints then doubles) of an allowed form; raises DecodeError(FORM)."""
    layout = _LAYOUTS.get(sensor_type)
    if layout is not None:
        for ints, dbls in _forms_of(layout):
            if len(ints) == n_int and len(dbls) == n_double:
                return ints + dbls
    raise DecodeError(RejectReason.FORM, f"no form ({sensor_type}, N_INT={n_int}, N_DOUBLE={n_double})")


def sensor_type_of(msg: InputMessage) -> SensorType:
    """The SENSOR_TYPE of an input message object; raises EncodeError(TYPE) for anything else."""
    t = _TYPE_BY_CLASS.get(type(msg))
    if t is None:
        raise EncodeError(RejectReason.TYPE, f"not an input message: {type(msg).__name__}")
    return t


# --------------------------------------------------------------------------------------------------
# Diagnosis (slow path, shared by decode and encode).


def _integer(x: object, invalid: int) -> int:
    """``x`` as a plain int if it is an integer (int, IntEnum, numpy integer; not bool), else ``invalid``."""
    if isinstance(x, bool) or not isinstance(x, numbers.Integral):
        return invalid
    return int(x)


def _check_int_types(names: tuple[str, ...], values: tuple, where: str) -> None:
    """Raise EncodeError(RANGE) for an int field holding a non-integer (float, bool, None, str)."""
    for name, x in zip(names, values, strict=True):
        if isinstance(x, bool) or not isinstance(x, numbers.Integral):
            raise EncodeError(RejectReason.RANGE, f"{where}: {name} must be an int, got {type(x).__name__}")


def _diagnose(names: tuple[str, ...], values: tuple, error: type, where: str) -> None:
    """Raise ``error`` naming the first field (wire order) that is non-finite or out of range."""
    for name, x in zip(names, values, strict=True):
        rng = FIELD_RANGES[name]
        if isinstance(x, bool) or not isinstance(x, numbers.Integral if rng.integer else numbers.Real):
            kind = "an int" if rng.integer else "a float"
            raise error(RejectReason.RANGE, f"{where}: {name} must be {kind}, got {type(x).__name__}")
        if not rng.integer:
            if not math.isfinite(x):
                raise error(RejectReason.NON_FINITE, f"{where}: {name}={x!r} is not finite")
        ok = (rng.lo < x if rng.lo_open else rng.lo <= x) and x <= rng.hi
        if not ok:
            raise error(RejectReason.RANGE, f"{where}: {name}={x!r} outside {rng.describe()}")


def _range_expr(name: str, ref: str) -> str:
    rng = FIELD_RANGES[name]
    op = "<" if rng.lo_open else "<="
    return f"{rng.lo!r} {op} {ref} <= {rng.hi!r}"


@dataclass(frozen=True, slots=True)
class _Form:
    sensor_type: SensorType
    n_int: int
    n_double: int
    names: tuple[str, ...]  # payload fields, wire order
    struct: struct.Struct  # whole datagram, header included
    size: int
    build: Callable[[bytes], InputMessage]  # unpack + validate + construct (length already checked)
    pack: Callable[[InputMessage, bool], bytes]  # validate (optionally) + pack


def _compile_form(t: SensorType, ints: tuple[str, ...], dbls: tuple[str, ...], byteorder: str) -> _Form:
    """Build the Struct and generate the validate-and-build / validate-and-pack functions of one form.

    Generated code (as dataclasses and namedtuple do) keeps the hot path to one chained comparison per
    field and one slot store per field, while the field table above stays the single source. The
    instance is filled through the slot descriptors, as the frozen dataclass ``__init__`` itself does
    through ``object.__setattr__``, but without its per-field attribute-name lookup (about 2x faster;
    the result compares, hashes and prints exactly like a constructor-built one, which the tests check).
    """
    layout = _LAYOUTS[t]
    names = ints + dbls
    st = struct.Struct(f"{byteorder}BHBB{len(ints)}i{len(dbls)}d")
    where = f"{t.name}({len(ints)},{len(dbls)})"
    cls_fields = [f.name for f in fields(layout.cls)]
    values = [f"x_{n}" for n in names]
    unpacked = ", ".join(["_t", "seq", "_ni", "_nd", *values])
    args = []
    for fname in cls_fields:
        if fname == "seq":
            args.append("seq")
        elif fname in names:
            args.append(f"x_{fname}")
        else:
            args.append("None")
    check = " and ".join(_range_expr(n, f"x_{n}") for n in names) or "True"
    # Encoding: the form must match exactly which optional fields are set.
    optional = ("fix_quality", "num_sv", "sigma_h", "epoch", "line_id")
    present = [f"m.{n} is not None" for n in names if n in optional]
    absent = [
        f"m.{fname} is None"
        for fname in cls_fields
        if fname not in names and fname != "seq"
    ]
    shape = " and ".join(present + absent) or "True"
    pack_args = ", ".join(f"m.{n}" for n in names)
    enc_check = " and ".join(_range_expr(n, f"m.{n}") for n in names) or "True"
    int_types = " and ".join(f"type(m.{n}) is int" for n in ints) or "True"
    int_args = ", ".join(f"m.{n}" for n in ints)
    src = f"""
def build(data):
    {unpacked} = UNPACK(data)
    if not ({check}):
        _diagnose(NAMES, ({", ".join(values)}{"," if names else ""}), DecodeError, WHERE)
    m = NEW(CLS)
    {"; ".join(f"SET_{fname}(m, {arg})" for fname, arg in zip(cls_fields, args, strict=True))}
    return m

def pack(m, validate):
    if not ({shape}):
        raise EncodeError(RejectReason.FORM, WHERE + ": optional fields do not match this form")
    seq = m.seq
    if type(seq) is not int:
        seq = _integer(seq, -1)  # an IntEnum or numpy integer is fine; a float, bool or None is not
    if not (0 <= seq <= 0xFFFF):
        raise EncodeError(RejectReason.RANGE, f"{{WHERE}}: seq={{m.seq!r}} outside [0, 65535]")
    if not ({int_types}):
        _check_int_types(INT_NAMES, ({int_args}{"," if ints else ""}), WHERE)
    if validate:
        try:
            ok = {enc_check}
        except TypeError:  # a str or None where a number belongs
            ok = False
        if not ok:
            _diagnose(NAMES, ({pack_args}{"," if names else ""}), EncodeError, WHERE)
    try:
        return ST.pack(TYPE, seq, NI, ND{", " if names else ""}{pack_args})
    except struct.error as exc:
        raise EncodeError(RejectReason.RANGE, f"{{WHERE}}: {{exc}}") from None
"""
    ns = {
        "CLS": layout.cls,
        "NAMES": names,
        "WHERE": where,
        "ST": st,
        "TYPE": int(t),
        "NI": len(ints),
        "ND": len(dbls),
        "_diagnose": _diagnose,
        "DecodeError": DecodeError,
        "EncodeError": EncodeError,
        "RejectReason": RejectReason,
        "struct": struct,
        "_integer": _integer,
        "_check_int_types": _check_int_types,
        "INT_NAMES": ints,
        "NEW": object.__new__,
        "UNPACK": st.unpack,
        **{f"SET_{fname}": getattr(layout.cls, fname).__set__ for fname in cls_fields},
    }
    exec(compile(src, f"<listener.codec form {where}>", "exec"), ns)  # noqa: S102 - generated from constants
    return _Form(t, len(ints), len(dbls), names, st, st.size, ns["build"], ns["pack"])


def _header_key(t: int, n_int: int, n_double: int) -> int:
    return (t << 16) | (n_int << 8) | n_double


@dataclass(frozen=True, slots=True)
class _Tables:
    by_key: dict[int, _Form]  # header key -> form
    by_shape: dict[tuple[type, int, int], _Form]  # (class, n_int, n_double) -> form


def _build_tables(byteorder: str) -> _Tables:
    by_key: dict[int, _Form] = {}
    by_shape: dict[tuple[type, int, int], _Form] = {}
    for t, lay in _LAYOUTS.items():
        for ints, dbls in _forms_of(lay):
            form = _compile_form(t, ints, dbls, byteorder)
            by_key[_header_key(int(t), len(ints), len(dbls))] = form
            by_shape[(lay.cls, len(ints), len(dbls))] = form
    return _Tables(by_key, by_shape)


_TABLES: Final[dict[str, _Tables]] = {bo: _build_tables(bo) for bo in BYTEORDERS}
_DECODERS: Final[dict[str, dict[int, tuple[int, Callable[[bytes], InputMessage]]]]] = {
    bo: {key: (form.size, form.build) for key, form in tables.by_key.items()}
    for bo, tables in _TABLES.items()
}  # the hot path's view: header key -> (datagram size, decode function)
_HEADERS: Final[dict[str, dict[int, tuple[int, SensorType, int, int]]]] = {
    bo: {key: (f.size, f.sensor_type, f.n_int, f.n_double) for key, f in tables.by_key.items()}
    for bo, tables in _TABLES.items()
}  # decode_header's view: header key -> (datagram size, type, N_INT, N_DOUBLE)


def _tables(byteorder: str) -> _Tables:
    tables = _TABLES.get(byteorder)
    if tables is None:
        raise ConfigError(f"byteorder must be '<' (little-endian, the protocol) or '>', got {byteorder!r}")
    return tables


def _as_bytes(data: object) -> bytes:
    if isinstance(data, (bytes, bytearray, memoryview)):
        try:
            return memoryview(data).tobytes()
        except (TypeError, ValueError) as exc:  # released memoryview, ...
            raise DecodeError(RejectReason.NOT_BYTES, f"unreadable buffer: {exc}") from None
    raise DecodeError(RejectReason.NOT_BYTES, f"expected bytes, got {type(data).__name__}")


def _reject_header(data: bytes, n: int) -> DecodeError:
    """The reason a datagram whose header matched no form is rejected (slow path)."""
    if n < HEADER_SIZE:
        return DecodeError(RejectReason.SHORT, f"{n} bytes, the header alone is {HEADER_SIZE}")
    t, n_int, n_double = data[0], data[3], data[4]
    st = _TYPE_BY_VALUE.get(t)
    if st is None:
        return DecodeError(RejectReason.TYPE, f"unknown SENSOR_TYPE {t}")
    expected = HEADER_SIZE + 4 * n_int + 8 * n_double
    if n != expected:
        return DecodeError(
            RejectReason.LENGTH,
            f"{st.name}: {n} bytes, header N_INT={n_int} N_DOUBLE={n_double} says {expected}",
        )
    allowed = ", ".join(f"({ni},{nd})" for tt, ni, nd in INPUT_FORMS if tt is st)
    return DecodeError(
        RejectReason.FORM, f"{st.name}: (N_INT, N_DOUBLE)=({n_int},{n_double}) not allowed; allowed {allowed}"
    )


# --------------------------------------------------------------------------------------------------
# INPUT_PROTOCOL


def decode_input(data: bytes, byteorder: str = "<") -> InputMessage:
    """Decode one INPUT_PROTOCOL datagram. Raises :class:`DecodeError` (and nothing else) on bad input.

    Checks, in this order: bytes-like (NOT_BYTES), header present (SHORT), known type (TYPE), length equal
    to 5 + 4*N_INT + 8*N_DOUBLE (LENGTH), allowed form (FORM), then per field in wire order NaN/inf
    (NON_FINITE) or outside the physical range (RANGE). ``byteorder`` is ``"<"`` (the protocol) or ``">"``.
    """
    if type(data) is not bytes:
        data = _as_bytes(data)
    forms = _DECODERS.get(byteorder)
    if forms is None:
        _tables(byteorder)  # raises ConfigError
    n = len(data)
    if n >= HEADER_SIZE:
        entry = forms.get(data[0] << 16 | data[3] << 8 | data[4])
        if entry is not None and n == entry[0]:
            return entry[1](data)
    raise _reject_header(data, n)


def decode_header(data: bytes, byteorder: str = "<") -> tuple[SensorType, int, int, int]:
    """Validate only the header and the length; return ``(sensor_type, seq, n_int, n_double)``.

    Used to route and sequence a datagram before (or instead of) the full decode. Raises DecodeError
    with NOT_BYTES, SHORT, TYPE, LENGTH or FORM; the payload values are not looked at.
    """
    if type(data) is not bytes:
        data = _as_bytes(data)
    headers = _HEADERS.get(byteorder)
    if headers is None:
        _tables(byteorder)  # raises ConfigError
    n = len(data)
    if n >= HEADER_SIZE:
        entry = headers.get(data[0] << 16 | data[3] << 8 | data[4])
        if entry is not None and n == entry[0]:
            seq = data[1] | data[2] << 8 if byteorder == "<" else data[1] << 8 | data[2]
            return entry[1], seq, entry[2], entry[3]
    raise _reject_header(data, n)


def encode_input(msg: InputMessage, byteorder: str = "<", *, validate: bool = True) -> bytes:
    """Encode one input message into its INPUT_PROTOCOL datagram.

    The form (N_INT, N_DOUBLE) follows from which optional fields are set: GPS ``fix_quality`` and
    ``num_sv`` go together; GPS ``epoch`` requires ``sigma_h``. Raises :class:`EncodeError` with FORM
    (optional fields that no form allows), RANGE (seq outside 0..65535, wrong field types, or with
    ``validate`` a value outside its range) or NON_FINITE. ``validate=False`` skips the value checks
    (ranges and finiteness; not the form, the seq or the field types), for fault-injection tools that
    must send out-of-range values on purpose.
    """
    tables = _tables(byteorder)
    t = sensor_type_of(msg)
    lay = _LAYOUTS[t]
    n_int = 0
    if t is SensorType.GPS:
        n_int = 0 if msg.fix_quality is None and msg.num_sv is None else 2
    elif t is SensorType.GROUND_TRUTH:
        n_int = 0 if msg.line_id is None else 1
    n_double = lay.n_required_doubles
    for name in lay.doubles[lay.n_required_doubles :]:
        if getattr(msg, name) is not None:
            n_double = lay.doubles.index(name) + 1
    form = tables.by_shape.get((lay.cls, n_int, n_double))
    if form is None:
        raise EncodeError(RejectReason.FORM, f"{t.name}: no form with N_INT={n_int}, N_DOUBLE={n_double}")
    return form.pack(msg, validate)


# --------------------------------------------------------------------------------------------------
# OUTPUT_PROTOCOL, its extension, ACK

_OUT: Final = {bo: struct.Struct(f"{bo}Hdd") for bo in BYTEORDERS}
_OUT_EXT: Final = {bo: struct.Struct(f"{bo}HdddddBi") for bo in BYTEORDERS}
_ACK: Final = {bo: struct.Struct(f"{bo}H") for bo in BYTEORDERS}
assert (_OUT["<"].size, _OUT_EXT["<"].size, _ACK["<"].size) == (OUTPUT_SIZE, OUTPUT_EXTENDED_SIZE, ACK_SIZE)


def _struct_for(table: dict[str, struct.Struct], byteorder: str) -> struct.Struct:
    st = table.get(byteorder)
    if st is None:
        _tables(byteorder)  # raises ConfigError with the explanation
    return st


def _check_seq_out(seq: object, where: str) -> int:
    value = seq if type(seq) is int else _integer(seq, -1)
    if not 0 <= value <= 0xFFFF:
        raise EncodeError(RejectReason.RANGE, f"{where}: seq={seq!r} outside [0, 65535]")
    return value


def _check_finite(where: str, error: type, **values: object) -> None:
    for name, x in values.items():
        if not isinstance(x, numbers.Real) or isinstance(x, bool):
            raise error(RejectReason.RANGE, f"{where}: {name} must be a float, got {type(x).__name__}")
        if not math.isfinite(x):
            raise error(RejectReason.NON_FINITE, f"{where}: {name}={x!r} is not finite")


def _check_length(data: object, size: int, where: str) -> bytes:
    if type(data) is not bytes:
        data = _as_bytes(data)
    if len(data) != size:
        raise DecodeError(RejectReason.LENGTH, f"{where}: {len(data)} bytes, expected {size}")
    return data


def encode_output(msg: OutputMessage, byteorder: str = "<") -> bytes:
    """Encode OUTPUT_PROTOCOL (18 bytes ``<Hdd``). EncodeError: seq outside 0..65535, non-finite values."""
    st = _struct_for(_OUT, byteorder)
    seq = _check_seq_out(msg.seq, "OUTPUT")
    _check_finite("OUTPUT", EncodeError, epoch=msg.epoch, arc_length=msg.arc_length)
    return st.pack(seq, msg.epoch, msg.arc_length)


def decode_output(data: bytes, byteorder: str = "<") -> OutputMessage:
    """Decode OUTPUT_PROTOCOL: exactly 18 bytes (LENGTH), finite epoch and arc length (NON_FINITE)."""
    st = _struct_for(_OUT, byteorder)
    seq, epoch, arc = st.unpack(_check_length(data, OUTPUT_SIZE, "OUTPUT"))
    _check_finite("OUTPUT", DecodeError, epoch=epoch, arc_length=arc)
    return OutputMessage(seq, epoch, arc)


def _check_extended(m: OutputExtended, error: type) -> None:
    where = "OUTPUT_EXTENDED"
    _check_finite(
        where, error, epoch=m.epoch, arc_length=m.arc_length, speed=m.speed,
        interval_low=m.interval_low, interval_high=m.interval_high,
    )  # fmt: skip
    if not m.interval_low <= m.arc_length <= m.interval_high:
        raise error(
            RejectReason.RANGE,
            f"{where}: interval [{m.interval_low!r}, {m.interval_high!r}]"
            f" does not contain arc_length={m.arc_length!r}",
        )
    if not 0 <= _integer(m.status, -1) <= 255:
        raise error(RejectReason.RANGE, f"{where}: status={m.status!r} outside [0, 255]")
    line = m.line_id
    if line is not None and not L.LINE_ID_MIN <= _integer(line, -1) <= L.LINE_ID_MAX:
        raise error(RejectReason.RANGE, f"{where}: line_id={line!r} outside [0, {L.LINE_ID_MAX}] or None")


def encode_output_extended(msg: OutputExtended, byteorder: str = "<") -> bytes:
    """Encode the extended OUTPUT (47 bytes ``<HdddddBi``; line_id None is sent as -1); EncodeError if bad."""
    st = _struct_for(_OUT_EXT, byteorder)
    seq = _check_seq_out(msg.seq, "OUTPUT_EXTENDED")
    _check_extended(msg, EncodeError)
    line = -1 if msg.line_id is None else int(msg.line_id)
    return st.pack(
        seq, msg.epoch, msg.arc_length, msg.speed, msg.interval_low, msg.interval_high, int(msg.status), line
    )


def decode_output_extended(data: bytes, byteorder: str = "<") -> OutputExtended:
    """Decode the extended OUTPUT: 47 bytes, finite reals, low <= arc_length <= high, line_id >= -1."""
    st = _struct_for(_OUT_EXT, byteorder)
    seq, epoch, arc, speed, low, high, status, line = st.unpack(
        _check_length(data, OUTPUT_EXTENDED_SIZE, "OUTPUT_EXTENDED")
    )
    if line < -1:
        raise DecodeError(RejectReason.RANGE, f"OUTPUT_EXTENDED: line_id={line} (only -1 means none)")
    msg = OutputExtended(seq, epoch, arc, speed, low, high, status, None if line == -1 else line)
    _check_extended(msg, DecodeError)
    return msg


def decode_output_any(data: bytes, byteorder: str = "<") -> OutputMessage | OutputExtended:
    """Decode either output form, told apart by length (18: standard, 47: extension); else LENGTH."""
    if type(data) is not bytes:
        data = _as_bytes(data)
    if len(data) == OUTPUT_EXTENDED_SIZE:
        return decode_output_extended(data, byteorder)
    return decode_output(data, byteorder)


def encode_ack(seq: int, byteorder: str = "<") -> bytes:
    """Encode an ACK (2 bytes ``<H``). EncodeError(RANGE) if seq is not an int in 0..65535."""
    st = _struct_for(_ACK, byteorder)
    return st.pack(_check_seq_out(seq, "ACK"))


def decode_ack(data: bytes, byteorder: str = "<") -> int:
    """Decode an ACK: exactly 2 bytes (LENGTH); returns the acknowledged SEQ."""
    st = _struct_for(_ACK, byteorder)
    return st.unpack(_check_length(data, ACK_SIZE, "ACK"))[0]
