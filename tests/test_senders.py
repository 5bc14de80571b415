"""Sender identity (listener.senders): the configured table, trust on first use, permissive mode, the
checkpoint's snapshot, and the pipeline rejecting what the table does not allow (issue 20)."""

from __future__ import annotations

import json
import math

import pytest
from test_listener_pipeline import PORTS, _datagrams, _feed, run  # noqa: F401 - fixtures

from listener.auth import EpochCounter, input_seq, wrap
from listener.auth_link import input_key
from listener.codec import GroundTruth, Stop, decode_output, encode_input
from listener.config import AuthSettings, ListenerConfig, config_from_dict, load_config
from listener.errors import ConfigError
from listener.pipeline import Pipeline
from listener.senders import SendersConfig, SenderTable, parse_senders, source_of
from listener.warnlimit import WarningLimiter

CTL, IMU, ODO, GPS = (f"127.0.0.1:{PORTS[m]}" for m in ("ctl", "imu", "odo", "gps"))
TABLE = {
    "control": {"source": CTL, "types": ["ground_truth", "strobe", "stop"]},
    "imu": {"source": IMU, "types": ["imu"]},
    "odometer": {"source": ODO, "types": ["odometer"]},
    "gnss": {"source": GPS, "types": ["gps"]},
}


# ---------------------------------------------------------------------------------------------- config


def test_a_configured_table_is_strict_by_default():
    cfg = parse_senders(TABLE)
    assert cfg.mode == "strict" and len(cfg.entries) == 4
    assert parse_senders({}).mode == "tofu"
    assert parse_senders({**TABLE, "mode": "permissive"}).mode == "permissive"


@pytest.mark.parametrize(
    ("data", "auth", "match"),
    [
        ({"a": {"source": CTL, "types": ["ground_truth"]}, "b": {"source": IMU, "types": ["stop"]}}, False,
         "control module only"),
        ({"a": {"source": CTL, "types": ["radar"]}}, False, "unknown type 'radar'"),
        ({"a": {"source": "localhost:1", "types": ["imu"]}}, False, "literal IP address"),
        ({"a": {"source": "127.0.0.1:0", "types": ["imu"]}}, False, "port must be in 1..65535"),
        ({"a": {"key_id": 3, "types": ["imu"]}}, False, "only with authenticated links"),
        ({"a": {"source": CTL, "types": ["imu"]}}, True, "KEY_ID"),
        ({"a": {"source": CTL, "key_id": 1, "types": ["imu"]}}, True, "exactly one of"),
        ({"a": {"source": CTL, "types": []}}, False, "non-empty list"),
        ({"a": {"source": CTL, "types": ["imu"], "port": 3}}, False, "senders.a.port: unknown key"),
        ({"a": {"source": CTL, "types": ["imu"]}, "b": {"source": CTL, "types": ["gps"]}}, False,
         "also senders.a"),
        ({"mode": "tofu", "a": {"source": CTL, "types": ["imu"]}}, False, "tofu learns"),
        ({"mode": "strict"}, False, "at least one"),
        ({"mode": "open"}, False, "senders.mode"),
        ({"warning_interval_s": -1}, False, "warning_interval_s"),
        ({"colour": "red"}, False, "senders.colour: unknown key"),
    ],
)
def test_bad_tables_are_one_line_errors_naming_the_key(data, auth, match):
    with pytest.raises(ConfigError, match=match):
        parse_senders(data, authenticated=auth)


def test_the_toml_file_and_overrides(tmp_path):
    p = tmp_path / "listener.toml"
    p.write_text(
        '[senders]\nwarning_interval_s = 2.0\n'
        f'[senders.control]\nsource = "{CTL}"\ntypes = ["ground_truth", "strobe", "stop"]\n'
        f'[senders.imu]\nsource = "{IMU}"\ntypes = ["imu"]\n'
    )
    cfg = load_config(p)
    assert cfg.senders.mode == "strict" and cfg.senders.warning_interval_s == 2.0
    assert {e.name for e in cfg.senders.entries} == {"control", "imu"}
    lab = load_config(p, ["senders.mode=permissive", 'senders.gnss.source="127.0.0.1:47003"',
                          'senders.gnss.types=["gps"]'])  # fmt: skip
    assert lab.senders.mode == "permissive" and len(lab.senders.entries) == 3
    keyed = config_from_dict(
        {"auth": {"enabled": True, "key_file": "k"}, "senders": {"ctl": {"key_id": 0, "types": ["stop"]}}}
    )
    assert keyed.senders.entries[0].source == "key:0"
    assert ListenerConfig().senders == SendersConfig()  # default: trust on first use


