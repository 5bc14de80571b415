"""Fast replay (tools.fast_replay): equal to the exact replay on clean captures, falls back otherwise.

The capture is a real simulator capture (``sfa sim regional-long --duration 60``: a single line, every
measurement with its epoch, STROBEs and a STOP), replayed by both paths in the same test.
"""

from __future__ import annotations

import dataclasses
import math
import struct
import subprocess
import sys

import dpkt
import numpy as np
import pytest
from helpers_capture import frame_ethernet, write_capture
from hypothesis import given, settings
from hypothesis import strategies as st

from interface_modules import capture as sim_capture
from interface_modules.capture import datagrams_of, lossy
from interface_modules.offline import generate
from interface_modules.scenario import load_scenario
from interface_modules.tracks import database_path
from listener.codec import (
    INPUT_FORMS,
    DecodeError,
    GroundTruth,
    Stop,
    decode_input,
    encode_input,
    input_layout,
)
from listener.config import (
    ClockConfig,
    FilterSelection,
    ListenerConfig,
    MergeConfig,
    PlausibilityConfig,
    VitalConfig,
    config_from_dict,
)
from tools.capture_reader import CaptureStats, read_capture
from tools.fast_decode import decode_bytes
from tools.fast_ingest import unique_few
from tools.fast_pcap import scan_capture
from tools.fast_replay import try_fast_replay
from tools.replay import ReplayOptions, replay_capture
from track_db import TrackDatabase

SECTIONS = ("input", "sequencing", "clock", "merge", "filter", "senders")


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    d = tmp_path_factory.mktemp("fast")
    subprocess.run(
        [sys.executable, "-m", "sfa", "sim", "regional-long", "--duration", "60", "--out-dir", str(d)],
        check=True,
        capture_output=True,
        timeout=300,
    )
    track = TrackDatabase.open(database_path(load_scenario("regional-long")))
    stats = CaptureStats()
    dgrams = [(g.time_s, g.src, g.payload) for g in read_capture(d / "capture.pcap", 48000, stats)]
    yield {"dir": d, "cap": d / "capture.pcap", "track": track, "dgrams": dgrams}
    track.close()


@pytest.fixture(scope="module")
def tram(tmp_path_factory):
    """The Jena tram over its first 8 min (line 2 passes junctions with other lines: branch hypotheses)."""
    d = tmp_path_factory.mktemp("tram")
    subprocess.run(
        [sys.executable, "-m", "sfa", "sim", "tram-urban", "--duration", "480", "--out-dir", str(d)],
        check=True,
        capture_output=True,
        timeout=300,
    )
    sc = load_scenario("tram-urban")
    track = TrackDatabase.open(database_path(sc))
    sel = FilterSelection(imu=sc.imu.preset, odometer=sc.odometer.preset, gps=sc.gps.preset)
    yield {
        "cap": d / "capture.pcap",
        "track": track,
        "opts": ReplayOptions(config=ListenerConfig(filter=sel)),
    }
    track.close()


@pytest.fixture(scope="module")
def strobe_dated(tmp_path_factory):
    """60 s of the E1 regional line with every sensor's epoch left out (the thesis's sensors' form):
    the listener dates each measurement with the STROBE clock at its arrival."""
    d = tmp_path_factory.mktemp("strobe")
    sc = sim_capture.strobe_dated(dataclasses.replace(load_scenario("regional-long"), max_duration_s=60.0))
    dgrams = datagrams_of(generate(sc))
    write_capture(d / "capture.pcap", dgrams)
    track = TrackDatabase.open(database_path(sc))
    sel = FilterSelection(imu=sc.imu.preset, odometer=sc.odometer.preset, gps=sc.gps.preset)
    yield {"cap": d / "capture.pcap", "dgrams": dgrams, "track": track, "sel": sel}
    track.close()


def assert_same(exact, fast) -> None:
    """New estimates, per-measurement updates, GNSS rows and counters identical, bit for bit."""
    a, b = exact.new_estimates(), fast.new_estimates()
    assert a.keys() == b.keys()
    assert a["epoch"].size > 1000
    for k in a:
        assert a[k].dtype == b[k].dtype, k
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)  # NaN == NaN here, values bitwise
    for k in exact.estimates:  # every output datagram, retransmissions included (estimates.csv)
        np.testing.assert_array_equal(exact.estimates[k], fast.estimates[k], err_msg=k)
    np.testing.assert_array_equal(exact.reasons, fast.reasons)  # (the Parquet file's reasons)
    for k in exact.updates:
        np.testing.assert_array_equal(exact.updates[k], fast.updates[k], err_msg=k)
    for k in exact.gps:
        np.testing.assert_array_equal(exact.gps[k], fast.gps[k], err_msg=k)
    for sec in SECTIONS:
        assert exact.metrics[sec] == fast.metrics[sec], sec
    # the link's counters (new outputs sent, resends of the newest, ...), but for the state the
    # compiled path does not simulate after the prefix (the fast result leaves those out)
    not_simulated = {k.removeprefix("link.") for k in fast.metrics["fast_replay"]["not_simulated"]}
    link = {k: v for k, v in exact.metrics["link"].items() if k not in not_simulated}
    assert link == fast.metrics["link"]
    assert {"outputs", "retransmits"} <= link.keys()
    assert exact.capture == fast.capture
    assert exact.datagrams == fast.datagrams


