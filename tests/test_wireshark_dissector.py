"""tools/wireshark/sfa.lua: tshark decodes the shipped sample capture field by field as listener.codec does.

The tshark tests are skipped, with the reason, where tshark is not installed (``apt-get install tshark``).
"""

from __future__ import annotations

import json
import math
import re
import shutil
import struct
import subprocess
from dataclasses import fields
from pathlib import Path

import dpkt
import pytest
from hypothesis import event, given, settings
from hypothesis import strategies as st

from listener.auth import MAGIC, AuthConfig, AuthState, input_seq, output_seq, unwrap
from listener.codec import (
    DecodeError,
    OutputExtended,
    SensorType,
    decode_ack,
    decode_input,
    decode_output_any,
    input_layout,
)
from listener.defaults import DEFAULT_LISTENER_PORT, DEFAULT_OBCU_PORT
from tools.wireshark.make_sample import SAMPLE_KEY, frame, sample_records, write_sample

ROOT = Path(__file__).resolve().parents[1]
LUA = ROOT / "tools" / "wireshark" / "sfa.lua"
SAMPLE = ROOT / "tools" / "wireshark" / "sample.pcap"
TSHARK = shutil.which("tshark")
needs_tshark = pytest.mark.skipif(
    TSHARK is None, reason="tshark is not installed (apt-get install tshark): the dissector is not exercised"
)
MODULE_PORTS = range(47000, 47004)
UDP_PAYLOAD_OFFSET = 14 + 20 + 8  # Ethernet, IPv4 without options, UDP
PREFIX = {
    SensorType.IMU: "imu",
    SensorType.ODOMETER: "odometer",
    SensorType.GPS: "gps",
    SensorType.GROUND_TRUTH: "ground_truth",
    SensorType.STROBE: "strobe",
    SensorType.STOP: "stop",
}
OUTPUT_LAYOUT = (  # name, offset, struct format
    ("seq", 0, "<H"), ("epoch", 2, "<d"), ("arc_length", 10, "<d"), ("speed", 18, "<d"),
    ("interval_low", 26, "<d"), ("interval_high", 34, "<d"), ("status", 42, "<B"), ("line_id", 43, "<i"),
)  # fmt: skip


def _frames(path: Path) -> list[tuple[int, int, bytes]]:
    out = []
    with open(path, "rb") as fh:
        for _, buf in dpkt.pcap.Reader(fh):
            udp = dpkt.ethernet.Ethernet(buf).data.data
            out.append((udp.sport, udp.dport, bytes(udp.data)))
    return out


def _auth_split(data: bytes, direction: str) -> tuple[int, int, bytes, bytes]:
    """(key_id, epoch, payload, tag) of a wrapped datagram, checked with listener.auth.unwrap."""
    if direction == "INPUT":
        inner = 5 + 4 * data[9] + 8 * data[10]
    else:
        inner = {"OUTPUT": 18, "ACK": 2}[direction]
    tag_bytes = len(data) - 6 - inner
    state = AuthState(AuthConfig(tag_bytes=tag_bytes))
    seq_of = input_seq if direction == "INPUT" else output_seq
    payload = unwrap(data, {data[1]: SAMPLE_KEY}, state, seq_of=seq_of)
    return data[1], struct.unpack_from("<I", data, 2)[0], payload, data[-tag_bytes:]


def _direction(sport: int, dport: int) -> str:
    """The dissector's rule: by the default ports, else (any port) INPUT by content."""
    if dport == DEFAULT_OBCU_PORT:
        return "OUTPUT"
    if sport == DEFAULT_OBCU_PORT:
        return "ACK"
    return "INPUT"


