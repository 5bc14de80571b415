"""Tests of listener.codec: round trips of every form, strict rejection with exact reasons, spec examples."""

from __future__ import annotations

import math
import re
import struct
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from listener import limits as L
from listener.codec import (
    FIELD_RANGES,
    INPUT_FORMS,
    OUTPUT_EXTENDED_SIZE,
    DecodeError,
    EncodeError,
    GpsFix,
    GroundTruth,
    ImuSample,
    OdometerSample,
    OutputExtended,
    OutputMessage,
    RejectReason,
    SensorType,
    Stop,
    Strobe,
    decode_ack,
    decode_header,
    decode_input,
    decode_output,
    decode_output_any,
    decode_output_extended,
    encode_ack,
    encode_input,
    encode_output,
    encode_output_extended,
    input_layout,
    sensor_type_of,
)
from listener.errors import ConfigError, ListenerError

DOC = Path(__file__).resolve().parents[1] / "docs" / "protocol.md"
BYTEORDER = st.sampled_from(["<", ">"])


# ---------------------------------------------------------------------------------------------- strategies


def _in_range(name: str) -> st.SearchStrategy:
    rng = FIELD_RANGES[name]
    if rng.integer:
        return st.integers(int(rng.lo), int(rng.hi))
    return st.floats(rng.lo, rng.hi, exclude_min=rng.lo_open, allow_nan=False, allow_infinity=False)


SEQ = st.integers(0, 0xFFFF)


def _opt(name: str) -> st.SearchStrategy:
    return st.one_of(st.none(), _in_range(name))


IMU = st.builds(ImuSample, SEQ, *(_in_range(n) for n in ("ax", "ay", "az", "gx", "gy", "gz")), _opt("epoch"))
ODO = st.builds(OdometerSample, SEQ, _in_range("speed"), _in_range("sigma"), _opt("epoch"))


@st.composite
def gps(draw) -> GpsFix:
    ints = draw(st.booleans())
    n_extra = draw(st.integers(0, 2))
    return GpsFix(
        draw(SEQ),
        draw(_in_range("lat")),
        draw(_in_range("lon")),
        draw(_in_range("alt")),
        draw(_in_range("fix_quality")) if ints else None,
        draw(_in_range("num_sv")) if ints else None,
        draw(_in_range("sigma_h")) if n_extra >= 1 else None,
        draw(_in_range("epoch")) if n_extra >= 2 else None,
    )


GT_VALUES = (_in_range(n) for n in ("vx", "vy", "vz", "arc_length"))
GT = st.builds(GroundTruth, SEQ, *GT_VALUES, _opt("line_id"), _opt("epoch"))
STROBE = st.builds(Strobe, SEQ, _in_range("timestamp"))
STOP = st.builds(Stop, SEQ)
ANY_INPUT = st.one_of(IMU, ODO, gps(), GT, STROBE, STOP)


# ---------------------------------------------------------------------------------------------- round trips


@given(ANY_INPUT, BYTEORDER)
def test_input_round_trip_every_type(msg, byteorder):
    data = encode_input(msg, byteorder)
    assert decode_input(data, byteorder) == msg
    t, seq, n_int, n_double = decode_header(data, byteorder)
    assert t is sensor_type_of(msg) and seq == msg.seq
    assert len(data) == 5 + 4 * n_int + 8 * n_double
    assert (t, n_int, n_double) in INPUT_FORMS


@pytest.mark.parametrize("form", INPUT_FORMS, ids=lambda f: f"{f[0].name}-{f[1]}-{f[2]}")
def test_every_allowed_form_round_trips(form):
    """One hypothesis run per (type, N_INT, N_DOUBLE): every optional form is exercised, not just some."""
    t, n_int, n_double = form
    names = input_layout(t, n_int, n_double)

    @given(SEQ, st.tuples(*(_in_range(n) for n in names)), BYTEORDER)
    def check(seq, values, byteorder):
        raw = struct.pack(f"{byteorder}BHBB{n_int}i{n_double}d", t, seq, n_int, n_double, *values)
        msg = decode_input(raw, byteorder)
        assert sensor_type_of(msg) is t and msg.seq == seq
        for name, value in zip(names, values, strict=True):
            assert getattr(msg, name) == value
        assert encode_input(msg, byteorder) == raw

    check()