def test_fast_equals_exact_on_a_clean_capture(sim):
    opts = ReplayOptions()
    exact = replay_capture(sim["cap"], sim["track"], opts)
    fast, info = try_fast_replay(sim["cap"], sim["track"], opts)
    assert info.used, info.reason
    assert info.compiled > 3 * info.exact_prefix  # most of the capture ran compiled
    assert fast is not None
    assert_same(exact, fast)
    assert exact.metrics["input"]["stops"] == 1  # the run ends at the simulator's STOP


def test_filter_inputs_are_the_rows_the_filter_processed(sim):
    rec: dict = {}
    fast, info = try_fast_replay(sim["cap"], sim["track"], ReplayOptions(), filter_inputs=rec)
    assert info.used, info.reason
    n = rec["kind"].size
    assert n > 0 and rec["t"].shape == (n,) and rec["vals"].shape[0] == n
    # after the exact prefix, one update per packed row, in the same order and at the same times
    assert np.array_equal(fast.updates["t"][-n:], rec["t"])
    names = {1: "imu", 2: "odo", 3: "gps"}
    assert list(fast.updates["kind"][-n:]) == [names[int(k)] for k in rec["kind"]]


def test_fast_equals_exact_through_junctions_and_stops(tram):
    """Junction windows: TrackFilter spawns the branches (Python, the track database) and its compiled
    loop (sfa.bank) carries the hypotheses on several lines and the standstill reversal hypotheses:
    nothing after the prefix goes through TrackFilter.process. Same estimates, bit for bit."""
    exact = replay_capture(tram["cap"], tram["track"], tram["opts"])
    fast, info = try_fast_replay(tram["cap"], tram["track"], tram["opts"])
    assert info.used, info.reason
    assert fast is not None
    assert_same(exact, fast)
    fr = fast.metrics["fast_replay"]
    assert fr["handed_back_at_junctions"] >= 1  # TrackFilter did spawn branches at a junction
    assert info.python_steps == 0  # (the GROUND TRUTH is in the prefix; no time jump on this capture)
    assert info.compiled > 0.5 * fast.datagrams  # and most of the capture still ran compiled
    assert fr["compiled_fraction"] == pytest.approx(info.compiled / fast.datagrams)
    assert fast.metrics["filter"]["counters"]["initialisations"] >= 1


def test_strobe_dated_measurements_take_the_compiled_path(strobe_dated):
    """No epoch in any IMU, odometer or GNSS datagram: each is dated by the STROBE clock at its arrival
    (listener.pipeline's _date), in compiled code after the hand-over; bit-identical to the exact replay."""
    opts = ReplayOptions(config=ListenerConfig(filter=strobe_dated["sel"]))
    exact = replay_capture(strobe_dated["cap"], strobe_dated["track"], opts)
    fast, info = try_fast_replay(strobe_dated["cap"], strobe_dated["track"], opts)
    assert info.used, info.reason
    assert fast is not None
    assert info.compiled > 0.99 * fast.datagrams
    counted = exact.metrics["input"]
    assert counted["dated_by_strobe"] > 7000 and counted["dated_by_epoch"] == 1  # the GROUND TRUTH's
    assert_same(exact, fast)


@pytest.mark.parametrize("max_undated", [512, 40])
def test_undated_queue_before_the_first_strobe(strobe_dated, tmp_path, max_undated):
    """The first STROBEs lost at the start: the measurements before the first STROBE wait in the
    listener's undated queue (at most clock.max_pending_undated, the oldest dropped beyond) and are
    dated when it comes. That start runs through the exact pipeline, the rest compiled; identical."""
    dgrams = list(strobe_dated["dgrams"])
    t0 = dgrams[0][0]
    late = [d for d in dgrams if not (d[2][0] == 9 and d[0] - t0 < 2.5)]
    cap = tmp_path / "late-strobe.pcap"
    write_capture(cap, _resequence(late))  # a STROBE module that starts late, not lost datagrams
    cfg = ListenerConfig(filter=strobe_dated["sel"], clock=ClockConfig(max_pending_undated=max_undated))
    opts = ReplayOptions(config=cfg)
    exact = replay_capture(cap, strobe_dated["track"], opts)
    fast, info = try_fast_replay(cap, strobe_dated["track"], opts)
    assert info.used, info.reason
    first_strobe = next(i for i, d in enumerate(late) if d[2][0] == 9)
    assert first_strobe > 200 and info.exact_prefix == first_strobe + 1
    overflow = exact.metrics["input"]["undated_overflow"]
    assert (overflow > 0) == (max_undated < first_strobe)
    assert_same(exact, fast)


def _resequence(dgrams):
    """Renumber every sender's SEQ consecutively (after datagrams were added or removed)."""
    nxt: dict = {}
    out = []
    for t, addr, p in dgrams:
        seq = nxt.get(addr, struct.unpack("<H", p[1:3])[0])
        out.append((t, addr, p[:1] + struct.pack("<H", seq & 0xFFFF) + p[3:]))
        nxt[addr] = seq + 1
    return out