def expected_fields(sport: int, dport: int, data: bytes) -> dict:
    """What the dissector must show, from the Python codec: {field: (value, payload offset, format)}.

    Also ``message`` (INPUT / OUTPUT / OUTPUT_EXTENDED / ACK), ``malformed`` (the codec's DecodeError
    reason, or None), and for authenticated datagrams the envelope fields."""
    direction = _direction(sport, dport)
    out: dict = {"fields": {}, "malformed": None, "auth": None}
    base = 0
    if data[0] == MAGIC and not (direction == "OUTPUT" and len(data) in (18, 47)) and not (
        direction == "ACK" and len(data) == 2
    ):
        key_id, epoch, payload, tag = _auth_split(data, direction)
        out["auth"] = {"sfa.auth.key_id": key_id, "sfa.auth.epoch": epoch, "sfa.auth.tag": tag,
                       "sfa.auth.payload_length": len(payload)}  # fmt: skip
        data, base = payload, 6
    f = out["fields"]
    if direction == "INPUT":
        out["message"] = "INPUT"
        try:
            msg = decode_input(data)
        except DecodeError as exc:
            out["malformed"] = str(exc.reason)
            return out
        st = SensorType(data[0])
        f["sfa.input.sensor_type"] = (int(st), base + 0, "<B")
        f["sfa.input.seq"] = (msg.seq, base + 1, "<H")
        f["sfa.input.n_int"] = (data[3], base + 3, "<B")
        f["sfa.input.n_double"] = (data[4], base + 4, "<B")
        names = input_layout(st, data[3], data[4])
        for i, name in enumerate(names):
            off = 5 + 4 * i if i < data[3] else 5 + 4 * data[3] + 8 * (i - data[3])
            fmt = "<i" if i < data[3] else "<d"
            f[f"sfa.{PREFIX[st]}.{name}"] = (getattr(msg, name), base + off, fmt)
        assert {fl.name for fl in fields(msg) if getattr(msg, fl.name) is not None} == {"seq", *names}
    elif direction == "OUTPUT":
        try:
            msg = decode_output_any(data)
        except DecodeError as exc:
            out["message"] = "OUTPUT_EXTENDED" if len(data) == 47 else "OUTPUT"
            out["malformed"] = str(exc.reason)
            return out
        out["message"] = "OUTPUT_EXTENDED" if isinstance(msg, OutputExtended) else "OUTPUT"
        for name, off, fmt in OUTPUT_LAYOUT:
            if hasattr(msg, name):
                value = getattr(msg, name)
                f[f"sfa.output.{name}"] = (-1 if value is None else value, base + off, fmt)
    else:
        out["message"] = "ACK"
        try:
            f["sfa.ack.seq"] = (decode_ack(data), base, "<H")
        except DecodeError as exc:
            out["malformed"] = str(exc.reason)
    return out


def _codec_error(sport: int, dport: int, data: bytes) -> str:
    """The codec's one-line rejection of a plain datagram, as ``str(DecodeError)``."""
    decode = {"INPUT": decode_input, "OUTPUT": decode_output_any, "ACK": decode_ack}[_direction(sport, dport)]
    try:
        decode(data)
    except DecodeError as exc:
        return str(exc)
    raise AssertionError("the codec accepts it")


def _same_words(shown: str, codec: str) -> bool:
    """Equal messages, a number written ``95`` by Lua and ``95.0`` by Python's repr counting as equal."""
    number = r"-?[0-9]+(?:\.[0-9]+)?(?:e[-+]?[0-9]+)?"
    if re.sub(number, "#", shown) != re.sub(number, "#", codec):
        return False
    return [float(x) for x in re.findall(number, shown)] == [float(x) for x in re.findall(number, codec)]


def _flatten(layer: dict, acc: dict) -> dict:
    for key, value in layer.items():
        if isinstance(value, dict):
            _flatten(value, acc)
        else:
            assert key not in acc, f"{key} twice in one frame"
            acc[key] = value
    return acc


