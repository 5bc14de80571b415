"""listener.checkpoint: the document (checksum, version), the assessment at start, the seed, the resume
guard; TrackFilter.seed; a pipeline resumed from another pipeline's checkpoint (scripted time)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_listener_pipeline import _datagrams, _feed

from interface_modules.presets import GPS_PRESETS, IMU_PRESETS, ODOMETER_PRESETS
from listener import checkpoint as ck
from listener.codec import decode_output
from listener.config import CheckpointConfig, ListenerConfig
from listener.pipeline import Pipeline
from sfa.filter import TrackFilter
from sfa.layout import FilterStatus, Outcome
from sfa.measurements import InitMeas
from sfa.synthetic import generate


@pytest.fixture(scope="module")
def run(track):
    return generate(track, 1, 60.0, IMU_PRESETS["mems-train"], ODOMETER_PRESETS["wheel-odometer"],
                    GPS_PRESETS["standalone"], seed=21)


#: a sender table's snapshot as the checkpoint carries it (listener.senders.SenderTable.snapshot)
_SENDERS = {"version": 1, "mode": "tofu", "bindings": {"imu": "127.0.0.1:47001"}}
_STATE = {"t_s": 1020.0, "line_id": 1, "s_m": 150.0, "v_mps": 10.0, "direction": 1, "sigma_s_m": 0.5,
          "sigma_v_mps": 0.05, "errors": {"odo_scale": [0.01, 0.002]}, "status": 1}


def _body(track, **over):
    body = {
        "track": ck.track_fingerprint(track),
        "taken": {"monotonic": 100.0, "wall": 1.7e9, "boot_id": "b1"},
        "filter": dict(_STATE),
        "link": {"next_seq": 65000},
        "auth": None,
        "extra": {"senders": _SENDERS},
    }
    body.update(over)
    return body


# ---------------------------------------------------------------- document
def test_document_round_trip_and_refusals(track):
    body = _body(track)
    data = ck.encode(body)
    assert ck.decode(data) == body
    doc = json.loads(data)
    doc["body"]["filter"]["s_m"] = 151.0  # edited without the checksum
    with pytest.raises(ck.CheckpointError) as e:
        ck.decode(json.dumps(doc).encode())
    assert e.value.reason == "checksum"
    doc = json.loads(data)
    doc["version"] = 2
    with pytest.raises(ck.CheckpointError, match="version"):
        ck.decode(json.dumps(doc).encode())
    for bad, reason in ((b"", "corrupt"), (data[: len(data) // 2], "corrupt"), (b"[1]", "format"),
                        (b"\xff\xfe", "corrupt")):
        with pytest.raises(ck.CheckpointError) as e:
            ck.decode(bad)
        assert e.value.reason == reason


@given(st.data())
@settings(max_examples=300, deadline=None)
def test_any_corruption_is_refused_or_harmless(data):
    """One flipped byte anywhere: refused with a reason, or (a whitespace flip) the very same body."""
    body = {"track": "abc", "taken": {"monotonic": 1.5, "wall": 2.5}, "filter": None,
            "link": {"next_seq": 7}, "auth": None, "extra": {}}
    raw = bytearray(ck.encode(body))
    i = data.draw(st.integers(0, len(raw) - 1))
    raw[i] ^= data.draw(st.integers(1, 255))
    try:
        got = ck.decode(bytes(raw))
    except ck.CheckpointError as exc:
        assert exc.reason in ("corrupt", "format", "version", "checksum")
    else:
        assert got == body


# ---------------------------------------------------------------- assessment
def test_assess_ages_by_monotonic_time_within_one_boot(track):
    fp = ck.track_fingerprint(track)
    cfg = CheckpointConfig(max_age_s=10.0, seq_skip=4096)
    plan = ck.assess(_body(track), track_fp=fp, wall_now=0.0, mono_now=103.0, boot_id="b1", config=cfg)
    assert plan.elapsed_s == pytest.approx(3.0)  # the (wrong) wall clock was not used
    assert plan.next_seq == (65000 + 4096) & 0xFFFF  # wraps, and is "newer" in serial arithmetic
    assert 0 < (plan.next_seq - 65000) & 0xFFFF < 32768
    assert plan.extra == {"senders": _SENDERS}
    other_boot = ck.assess(_body(track), track_fp=fp, wall_now=1.7e9 + 4.0, mono_now=5.0, boot_id="b2",
                           config=cfg)
    assert other_boot.elapsed_s == pytest.approx(4.0)


@pytest.mark.parametrize(
    ("change", "reason"),
    [
        ({"mono_now": 111.0}, "stale"),
        ({"mono_now": 90.0}, "future"),
        ({"track_fp": "0000"}, "track"),
    ],
)
def test_assess_refuses_with_a_reason(track, change, reason):
    kw = {"track_fp": ck.track_fingerprint(track), "wall_now": 0.0, "mono_now": 101.0, "boot_id": "b1"}
    kw.update(change)
    with pytest.raises(ck.CheckpointError) as e:
        ck.assess(_body(track), **kw, config=CheckpointConfig(max_age_s=10.0))
    assert e.value.reason == reason


@pytest.mark.parametrize(
    "over",
    [{"taken": {"wall": "x"}}, {"filter": {"t_s": 1.0}}, {"link": {"next_seq": 70000}},
     {"filter": {**_STATE, "t_s": float("nan")}}, {"filter": {**_STATE, "direction": 2}}],
)
def test_assess_refuses_malformed_parts(track, over):
    body = _body(track)
    body.update(over)
    with pytest.raises(ck.CheckpointError) as e:
        ck.assess(body, track_fp=ck.track_fingerprint(track), wall_now=1.7e9 + 1, mono_now=101.0,
                  boot_id="b2")
    assert e.value.reason == "corrupt"


# ---------------------------------------------------------------- seed
def test_seed_widens_by_the_gap_times_the_line_speed_and_refuses_a_clock_reset():
    state = {**_STATE, "v_mps": -10.0, "direction": -1}
    cfg = CheckpointConfig(clock_tolerance_s=2.0, max_accel_mps2=3.0, max_sigma_m=500.0)
    seed = ck.seed_values(state, 1022.5, 2.4, rate=1.0, max_speed_mps=20.0, config=cfg)
    assert seed.gap_s == pytest.approx(2.5)
    assert seed.arc_length_m == pytest.approx(150.0 - 25.0)  # carried at its speed (decreasing s)
    assert seed.speed_mps == pytest.approx(10.0)  # forward speed
    assert seed.sigma_s_m == pytest.approx(math.hypot(0.5, 2.5 * 20.0))
    assert seed.sigma_v_mps == pytest.approx(math.hypot(0.05, 7.5))
    with pytest.raises(ck.CheckpointError) as e:  # sensor time went on 30 s while 2.4 s passed
        ck.seed_values(state, 1050.0, 2.4, rate=1.0, max_speed_mps=20.0, config=cfg)
    assert e.value.reason == "clock"
    with pytest.raises(ck.CheckpointError) as e:  # 6 s at 100 m/s: sigma 600 m > max_sigma_m 500 m
        ck.seed_values(state, 1026.0, 6.0, rate=1.0, max_speed_mps=100.0, config=cfg)
    assert e.value.reason == "uncertain"


def test_track_filter_seed(track):
    filt = TrackFilter(track)
    upd = filt.seed(1000.0, 1, 300.0, 8.0, 1, 40.0, 2.0, {"odo_scale": (0.02, 0.001)})
    assert upd.outcome == Outcome.INITIALISED and filt.initialised
    est = filt.estimate()
    assert est.arc_length_m == 300.0 and est.speed_mps == pytest.approx(8.0) and est.line_id == 1
    assert est.sigma_s_m == pytest.approx(40.0)
    assert est.status == FilterStatus.DEGRADED  # 40 m > degraded_sigma_m
    x, P = filt.state()
    assert x[3] == 0.02 and P[3, 3] == pytest.approx(1e-6)
    bads = ((math.nan, 1, 3.0, 1.0, 1, 1.0, 1.0, None), (1000.0, 1, 3.0, 1.0, 2, 1.0, 1.0, None),
            (1000.0, 1, 3.0, 1.0, 1, -1.0, 1.0, None), (1000.0, 1, 3.0, 1.0, 1, 1.0, 1.0, {"nope": (1, 1)}))
    for bad in bads:
        f2 = TrackFilter(track)
        assert f2.seed(*bad).outcome == Outcome.INVALID and not f2.initialised


def test_resume_guard_keeps_degraded_until_gnss_and_odometer_anchor():
    from sfa.filter import Estimate

    est = Estimate(1.0, 10.0, 5.0, 1.0, 8.0, 12.0, FilterStatus.NOMINAL, (), 1, 0.0, 0.0)
    guard = ck.ResumeGuard(CheckpointConfig(reanchor_gnss=1, reanchor_odometer=2))
    assert guard.overlay(est) is est  # inactive: untouched
    guard.start(0.0)
    for kind in ("odo", "odo", "imu"):
        guard.on_update(kind, True)
        out = guard.overlay(est)
        assert out.status == FilterStatus.DEGRADED and ck.RESUMED in out.reasons
    guard.on_update("gps", False)  # a gated fix does not anchor
    assert guard.overlay(est).status == FilterStatus.DEGRADED
    guard.on_update("gps", True)
    assert guard.overlay(est) is est and not guard.active


def test_checkpointer_once_per_interval():
    c = ck.Checkpointer(CheckpointConfig(interval_s=1.0))
    taken = []
    for k in range(1000):
        now = k * 0.013
        if c.due(now):
            c.mark(now)
            taken.append(now)
    assert len(taken) == 13 and all(0.99 < b - a < 1.02 for a, b in zip(taken, taken[1:], strict=False))


# ---------------------------------------------------------------- pipelines
def _until(pipe, dgrams, t_end):
    """Feed until arrival t_end, running due timers (checkpoints) on the way; the outputs."""
    return _feed(pipe, [d for d in dgrams if d[0] < t_end])


def test_a_pipeline_resumes_from_another_pipelines_checkpoint(track, run):
    dgrams = [d for d in _datagrams(run, start_seq=10) if d[2][0] != 10]  # without the final STOP
    t0 = dgrams[0][0]
    cut, gap = t0 + 30.0, 2.0
    a = Pipeline(track, ListenerConfig())
    a.resilience.enable_checkpoints(t0)
    out_a = _until(a, dgrams, cut)
    assert a.resilience.checkpointer.taken == 29  # once a second, driven by now
    body = a.resilience.take_checkpoint()
    assert body is not None and body["filter"]["status"] == int(FilterStatus.NOMINAL)
    last_seq = decode_output(out_a[-1]).seq
    body["taken"].update(wall=1.7e9, boot_id="b")
    plan = ck.assess(ck.decode(ck.encode(body)), track_fp=ck.track_fingerprint(track),
                     wall_now=1.7e9 + 1.0 + gap, mono_now=0.0, boot_id=None, config=CheckpointConfig())
    b = Pipeline(track, ListenerConfig())
    seen = []
    b.on_output = lambda seq, est: seen.append((seq, est))
    b.resilience.resume(plan, cut + gap)
    out_b = _feed(b, [d for d in dgrams if d[0] >= cut + gap])
    assert b.resilience.counters["resumed"] == 1
    first = decode_output(out_b[0])
    # the first output within one IMU period of the first datagram after the gap; SEQ continues past
    # every SEQ the first pipeline could have sent since its checkpoint
    assert first.epoch - (cut + gap - t0 + run.t_s[0]) < 0.02
    assert 0 < (first.seq - last_seq) & 0xFFFF < 32768
    assert first.seq == (body["link"]["next_seq"] + CheckpointConfig().seq_skip) & 0xFFFF
    statuses = [(est.status, est.reasons) for _, est in seen]
    assert statuses[0][0] == FilterStatus.DEGRADED and ck.RESUMED in statuses[0][1]
    k = next(i for i, (s_, r) in enumerate(statuses) if ck.RESUMED not in r)
    assert seen[k][1].epoch_s - seen[0][1].epoch_s < 3.0  # re-anchored by GNSS and the odometer
    assert statuses[-1][0] == FilterStatus.NOMINAL
    msgs = [decode_output(o) for o in out_b]
    epochs = np.array([m.epoch for m in msgs])
    err = np.abs(np.array([m.arc_length for m in msgs]) - np.interp(epochs, run.t_s, run.s_m))
    assert err.max() < 3.0 * math.hypot(0.5, gap * 44.5)  # inside the widened interval throughout
    assert np.percentile(err[epochs > epochs[0] + 5.0], 95) < 2.0
    assert [e["event"] for e in b.take_events()].count("resumed") == 1


def test_a_checkpoint_of_a_reset_sensor_clock_is_refused_and_ground_truth_awaited(track, run):
    dgrams = [d for d in _datagrams(run, start_seq=10) if d[2][0] != 10]
    t0 = dgrams[0][0]
    a = Pipeline(track, ListenerConfig())
    _until(a, dgrams, t0 + 20.0)
    body = a.resilience.body(t0 + 20.0)
    body["taken"].update(wall=1.7e9)
    # 40 s said to have passed (the wall clock), but the measurements go on 2 s later: a clock mismatch
    plan = ck.assess(body, track_fp=ck.track_fingerprint(track), wall_now=1.7e9 + 2.0, mono_now=0.0,
                     boot_id=None, config=CheckpointConfig(max_age_s=60.0))
    b = Pipeline(track, ListenerConfig())
    b.resilience.resume(plan, t0 + 20.0)
    b.resilience._gap0 = 40.0
    out = _feed(b, [d for d in dgrams if d[0] >= t0 + 22.0])
    assert out == [] and not b.filter.initialised
    assert b.resilience.counters["refused_clock"] == 1
    assert any(e["event"] == "checkpoint_refused" and e["reason"] == "clock" for e in b.take_events())
    assert b.metrics()["filter"]["outcomes"].get("imu_not_initialised", 0) > 100


def test_ground_truth_first_supersedes_the_checkpoint(track, run):
    dgrams = [d for d in _datagrams(run, start_seq=10) if d[2][0] != 10]
    b = Pipeline(track, ListenerConfig())
    body = _body(track)
    plan = ck.assess(body, track_fp=ck.track_fingerprint(track), wall_now=0.0, mono_now=101.0,
                     boot_id="b1")
    b.resilience.resume(plan, dgrams[0][0])
    _feed(b, dgrams[:200])  # the capture starts with its GROUND TRUTH
    assert b.resilience.counters["resume_superseded"] == 1 and b.resilience.counters["resumed"] == 0
    est = b.filter.estimate()
    assert est.arc_length_m == pytest.approx(np.interp(est.epoch_s, run.t_s, run.s_m), abs=1.0)
    assert isinstance(run.measurements[0], InitMeas)


def test_anti_replay_state_survives_a_restart(track):
    """Authenticated links: the windows and the output epoch go through the checkpoint document; a
    datagram accepted before the checkpoint is a replay after the restore, the sender's next is not."""
    from listener.auth import AuthError, AuthReason, wrap
    from listener.auth_link import LinkAuth, input_key
    from listener.codec import Strobe, encode_input

    master = bytes(range(32))
    key = input_key(master, 3)
    first = LinkAuth(master, start_epoch=100)
    sent = [wrap(encode_input(Strobe(k, 1000.0 + k)), key, 7, key_id=3) for k in range(50)]
    for d in sent[:40]:
        first.open_input(d, ("127.0.0.1", 1))
    first.seal_output(b"\x00\x00" + bytes(16), 0)
    saved = json.loads(json.dumps(first.export_state()))  # as the checkpoint file carries it
    second = LinkAuth(master, start_epoch=50)  # a wall clock that went back
    second.restore_state(saved)
    for d, why in ((sent[39], AuthReason.REPLAY), (sent[5], AuthReason.REPLAY)):
        with pytest.raises(AuthError) as e:
            second.open_input(d, ("127.0.0.1", 9))  # from another address: the module's window
        assert e.value.reason == why
    small = LinkAuth(master)
    small.input_state.cfg = small.input_state.cfg.__class__(window=16)
    small.restore_state(saved)
    with pytest.raises(AuthError) as e:
        small.open_input(sent[2], ("127.0.0.1", 9))
    assert e.value.reason == AuthReason.OLD
    assert second.open_input(sent[40], ("127.0.0.1", 1))[0] == 9  # the sender's next: accepted
    assert second.output_epoch.epoch == 101  # past the saved one, never reused
    with pytest.raises(ValueError):
        second.restore_state({"input": [["x", -1, "zz"]]})