def test_reinitialisation_and_a_time_jump_go_through_trackfilter(sim, tmp_path):
    """A second GROUND TRUTH (both senses of travel again) and 15 s without any datagram (the filter's
    time-jump rule) used to send the whole capture to the exact replay; now only those rows do."""
    dgrams = list(sim["dgrams"])
    t0, gt_addr, gt = dgrams[0]
    assert gt[0] == 8 and struct.unpack("<BHBB", gt[:5])[2:] == (1, 5)
    k = next(i for i, d in enumerate(dgrams) if d[0] - t0 >= 20.0 and d[2][0] == 1)
    imu_epoch = struct.unpack("<7d", dgrams[k][2][5:])[6]
    fields = list(struct.unpack("<BHBBi5d", gt))
    fields[-1] = imu_epoch + 0.001
    again = (dgrams[k][0] + 1e-4, gt_addr, struct.pack("<BHBBi5d", *fields))
    out = dgrams[: k + 1] + [again] + [d for d in dgrams[k + 1 :] if not 35.0 <= d[0] - t0 < 50.0]
    cap = tmp_path / "reinit-gap.pcap"
    write_capture(cap, _resequence(out))
    # the filter alone (vital supervision off): with it, the 15 s silence latches the decay state
    # (LOST on the listener's timer), which the compiled path does not model: see the next test
    # and the GROUND TRUTH guard off: this second GROUND TRUTH (the first one's arc length again, 20 s
    # later) disagrees with the NOMINAL filter, which the guard holds for confirmation (below)
    opts = ReplayOptions(config=ListenerConfig(vital=VitalConfig(enabled=False),
                                               plausibility=PlausibilityConfig(enabled=False)))
    exact = replay_capture(cap, sim["track"], opts)
    fast, info = try_fast_replay(cap, sim["track"], opts)
    assert info.used, info.reason
    assert_same(exact, fast)
    counters = exact.metrics["filter"]["counters"]
    assert counters["initialisations"] == 2 and counters["time_jumps_rejected"] == 1
    # the silences: the OBCU link resends the newest estimate (while younger than max_output_age_s),
    # rows of estimates.csv the fast path writes too, after the hand-over (assert_same: every row)
    assert 0 < exact.metrics["link"]["retransmits"] == fast.metrics["fast_replay"]["retransmissions_added"]
    assert 2 <= info.python_steps < 0.2 * fast.datagrams
    # with the supervision on (the default) the fast path declines, and the exact replay withholds
    # the standard output once decay latches (no standstill + GROUND TRUTH follows)
    fast_on, info_on = try_fast_replay(cap, sim["track"], ReplayOptions())
    assert fast_on is None and "vital supervision" in info_on.reason
    on = replay_capture(cap, sim["track"], ReplayOptions())
    assert on.metrics["link"]["outputs"] < exact.metrics["link"]["outputs"]
    assert on.metrics["link"]["withheld"] > 0
    assert on.metrics["vital"]["decay"]["latched"]  # (this capture latches first on a long slip)
    # with the GROUND TRUTH guard on (the default) the far second GROUND TRUTH is held, not applied:
    # the exact replay runs (the compiled path does not model the guard)
    guarded = ReplayOptions(config=ListenerConfig(vital=VitalConfig(enabled=False)))
    fast_g, info_g = try_fast_replay(cap, sim["track"], guarded)
    assert fast_g is None and "resilience" in info_g.reason
    held = replay_capture(cap, sim["track"], guarded)
    assert held.metrics["filter"]["counters"]["initialisations"] == 1
    assert held.metrics["resilience"]["ground_truth"]["held"] == 1


@pytest.mark.parametrize(("tail_s", "vital"), [(1.6, True), (3.2, False)])
def test_resends_after_the_last_estimate(sim, tmp_path, tail_s, vital):
    """A capture cut 30 s in whose sensors then fall silent, with STROBEs going on for ``tail_s``: the
    link resends the last estimate every 0.5 s while it is younger than max_output_age_s; with the vital
    supervision on, the listener's timer withholds it once the filter, propagated to a module's
    time-out, is LOST. The fast path writes the same resend rows (assert_same: every row of
    estimates.csv)."""
    dgrams = list(sim["dgrams"])
    t0 = dgrams[0][0]
    cut = [d for d in dgrams if d[0] - t0 < 30.0 or (d[2][0] == 9 and d[0] - t0 < 30.0 + tail_s)]
    cap = tmp_path / "tail.pcap"
    write_capture(cap, cut)
    opts = ReplayOptions(config=ListenerConfig(vital=VitalConfig(enabled=vital)))
    exact = replay_capture(cap, sim["track"], opts)
    fast, info = try_fast_replay(cap, sim["track"], opts)
    assert info.used, info.reason
    assert exact.metrics["link"]["retransmits"] == (1 if vital else 2)  # (LOST at the odometer's time-out)
    assert_same(exact, fast)


