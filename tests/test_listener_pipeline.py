"""Pipeline core with scripted time: datagrams in, OUTPUT_PROTOCOL out, counters, hostile input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from interface_modules.presets import GPS_PRESETS, IMU_PRESETS, ODOMETER_PRESETS
from listener.codec import (
    GpsFix,
    GroundTruth,
    ImuSample,
    OdometerSample,
    Stop,
    Strobe,
    decode_input,
    decode_output,
    encode_ack,
    encode_input,
)
from listener.config import LinkConfig, ListenerConfig, config_from_dict
from listener.pipeline import Pipeline
from sfa.measurements import GpsMeas, ImuMeas, InitMeas, OdoMeas
from sfa.synthetic import generate

PORTS = {"imu": 47001, "odo": 47002, "gps": 47003, "ctl": 47000}



@pytest.fixture(scope="module")
def run(track):
    return generate(
        track,
        1,
        40.0,
        IMU_PRESETS["mems-train"],
        ODOMETER_PRESETS["wheel-odometer"],
        GPS_PRESETS["standalone"],
        seed=3,
    )


def _datagrams(run, start_seq=65500, with_epochs=True):
    """Encode the synthetic measurements as the four interface modules would send them."""
    seqs = dict.fromkeys(PORTS, start_seq)
    out = []  # (arrival_time, (host, port), bytes)

    def emit(mod, msg_factory, t):
        seq = seqs[mod]
        seqs[mod] = (seq + 1) & 0xFFFF
        out.append((t + 0.0005, ("127.0.0.1", PORTS[mod]), encode_input(msg_factory(seq))))

    t_first = run.measurements[0].t_s
    next_strobe = math.floor(t_first)
    for m in run.measurements:
        while next_strobe <= m.t_s:
            emit("ctl", lambda q, ts=next_strobe: Strobe(q, float(ts)), next_strobe)
            next_strobe += 1.0
        ep = m.t_s if with_epochs else None
        if isinstance(m, InitMeas):
            emit(
                "ctl",
                lambda q, m=m: GroundTruth(q, m.speed_mps, 0.0, 0.0, m.arc_length_m, m.line_id, m.t_s),
                m.t_s,
            )
        elif isinstance(m, ImuMeas):
            emit("imu", lambda q, m=m, ep=ep: ImuSample(q, *m.f_mps2, *m.w_radps, ep), m.t_s)
        elif isinstance(m, OdoMeas):
            emit("odo", lambda q, m=m, ep=ep: OdometerSample(q, m.speed_mps, m.sigma_mps, ep), m.t_s)
        elif isinstance(m, GpsMeas):
            emit(
                "gps",
                lambda q, m=m, ep=ep: GpsFix(q, m.lat_deg, m.lon_deg, m.alt_m, 1, 12, m.sigma_h_m or 1.5, ep),
                m.t_s,
            )
    end = run.measurements[-1].t_s + 0.01
    emit("ctl", lambda q: Stop(q), end)
    out.sort(key=lambda r: r[0])
    return out


def _feed(pipe: Pipeline, datagrams, hostile=None):
    outputs = []
    for i, (t, addr, data) in enumerate(datagrams):
        if hostile is not None and i % 7 == 0:
            for junk in hostile(i):
                outputs.extend(pipe.receive(junk, addr if i % 2 else ("127.0.0.1", 50000 + i % 5), t))
        nxt = pipe.next_timer()
        if nxt is not None and nxt <= t:
            outputs.extend(pipe.handle_timer(t))
        outputs.extend(pipe.receive(data, addr, t))
    return outputs


def _pipeline(track, **link):
    cfg = ListenerConfig(link=LinkConfig(**link))
    return Pipeline(track, cfg)


def test_outputs_track_the_truth_and_wrap_seq(track, run):
    pipe = _pipeline(track, start_seq=65530)
    outputs = _feed(pipe, _datagrams(run))
    assert pipe.stopped
    assert len(outputs) > 3000
    msgs = [decode_output(o) for o in outputs]
    assert all(len(o) == 18 for o in outputs)
    seqs = [m.seq for m in msgs]
    assert seqs[0] == 65530
    assert all((b - a) & 0xFFFF == 1 for a, b in zip(seqs, seqs[1:], strict=False))
    assert 0 in seqs  # crossed the wrap
    epochs = np.array([m.epoch for m in msgs])
    assert np.all(np.diff(epochs) >= 0)
    s_true = np.interp(epochs, run.t_s, run.s_m)
    err = np.abs(np.array([m.arc_length for m in msgs]) - s_true)
    assert np.percentile(err, 95) < 2.0, np.percentile(err, 95)
    m = pipe.metrics()
    n_in = len(run.measurements)
    assert m["input"]["rejected"] == 0
    assert m["sequencing"]["lost"] == 0 and m["sequencing"]["duplicates"] == 0
    assert m["input"]["processed"] == n_in
    assert m["link"]["outputs"] == len(outputs)


def test_hostile_datagrams_change_nothing(track, run):
    clean = _feed(_pipeline(track), _datagrams(run))
    rng = np.random.default_rng(5)

    def hostile(i):
        return [
            b"",
            b"\x01",
            bytes(rng.integers(0, 256, size=int(rng.integers(1, 80)), dtype=np.uint8)),
            b"\x01\x00\x00\x00\x07" + b"\x00" * 55,  # IMU, 7 doubles announced, 55 bytes
            b"\x03\x05\x00\x00\x03" + np.array([float("nan"), 11.0, 100.0]).tobytes(),  # NaN lat
            b"\x63\x00\x00\x00\x00",  # unknown type 99
        ]

    pipe = _pipeline(track)
    dirty = _feed(pipe, _datagrams(run), hostile=hostile)
    assert dirty == clean
    m = pipe.metrics()["input"]
    assert m["rejected"] >= 5 * (len(_datagrams(run)) // 7)
    assert set(m["rejected_by_reason"]) >= {"short", "length", "non_finite", "type"}


def test_reordered_and_duplicated_stream_gives_the_same_estimates(track, run):
    dgrams = _datagrams(run)
    clean = [decode_output(o) for o in _feed(_pipeline(track), dgrams)]
    rng = np.random.default_rng(9)
    mixed = list(dgrams)
    # swap neighbours of the same sender (within the 30 ms hold) and duplicate some datagrams
    for i in range(0, len(mixed) - 3, 11):
        if mixed[i][1] == mixed[i + 2][1]:
            (t1, a1, d1), (t2, a2, d2) = mixed[i], mixed[i + 2]
            mixed[i], mixed[i + 2] = (t1, a2, d2), (t2, a1, d1)
    dups = [mixed[i] for i in rng.choice(len(mixed) - 1, 40, replace=False)]
    mixed = sorted(mixed + dups, key=lambda r: r[0])
    pipe = _pipeline(track)
    got = [decode_output(o) for o in _feed(pipe, mixed)]
    seq = pipe.metrics()["sequencing"]
    assert seq["duplicates"] == 40
    assert seq["lost"] == 0
    assert seq["reordered"] > 0
    # every measurement still reaches the filter exactly once
    assert pipe.metrics()["input"]["processed"] == len(run.measurements)
    # estimates agree with the in-order run once the reordering settles (same data, same filter)
    assert abs(got[-1].arc_length - clean[-1].arc_length) < 0.05


def test_undated_measurements_use_the_strobe_clock(track, run):
    dgrams = _datagrams(run, with_epochs=False)
    pipe = _pipeline(track)
    outputs = [decode_output(o) for o in _feed(pipe, dgrams)]
    m = pipe.metrics()
    assert m["input"]["dated_by_strobe"] > 3000
    epochs = np.array([o.epoch for o in outputs])
    s_true = np.interp(epochs, run.t_s, run.s_m)
    err = np.abs(np.array([o.arc_length for o in outputs]) - s_true)
    assert np.percentile(err, 95) < 2.0


def test_acks_drive_the_link(track, run):
    pipe = _pipeline(track)
    dgrams = _datagrams(run)
    outs = []
    for t, addr, data in dgrams[:2000]:
        outs.extend(pipe.receive(data, addr, t))
    last = decode_output(outs[-1]).seq
    pipe.receive_ack(encode_ack(last), dgrams[1999][0])
    m = pipe.metrics()["link"]
    assert m["acks"] == 1 and m["last_acked_seq"] == last and m["state"] == "up"
    pipe.receive_ack(b"\xff", dgrams[1999][0])
    assert pipe.metrics()["link"]["bad_acks"] == 1


def test_config_rejects_bad_values():
    from listener.errors import ConfigError

    for bad, key in [
        ({"input": {"port": 0}}, "input.port"),
        ({"input": {"hold_time_s": -1}}, "input.hold_time_s"),
        ({"link": {"down_after_s": 1.0, "degraded_after_s": 2.0}}, "link.down_after_s"),
        ({"link": {"nope": 1}}, "link.nope"),
        ({"link": {"max_rate_hz": "fast"}}, "link.max_rate_hz"),
        ({"link": {"max_rate_hz": float("nan")}}, "link.max_rate_hz"),
        ({"input": {"per_type_sequence": 1}}, "input.per_type_sequence"),
        ({"log": {"level": "chatty"}}, "log.level"),
        ({"bogus": 1}, "bogus"),
        ({"input": 3}, "input"),
        ({"filter": {"set": {"nope": 1.0}}}, "filter.set"),
        ({"filter": {"set": {"separation_window_s": -1.0}}}, "filter.set"),
        ({"filter": {"set": {"separation_window_s": "60"}}}, "filter.set.separation_window_s"),
        ({"filter": {"set": 3}}, "filter.set"),
    ]:
        with pytest.raises(ConfigError) as exc:
            config_from_dict(bad)
        assert str(exc.value).startswith(key), (bad, str(exc.value))


def test_filter_set_reaches_the_pipelines_filter(track):
    """``[filter.set]`` fields are applied on top of the preset, in the listener's own filter."""
    from listener.config import load_config

    cfg = load_config(None, ["filter.set.separation_window_s=60.0", "filter.set.gate_prob_gps=0.999"])
    assert cfg.filter.set == (("gate_prob_gps", 0.999), ("separation_window_s", 60.0))
    got = Pipeline(track, cfg).filter.config
    base = ListenerConfig().filter.filter_config()
    assert got == base.replace(separation_window_s=60.0, gate_prob_gps=0.999)
    assert got != base