def test_source_strings():
    assert source_of(("127.0.0.1", 47000)) == "127.0.0.1:47000"
    assert source_of(("::1", 47000, 0, 0)) == "[::1]:47000"
    assert source_of(("10.0.0.1", 5), key_id=7) == "key:7"
    assert parse_senders({"a": {"source": "[::1]:5", "types": ["imu"]}}).entries[0].source == "[::1]:5"


# ---------------------------------------------------------------------------------------------- the table


def test_strict_table_accepts_its_entries_and_rejects_the_rest():
    table = SenderTable(parse_senders(TABLE))
    assert table.check(CTL, 8, 0.0) is None and table.check(CTL, 10, 0.0) is None
    assert table.check(GPS, 3, 0.0) is None
    assert table.check(GPS, 10, 0.1) == "sender_type"  # a module's own socket, not the control's type
    assert table.check("127.0.0.1:50000", 8, 0.2) == "sender_unknown"
    assert table.check("127.0.0.1:50000", 1, 0.3) == "sender_unknown"
    assert dict(table.rejected) == {"sender_type": 1, "sender_unknown": 2}
    events = [e for e in table.events if e["event"] == "sender_rejected"]
    assert [e["reason"] for e in events] == ["sender_type", "sender_unknown"]  # one per reason kind
    assert events[0]["allowed"] == [CTL] and events[0]["level"] == "warning"


def test_warnings_are_rate_limited_with_a_suppressed_count():
    table = SenderTable(parse_senders({**TABLE, "warning_interval_s": 10.0}))
    for i in range(50):
        table.check("127.0.0.1:50000", 8, i * 0.1)  # 5 s of one forgery every 0.1 s
    table.check("127.0.0.1:50000", 8, 10.5)
    events = [e for e in table.events if e["event"] == "sender_rejected"]
    assert len(events) == 2 and events[1]["suppressed"] == 49
    assert table.rejected["sender_unknown"] == 51  # the counter is never rate limited
    lim = WarningLimiter(1.0)
    assert lim.event("x", 0.0) is not None and lim.event("x", 0.5) is None and lim.event("y", 0.5)
    with pytest.raises(ConfigError):
        WarningLimiter(math.nan)


def test_tofu_binds_each_type_to_its_first_source_and_the_control_to_the_first_ground_truth():
    table = SenderTable()
    assert table.check(CTL, 10, 0.0) == "sender_unbound"  # STOP before any GROUND TRUTH
    assert table.check(CTL, 9, 0.0) is None  # STROBE: bound to the control socket
    assert table.check(IMU, 1, 0.1) is None
    assert table.check(CTL, 8, 0.2) is None  # first GROUND TRUTH: GROUND TRUTH and STOP to CTL
    bound = [e for e in table.events if e["event"] == "sender_bound"]
    assert [e["types"] for e in bound] == [["strobe"], ["imu"], ["ground_truth", "stop"]]
    assert table.check("127.0.0.1:50000", 8, 1.0) == "sender_unknown"  # GT from a new port
    assert table.check(IMU, 10, 1.1) == "sender_type"  # STOP from the IMU's socket
    assert table.check("127.0.0.1:50001", 1, 1.2) == "sender_unknown"  # a second IMU source
    assert table.check(CTL, 10, 1.3) is None
    assert table.stats()["bindings"] == {"imu": IMU, "ground_truth": CTL, "strobe": CTL, "stop": CTL}