@pytest.mark.parametrize(("stype", "seconds"), [(3, 6.0), (1, 1.0)])
def test_a_single_silent_sensor_keeps_the_fast_path(sim, tmp_path, stype, seconds):
    """GNSS silent for 6 s (past its 3 s time-out), or the IMU for 1 s with the odometer going on: the
    listener's timer reports DEGRADED between measurements, but with the standard output and the
    default decay reasons nothing sent changes, so the fast path is used and equals the exact replay."""
    dgrams = list(sim["dgrams"])
    t0 = dgrams[0][0]
    cut = [d for d in dgrams if not (d[2][0] == stype and 30.0 <= d[0] - t0 < 30.0 + seconds)]
    cap = tmp_path / f"silent-{stype}.pcap"
    write_capture(cap, _resequence(cut))  # a sensor that stops sending, not lost datagrams
    exact = replay_capture(cap, sim["track"], ReplayOptions())
    fast, info = try_fast_replay(cap, sim["track"], ReplayOptions())
    assert info.used, info.reason
    assert_same(exact, fast)
    vital = exact.metrics["vital"]
    base = replay_capture(sim["cap"], sim["track"], ReplayOptions()).metrics["vital"]
    assert vital["counters"]["timer_checks"] > base["counters"]["timer_checks"]  # it ran for the silence
    # decay only at the capture's end: every sensor stops some 0.5 s before the simulator's STOP
    last_sensor = max(t for t, _, p in cut if p[0] in (1, 2, 3))
    assert not vital["decay"]["latched"] or vital["decay"]["entered_at"] > last_sensor


def test_vital_reason_runs_of_decay_reasons():
    """The DEGRADED-run rule of vital_reason looks at the reasons of the rows: a long run of a reason
    that is not a decay reason (a GNSS rejection) keeps the fast path, one of a decay reason does not,
    and a module never heard (its time-out is not a failed sensor) does not count."""
    from types import SimpleNamespace

    from sfa.layout import R_GNSS_REJECTING, R_IMU_TIMEOUT
    from tools.fast_replay import vital_reason

    n = 200
    epoch = 1000.0 + 0.1 * np.arange(n)  # 20 s of outputs
    result = SimpleNamespace(estimates={"status": np.full(n, 2, dtype=np.int64), "epoch": epoch})
    arrivals = np.arange(0.0, 20.0, 0.01)
    got = SimpleNamespace(m_time=np.concatenate((arrivals, arrivals)),
                          kind=np.concatenate((np.full(arrivals.size, 1), np.full(arrivals.size, 2))))
    opts = ReplayOptions()
    assert vital_reason(got, result, opts, np.full(n, R_GNSS_REJECTING)) == ""
    assert "decay reason" in vital_reason(got, result, opts, np.full(n, R_IMU_TIMEOUT))
    assert "decay reason" in vital_reason(got, result, opts, np.full(n, -1))  # not recorded: any
    no_imu = SimpleNamespace(m_time=arrivals, kind=np.full(arrivals.size, 2))
    assert vital_reason(no_imu, result, opts, np.full(n, R_IMU_TIMEOUT)) == ""


def test_future_epochs_are_rejected_identically(sim, tmp_path):
    """Epochs far ahead of the STROBE clock (e.g. a flipped exponent bit) are rejected as epoch_future by
    the listener; the fast path drops the same measurements from its packed rows (updates, estimates
    and counters as the exact replay's)."""
    dgrams = list(sim["dgrams"])
    t0 = dgrams[0][0]
    imu = [i for i, (t, _, p) in enumerate(dgrams) if p[0] == 1 and t - t0 >= 10.0]
    out = list(dgrams)
    for k in (imu[0], imu[1], imu[2000]):
        t, addr, p = out[k]
        fields = list(struct.unpack("<BHBB7d", p))
        fields[-1] += 1.0e5  # the epoch, a day ahead
        out[k] = (t, addr, struct.pack("<BHBB7d", *fields))
    cap = tmp_path / "future.pcap"
    write_capture(cap, out)
    exact = replay_capture(cap, sim["track"], ReplayOptions())
    fast, info = try_fast_replay(cap, sim["track"], ReplayOptions())
    assert info.used, info.reason
    assert info.exact_prefix < imu[0]  # the rejected rows are in the compiled part
    assert exact.metrics["input"]["rejected_by_reason"]["epoch_future"] == 3
    assert_same(exact, fast)


def test_the_sender_table_applies_to_the_capture(sim, tmp_path):
    """A forged GROUND TRUTH (arc 2000 m) and STOP from a port the capture's control module does not use:
    the replay binds the senders as the listener does (trust on first use) and rejects both, so the
    estimates are the clean capture's; the compiled path cannot count per datagram and falls back."""
    dgrams = list(sim["dgrams"])
    t0 = dgrams[0][0]
    k = next(i for i, (t, _, _) in enumerate(dgrams) if t - t0 >= 20.0)
    gt = GroundTruth(0, 10.0, 0.0, 0.0, 2000.0, None, None)
    forged = [
        (dgrams[k][0], ("127.0.0.1", 50000), encode_input(gt)),
        (dgrams[k + 500][0], ("127.0.0.1", 50000), encode_input(Stop(1))),
    ]
    cap = tmp_path / "forged.pcap"
    write_capture(cap, sorted(dgrams + forged, key=lambda r: r[0]))
    clean = replay_capture(sim["cap"], sim["track"], ReplayOptions())
    exact = replay_capture(cap, sim["track"], ReplayOptions())
    assert exact.metrics["input"]["rejected_by_reason"]["sender_unknown"] == 2
    assert exact.metrics["input"]["stops"] == 1
    a, b = clean.new_estimates(), exact.new_estimates()
    for col in ("epoch", "arc_length", "status"):
        np.testing.assert_array_equal(a[col], b[col], err_msg=col)
    fast, info = try_fast_replay(cap, sim["track"], ReplayOptions())
    assert fast is None and "sender table" in info.reason
    # a configured table the capture follows keeps the compiled path (the same table, the same code)
    sources = {}
    for _, addr, p in dgrams:
        sources.setdefault(p[0], set()).add(f"{addr[0]}:{addr[1]}")
    assert all(len(v) == 1 for v in sources.values())  # one source per type in the simulator's capture
    names = {1: "imu", 2: "odometer", 3: "gps", 8: "ground_truth", 9: "strobe", 10: "stop"}
    table: dict = {}
    for t, (src,) in sources.items():
        table.setdefault(src, []).append(names[t])
    cfg = config_from_dict({"senders": {f"s{i}": {"source": src, "types": types}
                                        for i, (src, types) in enumerate(table.items())}})  # fmt: skip
    opts = ReplayOptions(config=cfg)
    fast, info = try_fast_replay(sim["cap"], sim["track"], opts)
    assert info.used, info.reason
    assert_same(replay_capture(sim["cap"], sim["track"], opts), fast)