def test_input_forms_match_the_spec_table():
    expected = {
        (SensorType.IMU, 0, 6), (SensorType.IMU, 0, 7),
        (SensorType.ODOMETER, 0, 2), (SensorType.ODOMETER, 0, 3),
        *((SensorType.GPS, ni, nd) for ni in (0, 2) for nd in (3, 4, 5)),
        *((SensorType.GROUND_TRUTH, ni, nd) for ni in (0, 1) for nd in (4, 5)),
        (SensorType.STROBE, 0, 1), (SensorType.STOP, 0, 0),
    }  # fmt: skip
    assert set(INPUT_FORMS) == expected and len(INPUT_FORMS) == len(expected)


@given(SEQ, _in_range("epoch"), st.floats(-1e9, 1e9), BYTEORDER)
def test_output_round_trip(seq, epoch, arc, byteorder):
    msg = OutputMessage(seq, epoch, arc)
    data = encode_output(msg, byteorder)
    assert len(data) == 18
    assert decode_output(data, byteorder) == msg
    assert decode_output_any(data, byteorder) == msg
    assert data == struct.pack(f"{byteorder}Hdd", seq, epoch, arc)


@st.composite
def extended(draw) -> OutputExtended:
    arc = draw(st.floats(-1e6, 1e8))
    low = arc - draw(st.floats(0, 1e4))
    high = arc + draw(st.floats(0, 1e4))
    return OutputExtended(
        draw(SEQ), draw(_in_range("epoch")), arc, draw(st.floats(-200, 200)), low, high,
        draw(st.integers(0, 255)), draw(_opt("line_id")),
    )  # fmt: skip


@given(extended(), BYTEORDER)
def test_output_extended_round_trip(msg, byteorder):
    data = encode_output_extended(msg, byteorder)
    assert len(data) == OUTPUT_EXTENDED_SIZE == 47
    assert decode_output_extended(data, byteorder) == msg
    assert decode_output_any(data, byteorder) == msg
    # the first 18 bytes are a valid standard OUTPUT: an OBCU that ignores the extension still works
    assert decode_output(data[:18], byteorder) == OutputMessage(msg.seq, msg.epoch, msg.arc_length)


@given(SEQ, BYTEORDER)
def test_ack_round_trip(seq, byteorder):
    data = encode_ack(seq, byteorder)
    assert len(data) == 2 and decode_ack(data, byteorder) == seq


def test_big_endian_is_really_big_endian():
    assert encode_input(Stop(0x0102), ">") == bytes.fromhex("0a 01 02 00 00")
    assert encode_input(Stop(0x0102)) == bytes.fromhex("0a 02 01 00 00")
    assert encode_ack(258, ">") == bytes.fromhex("01 02")


# ---------------------------------------------------------------------------------------------- spec page


@pytest.mark.parametrize(
    ("hex_text", "msg"),
    [
        ("0a 07 00 00 00", Stop(7)),
        ("09 01 00 00 01 00 00 00 00 00 00 f8 3f", Strobe(1, 1.5)),
    ],
)
def test_spec_page_input_examples(hex_text, msg):
    data = bytes.fromhex(hex_text)
    assert decode_input(data) == msg
    assert encode_input(msg) == data


def test_spec_page_ack_example():
    assert decode_ack(bytes.fromhex("02 01")) == 258
    assert encode_ack(258) == bytes.fromhex("02 01")


def test_thesis_rest_example_imu_reads_minus_g():
    """The spec: a level IMU at rest reads about (0, 0, -9.81); it must be accepted."""
    msg = ImuSample(3, 0.0, 0.0, -9.81, 0.0, 0.0, 0.0)
    assert decode_input(encode_input(msg)) == msg


# ---------------------------------------------------------------------------------------------- rejection