def _tshark_json(path: Path, *options: str) -> list[dict]:
    res = subprocess.run(
        [TSHARK, "-n", "-X", f"lua_script:{LUA}", "-r", str(path), "-T", "json", "-x", *options],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    assert "Lua" not in res.stderr and "rror" not in res.stderr, res.stderr
    return [pkt["_source"]["layers"] for pkt in json.loads(res.stdout)]


def test_sample_holds_every_message_kind(tmp_path):
    """The builder runs (seeded) and the shipped file has what the docs say (no tshark needed)."""
    fresh = tmp_path / "sample.pcap"
    n = write_sample(fresh)
    assert n == len(sample_records()) == len(_frames(fresh))
    for path in (fresh, SAMPLE):
        kinds: dict[str, int] = {}
        for sport, dport, data in _frames(path):
            exp = expected_fields(sport, dport, data)
            kind = exp["message"]
            if exp["message"] == "INPUT" and exp["malformed"] is None:
                kind = PREFIX[SensorType(exp["fields"]["sfa.input.sensor_type"][0])]
            kind = ("auth " if exp["auth"] else "") + kind + (" malformed" if exp["malformed"] else "")
            kinds[kind] = kinds.get(kind, 0) + 1
        assert set(kinds) == {
            "imu", "odometer", "gps", "ground_truth", "strobe", "stop", "OUTPUT", "OUTPUT_EXTENDED", "ACK",
            "auth strobe", "auth imu", "auth OUTPUT", "auth ACK", "INPUT malformed", "OUTPUT malformed",
            "OUTPUT_EXTENDED malformed",
        }, (path, kinds)  # fmt: skip
        assert (kinds["INPUT malformed"], kinds["OUTPUT malformed"]) == (5, 1)
        reasons = {expected_fields(*f)["malformed"] for f in _frames(path)} - {None}
        assert reasons == {"length", "type", "range", "non_finite"}


def _compare(frames: list[tuple[int, int, bytes]], layers: list[dict]) -> int:
    """Assert that tshark's decode of every frame is the codec's; return the number of fields compared."""
    assert len(layers) == len(frames)
    checked = 0
    for i, ((sport, dport, data), layer) in enumerate(zip(frames, layers, strict=True), start=1):
        assert "sfa" in layer, (i, list(layer))
        assert not {"hcrt", "cigi", "data"} & set(layer), (i, list(layer))  # the misreadings are gone
        got = _flatten(layer["sfa"], {})
        exp = expected_fields(sport, dport, data)
        assert got["sfa.message"] == exp["message"], i
        if exp["malformed"]:
            expert = "sfa.non_finite" if exp["malformed"] == "non_finite" else "sfa.malformed"
            assert expert in got, (i, got)
            assert got["_ws.expert.message"].startswith(exp["malformed"] + ": "), (i, got)  # the same reason
            assert _same_words(got["_ws.expert.message"], _codec_error(sport, dport, data)), i  # same words
            continue
        assert "sfa.malformed" not in got and "sfa.non_finite" not in got, (i, got)
        if exp["auth"]:
            a = exp["auth"]
            assert got["sfa.auth.magic"] == "0xa5"
            assert int(got["sfa.auth.key_id"]) == a["sfa.auth.key_id"]
            assert int(got["sfa.auth.epoch"]) == a["sfa.auth.epoch"]
            assert int(got["sfa.auth.payload_length"]) == a["sfa.auth.payload_length"]
            assert bytes.fromhex(got["sfa.auth.tag"].replace(":", "")) == a["sfa.auth.tag"]
        sfa_fields = {k for k in got if k.startswith("sfa.") and not k.endswith("_raw")}
        envelope = {"sfa.message", *(("sfa.auth.magic", *exp["auth"]) if exp["auth"] else ())}
        assert sfa_fields - envelope == set(exp["fields"]), i  # no field missing, none extra
        for name, (value, off, fmt) in exp["fields"].items():
            raw_hex, raw_off, raw_len = got[f"{name}_raw"][:3]
            assert (raw_off, raw_len) == (UDP_PAYLOAD_OFFSET + off, struct.calcsize(fmt)), (i, name)
            assert struct.unpack(fmt, bytes.fromhex(raw_hex))[0] == value, (i, name)  # bit for bit
            shown = got[name]
            if fmt == "<d":  # tshark shows 15 significant digits (the raw bytes above are the exact check)
                assert shown == format(value, ".15g"), (i, name, shown)
            else:
                assert int(shown) == value, (i, name, shown)
            checked += 1
    return checked


@needs_tshark
def test_tshark_decodes_every_field_of_the_sample_as_the_codec():
    checked = _compare(_frames(SAMPLE), _tshark_json(SAMPLE))
    assert checked > 2000  # every field of every frame, not a few


def _fix_first_byte(data: bytes, keep_lengths: tuple[int, ...]) -> bytes:
    """No 0xA5 first byte (an authenticated envelope, not the codec's business) unless the length is plain."""
    if data and data[0] == MAGIC and len(data) not in keep_lengths:
        return b"\x00" + data[1:]
    return data


_FLOATS = (
    st.floats(0.001, 30.0) | st.floats(-200.0, 200.0) | st.floats(0.0, 2e10)
    | st.sampled_from([math.nan, math.inf, -math.inf]) | st.floats(width=64)
)  # fmt: skip


@st.composite
def _input_datagrams(draw) -> bytes:
    from listener.codec import INPUT_FORMS

    types = st.sampled_from([0, 1, 2, 3, 7, 8, 9, 10, 255])
    any_form = st.tuples(types, st.integers(0, 3), st.integers(0, 8))
    t, ni, nd = draw(st.sampled_from(INPUT_FORMS) | any_form)
    int32 = st.integers(0, 9) | st.integers(-(2**31), 2**31 - 1)
    ints = draw(st.lists(int32, min_size=ni, max_size=ni))
    dbls = draw(st.lists(_FLOATS, min_size=nd, max_size=nd))
    data = struct.pack(f"<BHBB{ni}i{nd}d", int(t), draw(st.integers(0, 65535)), ni, nd, *ints, *dbls)
    cut = draw(st.sampled_from([0, 0, 0, 0, 0, -1, -4, 2, 8]))
    data = data[:cut] if cut < 0 else data + bytes(cut)
    return _fix_first_byte(data or b"\x01", ())


@st.composite
def _output_datagrams(draw) -> bytes:
    v = draw(st.lists(_FLOATS, min_size=5, max_size=5))
    if draw(st.booleans()):  # arc length inside the interval, mostly
        v[1], v[3], v[4] = sorted((v[1], v[3], v[4]))[1], *sorted((v[1], v[3], v[4]))[::2]
    seq = draw(st.integers(0, 65535))
    if draw(st.booleans()):
        data = struct.pack("<HdddddBi", seq, v[0], v[1], v[2], v[3], v[4], draw(st.integers(0, 255)),
                           draw(st.integers(-3, 9)))  # fmt: skip
    else:
        data = struct.pack("<Hdd", seq, v[0], v[1])
    cut = draw(st.sampled_from([0, 0, 0, -1, 3]))
    data = data[:cut] if cut < 0 else data + bytes(cut)
    return _fix_first_byte(data, (18, 47))


@needs_tshark
@settings(max_examples=20)
@given(st.lists(st.one_of(
    st.tuples(st.just(41000), st.just(DEFAULT_LISTENER_PORT), _input_datagrams()),
    st.tuples(st.just(41001), st.just(DEFAULT_OBCU_PORT), _output_datagrams()),
    st.tuples(st.just(DEFAULT_OBCU_PORT), st.just(41002),
              st.binary(min_size=1, max_size=4).map(lambda d: _fix_first_byte(d, (2,)))),
), min_size=1, max_size=40))  # fmt: skip
def test_tshark_accepts_and_rejects_arbitrary_datagrams_as_the_codec(tmp_path_factory, datagrams):
    path = tmp_path_factory.mktemp("fuzz") / "f.pcap"
    with open(path, "wb") as fh:
        w = dpkt.pcap.Writer(fh, linktype=dpkt.pcap.DLT_EN10MB)
        for k, (sp, dp, data) in enumerate(datagrams):
            w.writepkt(frame(sp, dp, data, k), ts=1.0 + 0.001 * k)
    _compare([(sp, dp, data) for sp, dp, data in datagrams], _tshark_json(path))
    for sp, dp, data in datagrams:  # what was covered (pytest --hypothesis-show-statistics)
        exp = expected_fields(sp, dp, data)
        event(f"{exp['message']} {exp['malformed'] or 'accepted'}")


@needs_tshark
def test_ports_are_preferences_and_other_ports_fall_back_to_the_heuristic(tmp_path):
    from listener.codec import OutputMessage, Strobe, encode_input, encode_output

    path = tmp_path / "ports.pcap"
    recs = [
        (1.0, 41000, 49500, encode_input(Strobe(3, 1.7e9))),  # any port: found by content
        (1.1, 41001, 49501, encode_output(OutputMessage(4, 1.7e9, 12.5))),  # 18 bytes: only by port
    ]
    with open(path, "wb") as fh:
        w = dpkt.pcap.Writer(fh, linktype=dpkt.pcap.DLT_EN10MB)
        for k, (t, sp, dp, data) in enumerate(recs):
            w.writepkt(frame(sp, dp, data, k), ts=t)
    plain = _tshark_json(path)
    assert _flatten(plain[0]["sfa"], {})["sfa.strobe.timestamp"] == "1700000000"
    assert "sfa" not in plain[1]
    configured = _tshark_json(path, "-o", "sfa.input_port:49500", "-o", "sfa.obcu_port:49501")
    got = _flatten(configured[1]["sfa"], {})
    shown = (got["sfa.message"], got["sfa.output.seq"], got["sfa.output.arc_length"])
    assert shown == ("OUTPUT", "4", "12.5")


def test_default_ports_of_the_project_are_those_of_the_dissector():
    text = LUA.read_text()
    assert f'Pref.uint("Listener input port", {DEFAULT_LISTENER_PORT},' in text
    assert f'Pref.uint("OBCU port", {DEFAULT_OBCU_PORT},' in text
    from interface_modules.scenario import _DEFAULT_PORTS

    assert sorted(_DEFAULT_PORTS.values()) == list(MODULE_PORTS)
    assert '"47000-47003"' in text


def test_the_dissector_ranges_are_the_codec_ranges():
    from listener.codec import FIELD_RANGES

    block = LUA.read_text().split("local RANGES = {", 1)[1].split("\n}\n", 1)[0]
    got = {
        m[1]: (float(m[2]), float(m[3]), m[4], bool(m[5]))
        for m in re.finditer(r"(\w+) = \{ ([-0-9.]+), ([-0-9.]+), \"([^\"]*)\"(, true)? \}", block)
    }
    assert got == {k: (r.lo, r.hi, r.unit, r.lo_open) for k, r in FIELD_RANGES.items()}