def _bad_payloads() -> list[bytes]:
    """One datagram per rejection reason the codec has (none touches the sequence buffers)."""
    imu = struct.pack("<BHBB7d", 1, 7, 0, 7, 0.1, 0.0, -9.8, 0.0, 0.0, 0.0, 1.7e9)
    return [
        b"\x01\x00",  # short
        imu[:-1],  # length
        struct.pack("<BHBB", 42, 0, 0, 0),  # unknown type
        struct.pack("<BHBB2d", 1, 7, 0, 2, 0.0, 0.0),  # form (IMU with 2 doubles)
        struct.pack("<BHBB7d", 1, 7, 0, 7, math.nan, 0.0, -9.8, 0.0, 0.0, 0.0, 1.7e9),  # non-finite
        struct.pack("<BHBB3d", 2, 7, 0, 3, 999.0, 0.1, 1.7e9),  # odometer speed out of range
        struct.pack("<BHBB2i5d", 3, 7, 2, 5, 9, 8, 50.0, 11.0, 100.0, 2.0, 1.7e9),  # fix quality 9
    ]


def test_invalid_datagrams_are_counted_identically(sim, tmp_path):
    dgrams = list(sim["dgrams"])
    bad = _bad_payloads()
    out = []
    for i, (t, addr, p) in enumerate(dgrams):
        out.append((t, addr, p))
        if i in (100, 4000, 4500):  # one batch in the exact prefix, two in the compiled part
            out += [(t + 1e-6 * (k + 1), ("127.0.0.1", 47999), b) for k, b in enumerate(bad)]
    cap = tmp_path / "bad.pcap"
    write_capture(
        cap, out, extra=[(dgrams[50][0] + 1e-7, frame_ethernet(("127.0.0.1", 5353), 5353, b"mdns"))]
    )
    exact = replay_capture(cap, sim["track"], ReplayOptions())
    fast, info = try_fast_replay(cap, sim["track"], ReplayOptions())
    assert info.used, info.reason
    assert info.exact_prefix < 4000
    reasons = exact.metrics["input"]["rejected_by_reason"]
    assert sum(reasons.values()) == 3 * len(bad)
    assert len(reasons) >= 5
    assert exact.capture["skipped"] == {"other_port": 1}
    assert_same(exact, fast)


@pytest.mark.parametrize("dating", ["epoch", "strobe"])
def test_loss_duplicates_and_reordering_take_the_compiled_path(sim, strobe_dated, tmp_path, dating):
    """The listener's own sequence buffers (listener.seqbuf, the prefix pipeline's objects) take every
    datagram after the hand-over, with the replay's timer polls; the measurements they release go on
    compiled, in the merge's order. Identical to the exact replay, with epochs and STROBE-dated."""
    base = sim if dating == "epoch" else strobe_dated
    opts = ReplayOptions() if dating == "epoch" else ReplayOptions(config=ListenerConfig(filter=base["sel"]))
    cap = tmp_path / "lossy.pcap"
    write_capture(cap, lossy(base["dgrams"]))
    exact = replay_capture(cap, base["track"], opts)
    fast, info = try_fast_replay(cap, base["track"], opts)
    assert info.used, info.reason
    seq = exact.metrics["sequencing"]
    assert min(seq["reordered"], seq["duplicates"], seq["lost"]) > 40
    assert info.compiled > 0.99 * fast.datagrams
    assert_same(exact, fast)