@given(st.binary(min_size=0, max_size=64))
def test_any_short_byte_string_decodes_or_raises_decode_error(data):
    for byteorder in ("<", ">"):
        try:
            msg = decode_input(data, byteorder)
        except DecodeError as exc:
            assert isinstance(exc.reason, RejectReason) and exc.detail
        else:
            assert encode_input(msg, byteorder) == data
        for decode in (decode_output, decode_output_extended, decode_output_any, decode_ack, decode_header):
            try:
                decode(data, byteorder)
            except DecodeError as exc:
                assert isinstance(exc.reason, RejectReason)


@given(st.sampled_from(INPUT_FORMS), SEQ, st.binary(min_size=0, max_size=64))
def test_valid_headers_with_random_payload_decode_or_raise(form, seq, payload):
    """Random bytes rarely form a valid header: also fuzz payloads behind every valid header."""
    t, n_int, n_double = form
    size = 4 * n_int + 8 * n_double
    data = struct.pack("<BHBB", t, seq, n_int, n_double) + payload[:size]
    try:
        msg = decode_input(data)
    except DecodeError as exc:
        assert exc.reason in (RejectReason.LENGTH, RejectReason.NON_FINITE, RejectReason.RANGE)
        assert (exc.reason is RejectReason.LENGTH) == (len(payload) < size)
    else:
        assert encode_input(msg) == data


def _raw(t, n_int, n_double, *values, seq=0, extra=b""):
    return struct.pack(f"<BHBB{n_int}i{n_double}d", t, seq, n_int, n_double, *values) + extra


IMU_OK = (0.0, 0.0, -9.81, 0.0, 0.0, 0.0)
GPS_OK = (45.0, 9.0, 120.0)