def test_a_far_future_epoch_is_rejected_and_changes_nothing(track, run):
    """A bit flip can leave an epoch valid but far ahead: it must not drag the filter into the future."""
    clean = _feed(_pipeline(track), _datagrams(run))
    dgrams = _datagrams(run)
    # replace one IMU datagram in the middle by the same sample dated 1e5 s ahead (same seq)
    k = next(i for i in range(len(dgrams) // 2, len(dgrams)) if dgrams[i][2][0] == 1)
    from listener.codec import decode_input

    msg = decode_input(dgrams[k][2])
    bad = encode_input(ImuSample(msg.seq, msg.ax, msg.ay, msg.az, msg.gx, msg.gy, msg.gz, msg.epoch + 1e5))
    dgrams[k] = (dgrams[k][0], dgrams[k][1], bad)
    pipe = _pipeline(track)
    got = [decode_output(o) for o in _feed(pipe, dgrams)]
    m = pipe.metrics()["input"]
    assert m["rejected_by_reason"] == {"epoch_future": 1}
    # rejected after it was sequenced: counted once in the books (received = rejected on arrival +
    # sequenced), its SEQ given back
    assert m["rejected"] == m["rejected_after_sequencing"] == 1
    assert m["received"] == m["rejected"] - m["rejected_after_sequencing"] + sum(m["by_type"].values())
    ref = [decode_output(o) for o in clean]
    # the only difference is the one missing IMU sample: the run continues, close to the clean one
    assert max(o.epoch for o in got) == max(o.epoch for o in ref)
    assert abs(got[-1].arc_length - ref[-1].arc_length) < 0.05


# ---------------------------------------------------------------------------------------------- issue 20


def _outputs_around(outputs, t_split):
    epochs = np.array([decode_output(o).epoch for o in outputs])
    return int(np.sum((epochs >= t_split - 5) & (epochs < t_split))), int(
        np.sum((epochs >= t_split) & (epochs < t_split + 5))
    )


def test_forged_seq_jumps_do_not_silence_a_stream_and_are_warned_about(track, run):
    """Forged IMU datagrams with SEQ + 100 (inside max_backward) from the IMU's own port, one per second
    for 10 s: outputs per second before and after the first one stay the same, nothing is "late", and
    the warning goes out at most once per 10 s with the suppressed count."""
    dgrams = _datagrams(run)
    t0 = dgrams[0][0]
    imu_addr = ("127.0.0.1", PORTS["imu"])
    attacked = []
    next_forgery = t0 + 15.0
    last_imu = None
    for t, addr, data in dgrams:
        if addr == imu_addr:
            last_imu = int.from_bytes(data[1:3], "little")
        if t >= next_forgery and next_forgery < t0 + 25.0 and last_imu is not None:
            forged = ImuSample((last_imu + 100) & 0xFFFF, 0.0, 0.0, -9.81, 0.0, 0.0, 0.0, t - 0.0005)
            attacked.append((t, imu_addr, encode_input(forged)))
            next_forgery += 1.0
        attacked.append((t, addr, data))
    clean_outs = _feed(Pipeline(track), dgrams)
    pipe = Pipeline(track)
    outs = _feed(pipe, attacked)
    before, after = _outputs_around(outs, t0 + 15.0)
    clean_before, clean_after = _outputs_around(clean_outs, t0 + 15.0)
    assert (before, after) == (clean_before, clean_after)  # before the fix: about 20 % of them after
    seq = pipe.metrics()["sequencing"]
    assert (seq["late"], seq["lost"], seq["jump_drops"], seq["jumps_held"]) == (0, 0, 10, 10)
    held = [e for e in pipe.take_events() if e["event"] == "sequence_jump_held"]
    assert len(held) == 1 and held[0]["level"] == "warning"  # 10 within 10 s: one warning
    assert held[0]["stream"] == f"127.0.0.1:{PORTS['imu']}"


def test_a_content_rejection_does_not_use_up_the_sequence_number(track, run):
    """A forged GNSS fix with the next SEQ and an epoch a day ahead is rejected (epoch_future); the
    legitimate fix with that SEQ is then accepted, not dropped as a duplicate."""
    dgrams = _datagrams(run)
    t0 = dgrams[0][0]
    gps_addr = ("127.0.0.1", PORTS["gps"])
    k = next(i for i, (t, a, _) in enumerate(dgrams) if a == gps_addr and t - t0 > 10.0)
    legit = decode_input(dgrams[k][2])
    forged = GpsFix(legit.seq, legit.lat, legit.lon, legit.alt, 1, 12, 1.5, legit.epoch + 86400.0)
    attacked = [*dgrams[:k], (dgrams[k][0] - 0.001, gps_addr, encode_input(forged)), *dgrams[k:]]
    pipe = Pipeline(track)
    _feed(pipe, attacked)
    m = pipe.metrics()
    assert m["input"]["rejected_by_reason"]["epoch_future"] == 1
    assert m["sequencing"]["duplicates"] == 0 and m["sequencing"]["reopened"] == 1
    clean = Pipeline(track)
    _feed(clean, dgrams)
    assert m["filter"]["outcomes"] == clean.metrics()["filter"]["outcomes"]  # every fix processed


# ---------------------------------------------------------------------------------------------- batches


def test_count_batch_books_what_receive_books(track, run):
    """Pipeline.count_batch (the compiled replay's and the service's bulk counts) books a batch under the
    names and rules the per-datagram path uses: a run through ``receive`` (junk and a far-future epoch
    included) and a fresh pipeline given only the counts of what happened (seen from the codec and the
    pipeline's hooks, not its counters) report the same input, outcome, sequencing and link counters."""
    from collections import Counter

    from listener.errors import DecodeError
    from listener.pipeline import BatchCounts

    dgrams = _datagrams(run)
    k = next(i for i in range(len(dgrams) // 2, len(dgrams)) if dgrams[i][2][0] == 1)
    msg = decode_input(dgrams[k][2])
    bad = encode_input(ImuSample(msg.seq, msg.ax, msg.ay, msg.az, msg.gx, msg.gy, msg.gz, msg.epoch + 1e5))
    dgrams[k] = (dgrams[k][0], dgrams[k][1], bad)
    junk = [b"", b"\x01\x00", b"\x63\x00\x00\x00\x00", b"\x01\x00\x00\x00\x07" + b"\x00" * 55]
    pipe = _pipeline(track)
    outcomes: Counter = Counter()
    new_outputs = []
    pipe.on_update = lambda u: outcomes.update([(u.kind, u.outcome)])
    pipe.on_output = lambda seq, est: new_outputs.append(seq)
    sent = _feed(pipe, dgrams, hostile=lambda i: junk)
    assert pipe.stopped and outcomes and new_outputs

    rejected: Counter = Counter()
    for _ in range(0, len(dgrams), 7):  # (_feed: the junk before every 7th datagram)
        for data in junk:
            try:
                decode_input(data)
            except DecodeError as exc:
                rejected[exc.reason] += 1
    types = Counter(data[0] for _, _, data in dgrams)
    counts = BatchCounts(
        received=len(dgrams) + sum(rejected.values()),
        rejected=rejected,
        by_type=types,
        in_order=len(dgrams),
        strobes=types[9],
        stops=types[10],
        dated_by_epoch=len(dgrams) - types[9] - types[10] - 1,
        epoch_future=1,
        outcomes=outcomes,
        outputs=len(new_outputs),
        retransmits=len(sent) - len(new_outputs),
    )
    booked = _pipeline(track)
    booked.count_batch(counts)
    a, b = pipe.metrics(), booked.metrics()
    assert a["input"] == b["input"]
    assert a["input"]["rejected_by_reason"]["epoch_future"] == 1 and a["input"]["processed"] > 3000
    assert a["filter"]["outcomes"] == b["filter"]["outcomes"]
    for key in ("received", "released", "in_order"):
        assert a["sequencing"][key] == b["sequencing"][key], key
    for key in ("outputs", "retransmits"):
        assert a["link"][key] == b["link"][key], key
    assert booked.link.next_seq == pipe.link.next_seq
    # nothing to count books nothing: no counter appears at 0
    empty = _pipeline(track)
    empty.count_batch(BatchCounts())
    assert empty.metrics() == _pipeline(track).metrics()
    assert not empty.counters and not empty.rejected and not empty.by_type