def test_snapshot_restore_round_trip_through_json():
    table = SenderTable()
    for src, t in ((CTL, 8), (CTL, 9), (IMU, 1), (GPS, 3)):
        table.check(src, t, 0.0)
    snap = json.loads(json.dumps(table.snapshot()))
    restarted = SenderTable()
    assert restarted.restore(snap, now=5.0) == 5
    assert restarted.snapshot() == table.snapshot()
    assert restarted.check("127.0.0.1:50000", 8, 6.0) == "sender_unknown"  # still bound after restart
    assert restarted.check(CTL, 10, 6.0) is None
    assert restarted.events[0]["event"] == "sender_bindings_restored"
    # a configured table learns nothing and restores nothing
    assert SenderTable(parse_senders(TABLE)).restore(snap) == 0


@pytest.mark.parametrize(
    "snap",
    [
        None,
        {"version": 2, "bindings": {}},
        {"version": 1},
        {"version": 1, "bindings": {"radar": CTL}},
        {"version": 1, "bindings": {"imu": 5}},
        {"version": 1, "bindings": {"imu": "x" * 200}},
        {"version": 1, "bindings": {"ground_truth": CTL}},
        {"version": 1, "bindings": {"ground_truth": CTL, "stop": IMU}},
    ],
)
def test_a_malformed_snapshot_is_refused_and_changes_nothing(snap):
    table = SenderTable()
    table.check(IMU, 1, 0.0)
    before = table.snapshot()
    with pytest.raises(ConfigError, match="senders snapshot"):
        table.restore(snap)
    assert table.snapshot() == before


def test_permissive_accepts_counts_and_is_loud():
    table = SenderTable(parse_senders({**TABLE, "mode": "permissive"}))
    start = table.start_events(0.0)[0]
    assert start["level"] == "warning" and "PERMISSIVE" in start["warning"]
    assert table.check("127.0.0.1:50000", 10, 0.0) is None
    assert table.check(GPS, 8, 0.0) is None
    assert dict(table.would_reject) == {"sender_unknown": 1, "sender_type": 1} and not table.rejected
    assert {e["event"] for e in table.events} == {"sender_would_reject"}
    assert SenderTable(parse_senders(TABLE)).start_events(0.0)[0]["level"] == "info"
    assert SenderTable().start_events(0.0)[0]["level"] == "warning"  # TOFU says so at start


# ---------------------------------------------------------------------------------------------- pipeline


def _new_estimates(outputs):
    return [decode_output(o) for o in outputs]


def _attack(dgrams, after_s: float, make):
    """``dgrams`` with forged datagrams from ``make(t)`` ((addr, bytes) list) inserted ``after_s`` into
    the run."""
    forged_at = dgrams[0][0] + after_s
    out = [d for d in dgrams if d[0] < forged_at]
    out += [(forged_at, addr, data) for addr, data in make(forged_at)]
    out += [d for d in dgrams if d[0] >= forged_at]
    return out


def test_pipeline_rejects_a_ground_truth_from_a_new_port_and_keeps_tracking(track, run):  # noqa: F811
    dgrams = _datagrams(run)
    clean = Pipeline(track)
    base = _new_estimates(_feed(clean, dgrams))
    forged = GroundTruth(0, 10.0, 0.0, 0.0, 2000.0, None, None)
    attacked = _attack(dgrams, 20.0, lambda t: [(("127.0.0.1", 50000), encode_input(forged))])
    pipe = Pipeline(track)
    outs = _new_estimates(_feed(pipe, attacked))
    assert pipe.stopped
    assert pipe.rejected["sender_unknown"] == 1
    assert pipe.metrics()["senders"]["rejected"] == {"sender_unknown": 1}
    assert [(o.epoch, o.arc_length) for o in outs] == [(o.epoch, o.arc_length) for o in base]
    events = [e for e in pipe.take_events() if e["event"].startswith("sender")]
    assert any(e["event"] == "sender_rejected" and e["source"] == "127.0.0.1:50000" for e in events)
    # strobe, ground truth + stop (the control socket), imu, odometer, gps
    assert sum(e["event"] == "sender_bound" for e in events) == 5


def test_pipeline_ignores_a_stop_from_an_unknown_port(track, run):  # noqa: F811
    dgrams = _datagrams(run)
    attacked = _attack(dgrams, 15.0, lambda t: [(("127.0.0.1", 50000), encode_input(Stop(0)))])
    pipe = Pipeline(track)
    outs = _feed(pipe, [d for d in attacked if d[0] < dgrams[0][0] + 30.0])
    assert not pipe.stopped and len(outs) > 1000
    assert pipe.rejected["sender_unknown"] == 1
    assert pipe.counters["stops"] == 0