def test_senders_restarting_take_the_compiled_path(strobe_dated, tmp_path):
    """The IMU, odometer and GNSS interface modules restart mid-run (STROBE-dated capture): each falls
    silent for 0.8 s and comes back numbering from a new start, behind or far ahead of where it was,
    with 1 % loss, duplicates and reordering throughout. The listener's sequence buffers put each
    restarted sender on probation and resynchronise it; the compiled replay takes every datagram after
    the hand-over through those same buffers and gives the exact replay's outputs bit for bit."""
    dgrams = strobe_dated["dgrams"]
    t0 = dgrams[0][0]
    # type: (restart time [s], first number after it): behind by more than max_backward, or far ahead
    restarts = {1: (20.0, 7), 2: (28.0, 60000), 3: (35.0, 30000)}
    first_seq: dict[int, int] = {}
    out = []
    for t, addr, payload in dgrams:
        kind = payload[0]
        if kind in restarts:
            at, start = restarts[kind]
            if at <= t - t0 < at + 0.8:
                continue  # the module is down
            if t - t0 >= at + 0.8:
                seq = struct.unpack_from("<H", payload, 1)[0]
                first_seq.setdefault(kind, seq)
                renumbered = (start + seq - first_seq[kind]) & 0xFFFF
                payload = payload[:1] + struct.pack("<H", renumbered) + payload[3:]
        out.append((t, addr, payload))
    cap = tmp_path / "restarts.pcap"
    write_capture(cap, lossy(out))
    opts = ReplayOptions(config=ListenerConfig(filter=strobe_dated["sel"]))
    exact = replay_capture(cap, strobe_dated["track"], opts)
    fast, info = try_fast_replay(cap, strobe_dated["track"], opts)
    assert info.used, info.reason
    assert exact.metrics["sequencing"]["resyncs"] >= 3
    assert info.compiled > 0.99 * fast.datagrams
    assert_same(exact, fast)


def test_sequence_repair_through_junctions_and_held_jumps(tram, tmp_path):
    """The Jena tram with 1 % loss, duplicates and reordering: junction hand-overs to TrackFilter and
    forward jumps the buffers hold as suspects (listener.seqbuf's trust rules) in one capture."""
    dgrams = [(g.time_s, g.src, g.payload) for g in read_capture(tram["cap"], 48000, CaptureStats())]
    cap = tmp_path / "tram-lossy.pcap"
    write_capture(cap, lossy(dgrams, seed=5))
    exact = replay_capture(cap, tram["track"], tram["opts"])
    fast, info = try_fast_replay(cap, tram["track"], tram["opts"])
    assert info.used, info.reason
    assert exact.metrics["sequencing"]["jumps_held"] >= 1
    assert fast.metrics["fast_replay"]["handed_back_at_junctions"] >= 1
    assert_same(exact, fast)


def test_a_content_rejection_with_sequence_repair_falls_back(sim, tmp_path):
    """An epoch_future rejection gives its SEQ back to the sequence buffer (``reopen``), which the
    compiled path does not follow when the buffers repair the stream: the exact replay runs."""
    dgrams = list(sim["dgrams"])
    t0 = dgrams[0][0]
    k = next(i for i, (t, _, p) in enumerate(dgrams) if p[0] == 1 and t - t0 >= 10.0)
    fields = list(struct.unpack("<BHBB7d", dgrams[k][2]))
    fields[-1] += 1.0e5
    dgrams[k] = (dgrams[k][0], dgrams[k][1], struct.pack("<BHBB7d", *fields))
    cap = tmp_path / "future-lossy.pcap"
    write_capture(cap, lossy(dgrams))
    result, info = try_fast_replay(cap, sim["track"], ReplayOptions())
    assert result is None and "epoch_future" in info.reason


#: capture forms other tools write (tests/helpers_capture.write_capture options)
FORMS = {
    "pcapng": {"pcapng": True},
    "nanosecond": {"nano": True},
    "big-endian nanosecond": {"big_endian": True, "nano": True},
    "802.1Q VLAN": {"vlan": [(0x8100, 5)]},
    "802.1ad QinQ": {"vlan": [(0x88A8, 7), (0x8100, 5)]},
    "IPv6": {"ipv6": True},
    "pcapng VLAN IPv6": {"pcapng": True, "vlan": [(0x8100, 3)], "ipv6": True},
}


#: Ethernet frames without an IP packet, as a NIC capture has them: ARP (and one cut short), LLDP, a
#: VLAN-tagged ARP, a type-0 frame (dpkt: "unknown type")
NOT_IP_FRAMES = (
    b"\xff" * 6 + b"\x02" * 6 + b"\x08\x06" + bytes(28),
    b"\xff" * 6 + b"\x02" * 6 + b"\x08\x06" + bytes(5),
    b"\x01\x80\xc2\x00\x00\x0e" + b"\x02" * 6 + b"\x88\xcc" + bytes(20),
    b"\xff" * 12 + b"\x81\x00\x00\x05\x08\x06" + bytes(28),
    bytes(14),
)


@pytest.mark.parametrize("form", list(FORMS))
def test_capture_forms_take_the_compiled_path(sim, tmp_path, form):
    """pcapng, nanosecond and big-endian pcap, VLAN tags and IPv6 frames are read by the compiled walk as
    the exact replay's dpkt reader reads them (timestamps to the bit, IPv6 source addresses, frames to
    other ports skipped and counted alike): the replay is identical to the exact one."""
    dgrams = sim["dgrams"][:3000]
    other = frame_ethernet(("127.0.0.1", 5353), 5353, b"mdns", vlan=FORMS[form].get("vlan", ()),
                           ipv6=FORMS[form].get("ipv6", False))  # fmt: skip
    cap = tmp_path / "capture.cap"
    write_capture(cap, dgrams, extra=[(dgrams[700][0] + 1e-7, f) for f in (other, *NOT_IP_FRAMES)],
                  **FORMS[form])  # fmt: skip
    exact = replay_capture(cap, sim["track"], ReplayOptions())
    fast, info = try_fast_replay(cap, sim["track"], ReplayOptions())
    assert info.used, info.reason
    assert info.compiled > 0.9 * fast.datagrams
    assert exact.capture["skipped"] == {"other_port": 1, "not_ip": len(NOT_IP_FRAMES)}
    if FORMS[form].get("ipv6"):  # the senders bound (trust on first use) by their IPv6 addresses
        assert all("fd00::" in str(v) for v in fast.metrics["senders"]["bindings"].values())
    assert_same(exact, fast)