@pytest.mark.parametrize(
    ("data", "reason", "detail"),
    [
        (b"", RejectReason.SHORT, "0 bytes"),
        (b"\x0a\x00\x00\x00", RejectReason.SHORT, "4 bytes"),
        (bytes([0, 0, 0, 0, 0]), RejectReason.TYPE, "unknown SENSOR_TYPE 0"),
        (bytes([4, 0, 0, 0, 0]), RejectReason.TYPE, "unknown SENSOR_TYPE 4"),
        (bytes([255, 0, 0, 0, 0]), RejectReason.TYPE, "unknown SENSOR_TYPE 255"),
        (_raw(10, 0, 0, extra=b"\x00"), RejectReason.LENGTH, "6 bytes"),
        (_raw(9, 0, 1, 1.5)[:-1], RejectReason.LENGTH, "says 13"),
        (_raw(1, 0, 6, *IMU_OK, extra=b"\x00" * 8), RejectReason.LENGTH, "says 53"),
        (_raw(10, 0, 1, 1.0), RejectReason.FORM, "STOP"),
        (_raw(1, 0, 5, *IMU_OK[:5]), RejectReason.FORM, "(0,5)"),
        (_raw(1, 0, 8, *IMU_OK, 1.0, 2.0), RejectReason.FORM, "allowed (0,6), (0,7)"),
        (_raw(1, 1, 6, 0, *IMU_OK), RejectReason.FORM, "IMU"),
        (_raw(2, 0, 1, 1.0), RejectReason.FORM, "ODOMETER"),
        (_raw(3, 1, 3, 1, *GPS_OK), RejectReason.FORM, "GPS"),
        (_raw(3, 0, 2, *GPS_OK[:2]), RejectReason.FORM, "GPS"),
        (_raw(8, 2, 4, 1, 2, 0.0, 0.0, 0.0, 10.0), RejectReason.FORM, "GROUND_TRUTH"),
        (_raw(9, 0, 0), RejectReason.FORM, "STROBE"),
        (_raw(1, 0, 6, 0.0, math.nan, -9.81, 0.0, 0.0, 0.0), RejectReason.NON_FINITE, "ay=nan"),
        (_raw(1, 0, 7, *IMU_OK, math.inf), RejectReason.NON_FINITE, "epoch=inf"),
        (_raw(1, 0, 6, 0.0, 0.0, -200.0, 0.0, 0.0, 0.0), RejectReason.RANGE, "az=-200.0"),
        (_raw(1, 0, 6, 0.0, 0.0, -9.81, 0.0, 0.0, 36.0), RejectReason.RANGE, "gz=36.0"),
        (_raw(1, 0, 7, *IMU_OK, -1.0), RejectReason.RANGE, "epoch=-1.0"),
        (_raw(2, 0, 2, 10.0, 0.0), RejectReason.RANGE, "sigma=0.0"),
        (_raw(2, 0, 2, 10.0, -0.1), RejectReason.RANGE, "sigma=-0.1"),
        (_raw(2, 0, 2, 151.0, 0.1), RejectReason.RANGE, "speed=151.0"),
        (_raw(2, 0, 3, 10.0, math.nan, 5.0), RejectReason.NON_FINITE, "sigma=nan"),
        (_raw(3, 0, 3, 90.5, 9.0, 100.0), RejectReason.RANGE, "lat=90.5"),
        (_raw(3, 0, 3, 45.0, -180.01, 100.0), RejectReason.RANGE, "lon=-180.01"),
        (_raw(3, 0, 3, 45.0, 9.0, 9001.0), RejectReason.RANGE, "alt=9001.0"),
        (_raw(3, 0, 3, 45.0, 9.0, -math.inf), RejectReason.NON_FINITE, "alt=-inf"),
        (_raw(3, 0, 4, *GPS_OK, 0.0), RejectReason.RANGE, "sigma_h=0.0"),
        (_raw(3, 2, 3, 9, 10, *GPS_OK), RejectReason.RANGE, "fix_quality=9"),
        (_raw(3, 2, 3, -1, 10, *GPS_OK), RejectReason.RANGE, "fix_quality=-1"),
        (_raw(3, 2, 3, 4, 256, *GPS_OK), RejectReason.RANGE, "num_sv=256"),
        (_raw(8, 1, 4, -1, 0.0, 0.0, 0.0, 10.0), RejectReason.RANGE, "line_id=-1"),
        (_raw(8, 0, 4, 0.0, 0.0, 0.0, -1001.0), RejectReason.RANGE, "arc_length=-1001.0"),
        (_raw(8, 0, 4, 0.0, 0.0, 0.0, 1.1e8), RejectReason.RANGE, "arc_length=110000000.0"),
        (_raw(8, 0, 4, 0.0, 151.0, 0.0, 0.0), RejectReason.RANGE, "vy=151.0"),
        (_raw(9, 0, 1, math.nan), RejectReason.NON_FINITE, "timestamp=nan"),
        (_raw(9, 0, 1, -0.5), RejectReason.RANGE, "timestamp=-0.5"),
        (_raw(9, 0, 1, 2e10), RejectReason.RANGE, "timestamp=20000000000.0"),
    ],
)
def test_malformed_input_exact_reason(data, reason, detail):
    with pytest.raises(DecodeError) as info:
        decode_input(data)
    assert info.value.reason is reason
    assert detail in info.value.detail
    assert str(info.value).startswith(f"{reason.value}: ")
    assert isinstance(info.value, ListenerError)


def test_first_bad_field_in_wire_order_is_reported():
    data = _raw(1, 0, 6, 500.0, math.nan, -9.81, 0.0, 0.0, 0.0)
    with pytest.raises(DecodeError) as info:
        decode_input(data)
    assert info.value.reason is RejectReason.RANGE and "ax=500.0" in info.value.detail


def test_boundaries_are_inclusive_except_sigma():
    ok = [
        _raw(1, 0, 6, L.ACCEL_MAX_MPS2, -L.ACCEL_MAX_MPS2, 0.0, L.RATE_MAX_RADPS, -L.RATE_MAX_RADPS, 0.0),
        _raw(3, 2, 4, 8, 255, 90.0, -180.0, 9000.0, L.GPS_SIGMA_H_MAX_M),
        _raw(3, 2, 3, 0, 0, -90.0, 180.0, -500.0),
        _raw(2, 0, 3, -150.0, L.ODO_SIGMA_MAX_MPS, 0.0),
        _raw(8, 1, 5, 2**31 - 1, 150.0, -150.0, 0.0, -1000.0, 1e10),
        _raw(8, 1, 4, 0, 0.0, 0.0, 0.0, 1e8),
        _raw(2, 0, 2, 0.0, 5e-324),  # the smallest positive sigma is > 0
    ]
    for data in ok:
        assert encode_input(decode_input(data)) == data