def test_datagrams_accepted_after_the_last_checkpoint_are_not_accepted_again(track):
    """kill -9 between two checkpoints: what the process accepted after the last one is not in the saved
    window. Each window is saved with its advance over the last interval and skips that (+1) on the
    restore, so those datagrams stay replays; the sender's later datagrams pass."""
    from listener.auth import AuthError, AuthReason, wrap
    from listener.auth_link import RESUME_SKIP_FACTOR, LinkAuth, input_key
    from listener.codec import Strobe, encode_input

    master = bytes(range(32))
    key = input_key(master, 3)
    sent = [wrap(encode_input(Strobe(k, 1000.0 + k)), key, 7, key_id=3) for k in range(200)]
    first = LinkAuth(master)
    for d in sent[:40]:
        first.open_input(d, ("127.0.0.1", 1))
    first.export_state()  # checkpoint 1 (no advance known yet)
    for d in sent[40:80]:
        first.open_input(d, ("127.0.0.1", 1))
    saved = json.loads(json.dumps(first.export_state()))  # checkpoint 2: advanced by 40
    assert saved["input"][0][3] == 40
    for d in sent[80:110]:  # accepted after the last checkpoint, then killed
        first.open_input(d, ("127.0.0.1", 1))
    second = LinkAuth(master)
    second.restore_state(saved)
    skip_to = 79 + math.ceil(40 * RESUME_SKIP_FACTOR) + 1
    for d in (sent[80], sent[109], sent[skip_to]):
        with pytest.raises(AuthError) as e:
            second.open_input(d, ("127.0.0.1", 9))
        assert e.value.reason == AuthReason.REPLAY
    assert second.open_input(sent[skip_to + 1], ("127.0.0.1", 1))[0] == 9
    with pytest.raises(ValueError, match="advance"):
        LinkAuth(master).restore_state({"input": [[3, 5, "1", -2]]})