def test_strobe_dated_pcapng_with_vlan(strobe_dated, tmp_path):
    """The thesis's form (no epochs) in a pcapng of VLAN-tagged frames: compiled, identical."""
    cap = tmp_path / "strobe.pcapng"
    write_capture(cap, strobe_dated["dgrams"], pcapng=True, vlan=[(0x8100, 12)])
    opts = ReplayOptions(config=ListenerConfig(filter=strobe_dated["sel"]))
    exact = replay_capture(cap, strobe_dated["track"], opts)
    fast, info = try_fast_replay(cap, strobe_dated["track"], opts)
    assert info.used, info.reason
    assert exact.metrics["input"]["dated_by_strobe"] > 7000
    assert_same(exact, fast)


def _small_captures() -> dict[str, bytes]:
    import tempfile
    from pathlib import Path

    dgrams = [(1.7e9 + 0.01 * i, ("127.0.0.1", 40000 + i % 3), bytes([1, i, 0, 0, 7]) + bytes(56))
              for i in range(12)]  # fmt: skip
    out = {}
    with tempfile.TemporaryDirectory() as d:
        for name, form in FORMS.items():
            path = Path(d) / "c.cap"
            write_capture(path, dgrams, extra=[(dgrams[4][0] + 1e-7, NOT_IP_FRAMES[0])], **form)
            out[name] = path.read_bytes()
    return out


_SMALL = _small_captures()


_EDITS = st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 255)), min_size=1, max_size=4)


@settings(max_examples=300, deadline=None)
@given(form=st.sampled_from(sorted(_SMALL)), edits=_EDITS, cut=st.integers(0, 10**6))
def test_the_compiled_walk_reads_damaged_files_as_dpkt_does(form, edits, cut):
    """Bytes of a small capture of each form overwritten (and the file cut): whenever the compiled walk
    reads the file, it returns what the exact replay's dpkt reader returns (every datagram, its
    timestamp, port and payload, the skip counts, the records); otherwise it gives a reason."""
    import tempfile
    from collections import Counter
    from pathlib import Path

    from tools.errors import CaptureError
    from tools.fast_pcap import SKIP_REASONS

    raw = bytearray(_SMALL[form])
    for at, value in edits:
        raw[at % len(raw)] = value
    if cut % 5 == 0:
        raw = raw[: cut % len(raw)]
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "c.cap"
        path.write_bytes(bytes(raw))
        scan = scan_capture(path, 48000)
        if isinstance(scan, str):
            return
        stats = CaptureStats()
        try:
            ref = list(read_capture(path, 48000, stats))
        except CaptureError as exc:  # pragma: no cover - a file the walk read must be a capture
            raise AssertionError(f"the walk read a file the exact reader refuses: {exc}") from exc
        assert scan.time_s.size == len(ref)
        for k, g in enumerate(ref):
            o, n = int(scan.offset[k]), int(scan.length[k])
            assert (scan.time_s[k], int(scan.src_port[k]), bytes(scan.data[o : o + n])) == (
                g.time_s, g.src[1], g.payload)
        assert Counter(SKIP_REASONS[int(c)] for _, c in scan.skipped_at) == stats.skipped
        assert scan.frames == stats.frames


@given(sec=st.integers(0, 2**32 - 1), nsec=st.integers(0, 2**32 - 1))
def test_nanosecond_timestamps_as_dpkt(sec, nsec):
    """dpkt reads a nanosecond pcap's timestamp as sec + Decimal(nsec) / Decimal("1E9") and the exact
    replay takes float() of it: the compiled walk's integer rounding gives the same double (NaN only
    below 1 s, which it refuses)."""
    from decimal import Decimal

    from tools.fast_ingest import nano_timestamp

    want = float(sec + Decimal(nsec) / Decimal("1E9"))
    got = nano_timestamp(sec, nsec)
    if want < 1.0:
        assert math.isnan(got)
    else:
        assert got == want