@pytest.mark.parametrize("bad", ["text", 42, None, [1, 2, 3, 4, 5], 1.5])
def test_not_bytes_is_a_decode_error(bad):
    for decode in (decode_input, decode_header, decode_output, decode_output_extended, decode_ack):
        with pytest.raises(DecodeError) as info:
            decode(bad)
        assert info.value.reason is RejectReason.NOT_BYTES


def test_bytearray_and_memoryview_are_accepted():
    data = encode_input(GpsFix(9, 45.0, 9.0, 100.0, 1, 7, 3.0, 12.5))
    assert decode_input(bytearray(data)) == decode_input(memoryview(data)) == decode_input(data)
    wide = memoryview(bytearray(data[:52] + b"\x00" * 4)).cast("i")  # 14 ints = 56 bytes: LENGTH, not garbage
    with pytest.raises(DecodeError) as info:
        decode_input(wide)
    assert info.value.reason is RejectReason.LENGTH


def test_header_only_validation_ignores_payload_values():
    data = _raw(3, 2, 5, 99, -5, math.nan, 1e9, 1e9, -1.0, -1.0, seq=65535)
    assert decode_header(data) == (SensorType.GPS, 65535, 2, 5)
    assert decode_header(data)[0] is SensorType.GPS
    with pytest.raises(DecodeError) as info:
        decode_input(data)
    assert info.value.reason is RejectReason.RANGE
    cases = [
        (data[:4], RejectReason.SHORT),
        (data[:-1], RejectReason.LENGTH),
        (_raw(9, 0, 2, 1.0, 2.0), RejectReason.FORM),
        (b"\x05" + data[1:], RejectReason.TYPE),
    ]
    for bad, reason in cases:
        with pytest.raises(DecodeError) as info:
            decode_header(bad)
        assert info.value.reason is reason


def test_bad_byteorder_is_a_config_error():
    for call in (lambda: decode_input(b"\x0a\0\0\0\0", "@"), lambda: encode_ack(1, "!"),
                 lambda: encode_input(Stop(1), "="), lambda: decode_output(b"\0" * 18, "x")):
        with pytest.raises(ConfigError, match="byteorder"):
            call()


# ---------------------------------------------------------------------------------------------- encode errors


@pytest.mark.parametrize(
    ("msg", "reason", "detail"),
    [
        (Stop(-1), RejectReason.RANGE, "seq=-1"),
        (Stop(65536), RejectReason.RANGE, "seq=65536"),
        (Stop(True), RejectReason.RANGE, "seq=True"),
        (Strobe(1, math.nan), RejectReason.NON_FINITE, "timestamp=nan"),
        (GpsFix(1, 45.0, 9.0, 0.0, epoch=5.0), RejectReason.FORM, "optional fields"),
        (GpsFix(1, 45.0, 9.0, 0.0, fix_quality=1), RejectReason.FORM, "optional fields"),
        (GpsFix(1, 45.0, 9.0, 0.0, fix_quality=1.0, num_sv=5), RejectReason.RANGE, "fix_quality must be"),
        (GpsFix(1, 91.0, 9.0, 0.0), RejectReason.RANGE, "lat=91.0"),
        (OdometerSample(1, 1.0, 0.0), RejectReason.RANGE, "sigma=0.0"),
        (OdometerSample(1, "fast", 0.1), RejectReason.RANGE, "speed must be a float"),
        (GroundTruth(1, 0.0, 0.0, 0.0, 5.0, line_id=-3), RejectReason.RANGE, "line_id=-3"),
        ("not a message", RejectReason.TYPE, "str"),
    ],
)
def test_encode_input_rejects_with_encode_error(msg, reason, detail):
    with pytest.raises(EncodeError) as info:
        encode_input(msg)
    assert info.value.reason is reason and detail in info.value.detail
    assert not isinstance(info.value, DecodeError)