def test_a_configured_table_through_the_pipeline(track, run):  # noqa: F811
    dgrams = _datagrams(run)
    cfg = config_from_dict({"senders": TABLE})
    forged_stop = (("127.0.0.1", PORTS["gps"]), encode_input(Stop(4)))  # the GNSS socket sends STOP
    attacked = _attack(dgrams, 10.0, lambda t: [forged_stop])
    pipe = Pipeline(track, cfg)
    outs = _feed(pipe, attacked)
    assert pipe.stopped and pipe.counters["stops"] == 1  # only the control module's STOP at the end
    assert pipe.rejected["sender_type"] == 1
    assert len(outs) > 1000


MASTER = bytes(range(32))


def test_cross_key_forgeries_are_all_rejected(track, run, tmp_path):  # noqa: F811
    """Authenticated links: each module's key is bound to its types; a STOP or a GROUND TRUTH signed with
    the GNSS or IMU key (valid tags) is rejected, every one of them."""
    key_file = tmp_path / "master.key"
    key_file.write_text(MASTER.hex())
    cfg = ListenerConfig(auth=AuthSettings(enabled=True, key_file=str(key_file)))
    mid = {port: port - 47000 for port in PORTS.values()}  # ctl 0, imu 1, odo 2, gps 3
    counters: dict = {}
    good = []
    for t, addr, data in _datagrams(run):
        c = counters.setdefault(addr, EpochCounter(3))
        k = mid[addr[1]]
        good.append((t, addr, wrap(data, input_key(MASTER, k), c.epoch_for(input_seq(data)), key_id=k)))
    forged = []
    t0 = good[0][0]
    for i in range(100):
        t = t0 + 5.0 + i * 0.3
        k = 3 if i % 2 else 2  # the GNSS key, the odometer key
        # (epoch 3, SEQ below the legitimate start 65500): never used by the module itself and inside
        # its anti-replay window, so the tag and the window accept them: only the sender table is left
        seq = 65499 - i
        msg = Stop(seq) if i % 4 < 2 else GroundTruth(seq, 10.0, 0.0, 0.0, 2000.0, None, None)
        data = encode_input(msg)
        forged.append((t, ("127.0.0.1", 47000 + k), wrap(data, input_key(MASTER, k), 3, key_id=k)))
    mixed = sorted(good + forged, key=lambda r: r[0])
    clean = Pipeline(track, cfg, start_epoch=7)
    base = _new_estimates(o[6:24] for o in _feed(clean, good))
    pipe = Pipeline(track, cfg, start_epoch=7)
    outs = _new_estimates(o[6:24] for o in _feed(pipe, mixed))
    m = pipe.metrics()
    assert m["auth"]["input_accepted"] == len(good) + len(forged)  # the tags are valid...
    assert m["senders"]["rejected"] == {"sender_type": 100}  # ...and the table refuses all 100
    assert m["senders"]["bindings"]["stop"] == "key:0"
    assert pipe.counters["stops"] == 1 and pipe.stopped
    assert [(o.epoch, o.arc_length) for o in outs] == [(o.epoch, o.arc_length) for o in base]


def test_permissive_mode_through_the_pipeline_accepts_and_counts(track, run):  # noqa: F811
    dgrams = _datagrams(run)
    cfg = config_from_dict({"senders": {**TABLE, "mode": "permissive"}})
    forged_stop = (("127.0.0.1", 50000), encode_input(Stop(0)))
    pipe = Pipeline(track, cfg)
    _feed(pipe, _attack(dgrams, 10.0, lambda t: [forged_stop]))
    m = pipe.metrics()
    assert pipe.stopped and pipe.counters["stops"] == 1  # the lab mode let the forged STOP through...
    assert m["senders"]["would_reject"] == {"sender_unknown": 1}  # ...and counted it
    assert "sender_unknown" not in m["input"]["rejected_by_reason"]
    events = pipe.take_events()
    assert events[0]["event"] == "senders_mode" and "PERMISSIVE" in events[0]["warning"]
    assert any(e["event"] == "sender_would_reject" for e in events)