def test_falls_back_for_other_files_and_options(sim, tmp_path):
    raw_ip = tmp_path / "raw.pcap"
    with open(raw_ip, "wb") as fh:  # link type raw IP (tcpdump on a tunnel): the exact reader reads it
        w = dpkt.pcap.Writer(fh, linktype=dpkt.pcap.DLT_RAW)
        for t, _, p in sim["dgrams"][:50]:
            w.writepkt(frame_ethernet(("127.0.0.1", 40000), 48000, p)[14:], ts=t)
    result, info = try_fast_replay(raw_ip, sim["track"], ReplayOptions())
    assert result is None and f"link type {dpkt.pcap.DLT_RAW}" in info.reason
    hop = tmp_path / "hop-by-hop.pcap"  # an IPv6 extension header (dpkt.ip6.EXT_HDRS)
    frame = bytearray(frame_ethernet(("127.0.0.1", 40000), 48000, sim["dgrams"][3][2], ipv6=True))
    frame[14 + 6] = 0  # next header: hop-by-hop options
    write_capture(hop, sim["dgrams"][:20], extra=[(sim["dgrams"][5][0] + 1e-7, bytes(frame))])
    result, info = try_fast_replay(hop, sim["track"], ReplayOptions())
    assert result is None and "extension headers" in info.reason
    held = ReplayOptions(config=ListenerConfig(merge=MergeConfig(hold_s=0.1)))
    result, info = try_fast_replay(sim["cap"], sim["track"], held)
    assert result is None and "hold_s" in info.reason
    result, info = try_fast_replay(sim["cap"], sim["track"], ReplayOptions(sensors=frozenset({"imu"})))
    assert result is None and "sensor" in info.reason
    odd = tmp_path / "stp.pcap"  # an 802.3/LLC frame (spanning tree): dpkt's LLC reading is not followed
    stp = b"\x01\x80\xc2\x00\x00\x00" + b"\x02" * 6 + b"\x00\x26" + b"\x42\x42\x03" + bytes(35)
    write_capture(odd, sim["dgrams"][:20], extra=[(sim["dgrams"][5][0] + 1e-7, stp)])
    assert "802.3/LLC" in scan_capture(odd, 48000)


def test_scan_equals_the_dpkt_reader(sim):
    scan = scan_capture(sim["cap"], 48000)
    assert not isinstance(scan, str)
    assert scan.time_s.size == len(sim["dgrams"])
    for k in (0, 1, 777, len(sim["dgrams"]) - 1):
        t, (host, port), payload = sim["dgrams"][k]
        assert scan.time_s[k] == t  # same float operations as dpkt: bit-identical
        assert int(scan.src_port[k]) == port
        o = int(scan.offset[k])
        assert bytes(scan.data[o : o + int(scan.length[k])]) == payload
    assert scan.skipped_at.shape[0] == 0


def _forms():
    return st.sampled_from(INPUT_FORMS)


_values = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(min_value=-200.0, max_value=200.0),
    st.sampled_from([0.0, -0.0, 1e10, 1e10 + 1.0, 90.0, 180.0, -1000.0, 150.0, 100000.0, 1.7e9]),
)


@given(form=_forms(), data=st.data(), cut=st.integers(min_value=-2, max_value=2))
def test_compiled_decoder_agrees_with_the_codec(form, data, cut):
    stype, n_int, n_double = form
    names = input_layout(stype, n_int, n_double)
    ints = [
        data.draw(st.integers(min_value=-(2**31), max_value=2**31 - 1) | st.integers(0, 300))
        for _ in range(n_int)
    ]
    dbls = [data.draw(_values) for _ in range(n_double)]
    payload = struct.pack(
        f"<BHBB{n_int}i{n_double}d",
        int(stype),
        data.draw(st.integers(0, 65535)),
        n_int,
        n_double,
        *ints,
        *dbls,
    )
    if cut < 0:
        payload = payload[:cut]
    elif cut > 0:
        payload = payload + b"\x00" * cut
    dec = decode_bytes([payload])
    try:
        msg = decode_input(payload)
    except DecodeError:
        assert not dec.ok[0]  # the compiled pass never accepts what the codec rejects
        return
    assert dec.ok[0]  # ... nor rejects what it accepts
    assert int(dec.stype[0]) == int(stype) and int(dec.seq[0]) == msg.seq
    for j, name in enumerate(names):
        assert dec.values[0, j] == float(getattr(msg, name)), name


@given(st.binary(max_size=80))
def test_compiled_decoder_on_arbitrary_bytes(payload):
    dec = decode_bytes([payload])
    try:
        decode_input(payload)
        accepted = True
    except DecodeError:
        accepted = False
    assert bool(dec.ok[0]) == accepted


def test_bad_files_fall_back_with_a_reason(sim, tmp_path):
    raw = sim["cap"].read_bytes()
    cut = tmp_path / "cut.pcap"
    cut.write_bytes(raw[: len(raw) // 2 + 7])  # tcpdump killed mid-record
    result, info = try_fast_replay(cut, sim["track"], ReplayOptions())
    assert result is None and "truncated" in info.reason
    for path, words in ((tmp_path, "cannot map"), (tmp_path / "missing.pcap", "cannot stat")):
        result, info = try_fast_replay(path, sim["track"], ReplayOptions())
        assert result is None and words in info.reason


@given(st.lists(st.integers(-(2**62), 2**62), max_size=40), st.integers(0, 2**32 - 1), st.integers(0, 300),
       st.sampled_from([1, 3, 32]))  # fmt: skip
def test_unique_few_is_np_unique(values, seed, n, most):
    """The senders' key dedup of the ingest (a pass per distinct value) gives np.unique's values, first
    indices and inverse, with few values and beyond ``most``."""
    rng = np.random.default_rng(seed)
    pool = np.asarray(values, dtype=np.int64)
    key = pool[rng.integers(0, len(values), n)] if values else pool
    want = np.unique(key, return_index=True, return_inverse=True)
    got = unique_few(key, most)
    assert all(np.array_equal(a, b) for a, b in zip(got, want, strict=True))