def test_encode_without_validation_sends_out_of_range_values_for_fault_injection():
    msg = ImuSample(4, 1e6, 0.0, math.nan, 0.0, 0.0, 99.0)
    data = encode_input(msg, validate=False)
    assert decode_header(data) == (SensorType.IMU, 4, 0, 6)
    with pytest.raises(DecodeError) as info:
        decode_input(data)
    assert info.value.reason is RejectReason.RANGE and "ax=1000000.0" in info.value.detail
    with pytest.raises(EncodeError):  # the form and seq are still enforced
        encode_input(ImuSample(70000, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0), validate=False)


@pytest.mark.parametrize(
    ("call", "reason"),
    [
        (lambda: encode_output(OutputMessage(65536, 1.0, 2.0)), RejectReason.RANGE),
        (lambda: encode_output(OutputMessage(-1, 1.0, 2.0)), RejectReason.RANGE),
        (lambda: encode_output(OutputMessage(1, math.inf, 2.0)), RejectReason.NON_FINITE),
        (lambda: encode_output(OutputMessage(1, 1.0, math.nan)), RejectReason.NON_FINITE),
        (lambda: encode_output(OutputMessage(1, None, 2.0)), RejectReason.RANGE),
        (lambda: encode_ack(65536), RejectReason.RANGE),
        (lambda: encode_ack(-1), RejectReason.RANGE),
        (lambda: encode_ack(3.0), RejectReason.RANGE),
        (lambda: encode_output_extended(OutputExtended(1, 1.0, 5.0, 1.0, 6.0, 7.0, 0)), RejectReason.RANGE),
        (lambda: encode_output_extended(OutputExtended(1, 1.0, 5.0, 1.0, 4.0, 7.0, 256)), RejectReason.RANGE),
        (lambda: encode_output_extended(OutputExtended(1, 1.0, 5.0, 1.0, 4.0, 7, 0, -1)), RejectReason.RANGE),
        (lambda: encode_output_extended(OutputExtended(1, 1.0, 5.0, math.nan, 4.0, 7.0, 0)),
         RejectReason.NON_FINITE),
    ],
)
def test_encode_output_and_ack_reject_with_encode_error(call, reason):
    with pytest.raises(EncodeError) as info:
        call()
    assert info.value.reason is reason


@pytest.mark.parametrize(
    ("call", "reason", "detail"),
    [
        (lambda: decode_output(b"\x00" * 17), RejectReason.LENGTH, "17 bytes, expected 18"),
        (lambda: decode_output(b"\x00" * 19), RejectReason.LENGTH, "19 bytes, expected 18"),
        (lambda: decode_output(struct.pack("<Hdd", 1, math.nan, 0.0)), RejectReason.NON_FINITE, "epoch=nan"),
        (lambda: decode_output(struct.pack("<Hdd", 1, 0, -math.inf)), RejectReason.NON_FINITE, "arc_length"),
        (lambda: decode_ack(b"\x01"), RejectReason.LENGTH, "1 bytes, expected 2"),
        (lambda: decode_ack(b"\x01\x02\x03"), RejectReason.LENGTH, "3 bytes, expected 2"),
        (lambda: decode_output_any(b"\x00" * 20), RejectReason.LENGTH, "expected 18"),
        (lambda: decode_output_extended(struct.pack("<HdddddBi", 1, 0.0, 5.0, 0.0, 4.0, 6.0, 0, -2)),
         RejectReason.RANGE, "line_id=-2"),
        (lambda: decode_output_extended(struct.pack("<HdddddBi", 1, 0.0, 5.0, 0.0, 6.0, 4.0, 0, 1)),
         RejectReason.RANGE, "does not contain"),
    ],
)
def test_decode_output_and_ack_reject_with_exact_reason(call, reason, detail):
    with pytest.raises(DecodeError) as info:
        call()
    assert info.value.reason is reason and detail in info.value.detail