def test_checkpoint_path_and_atomic_write(tmp_path):
    from listener.service import checkpoint_path, write_atomic

    cfg = ListenerConfig()
    assert checkpoint_path(cfg, {}) is None  # no path, no STATE_DIRECTORY: no checkpoint
    assert checkpoint_path(cfg, {"STATE_DIRECTORY": "/var/lib/sfa:/var/lib/other"}) == \
        __import__("pathlib").Path("/var/lib/sfa/listener-checkpoint.json")
    explicit = ListenerConfig(checkpoint=CheckpointConfig(path=str(tmp_path / "c.json")))
    assert checkpoint_path(explicit, {"STATE_DIRECTORY": "/x"}) == tmp_path / "c.json"
    assert checkpoint_path(ListenerConfig(checkpoint=CheckpointConfig(enabled=False, path="/y")), {}) is None
    target = tmp_path / "c.json"
    for k in range(3):
        write_atomic(target, ck.encode({"k": k}))
        assert ck.decode(target.read_bytes()) == {"k": k}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.json"]  # no temporary file left behind


def test_the_sender_bindings_survive_a_restart_and_a_malformed_table_refuses_the_checkpoint(track):
    """Trust on first use: the bindings learned before the crash are the restarted listener's, and a
    checkpoint whose sender table is malformed is refused (corrupt) rather than half restored."""
    a = Pipeline(track, ListenerConfig())
    a.senders.restore(_SENDERS)
    saved = a.checkpoint_extra["senders"][0]()
    assert saved["bindings"] == {"imu": "127.0.0.1:47001"}
    b = Pipeline(track, ListenerConfig())
    good = ck.assess(_body(track), track_fp=ck.track_fingerprint(track), wall_now=0.0, mono_now=101.0,
                     boot_id="b1")
    b.resilience.resume(good, 0.0)
    assert b.senders.snapshot()["bindings"] == {"imu": "127.0.0.1:47001"}
    bad = _body(track)
    bad["extra"] = {"senders": {"version": 99}}
    c = Pipeline(track, ListenerConfig())
    plan = ck.assess(bad, track_fp=ck.track_fingerprint(track), wall_now=0.0, mono_now=101.0, boot_id="b1")
    with pytest.raises(ck.CheckpointError, match="senders"):
        c.resilience.resume(plan, 0.0)