def test_messages_are_frozen():
    msg = Stop(1)
    with pytest.raises(AttributeError):
        msg.seq = 2  # type: ignore[misc]


# ---------------------------------------------------------------------------------------------- the doc


def test_protocol_doc_hex_examples_are_what_the_encoder_produces():
    """Every ``hex: ...`` line of docs/protocol.md follows a ``python: <expr>`` line; both must agree."""
    import listener.codec as codec

    text = DOC.read_text(encoding="utf-8")
    pairs = re.findall(r"^python: `(.+?)`\s*\nhex: `([0-9a-f ]+)`", text, flags=re.M)
    assert len(pairs) >= len(INPUT_FORMS) + 3  # every input form, OUTPUT, OUTPUT extended, ACK
    ns = {name: getattr(codec, name) for name in codec.__all__}
    seen_forms = set()
    for expr, hex_text in pairs:
        data = eval(expr, ns)  # noqa: S307 - expressions written in our own documentation
        assert data.hex(" ") == hex_text, expr
        if expr.startswith("encode_input("):
            t, _, n_int, n_double = decode_header(data)
            seen_forms.add((t, n_int, n_double))
    assert seen_forms == set(INPUT_FORMS)


def test_protocol_doc_range_table_matches_the_constants():
    text = DOC.read_text(encoding="utf-8")
    for name, rng in FIELD_RANGES.items():
        row = f"| `{name}` | {rng.describe()} |"
        assert row in text, row


def test_integer_like_and_numpy_values_encode_like_plain_ones():
    import enum

    import numpy as np

    class Status(enum.IntEnum):
        NOMINAL = 1

    ext = OutputExtended(np.uint16(42), 1.0, 5.0, np.float64(1.0), 4.0, 7.0, Status.NOMINAL, np.int64(3))
    plain = OutputExtended(42, 1.0, 5.0, 1.0, 4.0, 7.0, 1, 3)
    assert encode_output_extended(ext) == encode_output_extended(plain)
    assert encode_ack(np.int32(7)) == encode_ack(7)
    out = OutputMessage(np.int64(9), np.float32(1.5), 2.0)
    assert encode_output(out) == encode_output(OutputMessage(9, 1.5, 2.0))
    gps = GpsFix(np.int64(5), np.float64(45.0), 9.0, 100.0, np.int32(4), np.int64(12))
    assert encode_input(gps) == encode_input(GpsFix(5, 45.0, 9.0, 100.0, 4, 12))
    for bad in (OutputMessage(True, 1.0, 2.0), OutputMessage(1.0, 1.0, 2.0)):
        with pytest.raises(EncodeError):
            encode_output(bad)
    with pytest.raises(EncodeError):
        encode_input(GpsFix(5, 45.0, 9.0, 100.0, True, 12))


def test_every_header_with_a_consistent_length_is_classified():
    """All 256 types x N_INT 0..3 x N_DOUBLE 0..8 with zero payload: the exact reason for each."""
    allowed = set(INPUT_FORMS)
    for t in range(256):
        for n_int in range(4):
            for n_double in range(9):
                data = bytes([t, 1, 0, n_int, n_double]) + b"\x00" * (4 * n_int + 8 * n_double)
                try:
                    msg = decode_input(data)
                except DecodeError as exc:
                    if t not in {int(x) for x in SensorType}:
                        assert exc.reason is RejectReason.TYPE
                    elif (SensorType(t), n_int, n_double) not in allowed:
                        assert exc.reason is RejectReason.FORM
                    else:  # zeros are out of range for sigma (> 0) only
                        assert exc.reason is RejectReason.RANGE and "sigma" in exc.detail
                else:
                    assert (sensor_type_of(msg), n_int, n_double) in allowed


def test_protocol_doc_usage_example_runs():
    text = DOC.read_text(encoding="utf-8")
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert len(blocks) == 1
    exec(compile(blocks[0], str(DOC), "exec"), {})  # noqa: S102 - our own documentation; asserts inside
