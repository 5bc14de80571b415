"""The compiled sequence buffers (listener.seqbuf over listener.seq_core) against the Python
implementation they replaced (tests/seqbuf_oracle.py): the same releases, drops, counters, deadlines,
alerts and footprint on random schedules of pushes, polls, give-backs and flushes, for one stream and
for a table with evictions."""

from __future__ import annotations

import dataclasses
from collections import defaultdict

import numpy as np
import seqbuf_oracle as oracle
from hypothesis import given, settings
from hypothesis import strategies as st

from listener.seqbuf import SeqBufferConfig, SequenceBuffer, StreamTable

CONFIGS = st.builds(
    SeqBufferConfig,
    hold_time_s=st.sampled_from([0.0, 0.02, 0.03]),
    max_pending=st.sampled_from([3, 8]),
    max_forward=st.sampled_from([5, 50]),
    max_backward=st.sampled_from([0, 4, 10]),
    probation=st.sampled_from([1, 2, 3]),
    probation_timeout_s=st.sampled_from([0.05, 0.5]),
    startup_hold=st.booleans(),
    trusted_gap=st.sampled_from([0, 1, 3]),
    gap_budget=st.sampled_from([0, 1, 3]),
    gap_refill_s=st.sampled_from([0.05, 10.0]),
    jump_timeout_s=st.sampled_from([0.04, 1.5]),
    max_suspects=st.sampled_from([1, 2, 8]),
    max_reopened=st.sampled_from([0, 2, 64]),
)
#: (what, seq offset from the last number pushed, time step [s]); what: 0-5 push, 6 poll, 7 give back,
#: 8 flush
STEP = st.tuples(
    st.integers(0, 8),
    st.one_of(st.integers(-12, 60), st.integers(-70000, 70000)),
    st.sampled_from([0.0, 0.0, 0.001, 0.005, 0.01, 0.03, 0.7]),
)


def _view(buf):
    s = buf.stats
    return (dataclasses.astuple(s), buf.next_deadline(), buf.expected, buf.pending_count, buf.footprint)


@settings(max_examples=400)
@given(CONFIGS, st.integers(0, 0xFFFF), st.lists(STEP, min_size=1, max_size=200))
def test_one_stream_matches_the_python_implementation(cfg, seq0, steps):
    new: SequenceBuffer = SequenceBuffer(cfg)
    old = oracle.SequenceBuffer(oracle.SeqBufferConfig(**dataclasses.asdict(cfg)))
    new.alerts, old.alerts = [], []
    seq, now = seq0, 0.0
    for uid, (what, delta, dt) in enumerate(steps):
        seq = (seq + delta) & 0xFFFF
        now += dt
        if what <= 5:
            assert new.push(seq, uid, now) == old.push(seq, uid, now)
        elif what == 6:
            assert new.poll(now) == old.poll(now)
        elif what == 7:
            back = (seq - delta % 7) & 0xFFFF
            assert new.reopen(back) == old.reopen(back)
        else:
            assert new.flush() == old.flush()
        assert _view(new) == _view(old)
    assert new.alerts == old.alerts
    assert new.flush() == old.flush()
    assert _view(new) == _view(old)


def _stats(table):
    s = table.stats
    return s.streams, s.evictions, dataclasses.astuple(s.totals)


def _by_stream(items):
    """Items (stream, uid) grouped by stream, each stream's in order (the table's streams are polled
    in no set order)."""
    got = defaultdict(list)
    for x in items:
        got[x[0] if isinstance(x, tuple) else x["stream"]].append(x)
    return dict(got)


@settings(max_examples=300)
@given(CONFIGS, st.integers(1, 4), st.lists(st.tuples(st.integers(0, 5), STEP), min_size=1, max_size=250))
def test_a_table_matches_the_python_implementation(cfg, max_streams, steps):
    new: StreamTable = StreamTable(cfg, max_streams=max_streams)
    old = oracle.StreamTable(oracle.SeqBufferConfig(**dataclasses.asdict(cfg)), max_streams=max_streams)
    seq = [0] * 6
    now = 0.0
    for uid, (key, (what, delta, dt)) in enumerate(steps):
        seq[key] = (seq[key] + delta) & 0xFFFF
        now += dt
        if what <= 6:
            a, b = new.push(key, seq[key], (key, uid), now), old.push(key, seq[key], (key, uid), now)
            evicted = [x for x in b if x[0] != key]  # the evicted stream's flush comes first
            assert a[: len(evicted)] == evicted and a[len(evicted) :] == b[len(evicted) :]
        elif what == 7:
            assert _by_stream(new.poll(now)) == _by_stream(old.poll(now))
        else:
            assert _by_stream(new.flush()) == _by_stream(old.flush())
        assert _stats(new) == _stats(old) and new.next_deadline() == old.next_deadline()
        assert sorted(map(repr, (k for k in range(6) if k in new))) == sorted(
            map(repr, (k for k in range(6) if k in old)))  # fmt: skip
    assert _by_stream(new.alerts) == _by_stream(old.alerts)
    assert _by_stream(new.flush()) == _by_stream(old.flush())
    assert _stats(new) == _stats(old)


@settings(max_examples=60)
@given(st.integers(0, 2**32 - 1), st.sampled_from([1, 2, 3, 256]))
def test_run_matches_the_python_implementation(seed, max_streams):
    """StreamTable.run (one compiled loop) equals the Python table's timer-then-push loop over a
    recorded stream of three senders with loss, duplicates, reordering, jumps and restarts."""
    rng = np.random.default_rng(seed)
    rows = []
    for stream, period in (("imu", 0.01), ("odo", 0.02), ("gps", 1.0)):
        seq = int(rng.integers(65536))
        for k in range(int(3.0 / period)):
            u = rng.random()
            seq += (2 if u < 0.03 else 1) + (200 if 0.98 < u < 0.99 else 0)  # a loss; a jump
            seq = (seq + (9000 if u > 0.995 or k == 60 else 0)) & 0xFFFF  # a restart
            rows.append((round((k * period + float(rng.uniform(0.0, 0.004))) * 256) / 256, stream, seq))
            v = rng.random()
            if v < 0.02:  # a duplicate
                rows.append((rows[-1][0] + 1 / 256, stream, seq))
            elif v < 0.05:  # a lone datagram 100 ahead (a forgery: held as a suspect)
                rows.append((rows[-1][0] + 1 / 256, stream, (seq + 100) & 0xFFFF))
    rows.sort()
    for i in range(len(rows) - 1):
        if rng.random() < 0.03:
            (ta, *a), (tb, *b) = rows[i], rows[i + 1]
            rows[i], rows[i + 1] = (ta, *b), (tb, *a)
    keys, seqs, times = [r[1] for r in rows], [r[2] for r in rows], [r[0] for r in rows]
    items = list(range(len(rows)))
    cfg = SeqBufferConfig(hold_time_s=1 / 32)
    old = oracle.StreamTable(oracle.SeqBufferConfig(hold_time_s=1 / 32), max_streams=max_streams)
    new: StreamTable = StreamTable(cfg, max_streams=max_streams)
    want = old.run(keys, seqs, items, times)
    got = new.run(keys, seqs, items, times)
    assert got[3] == want[3] is None

    def released(run):  # (item, time, release number) by stream, each stream's in order
        return _by_stream([(keys[i], i, t, b) for i, t, b in zip(*run[:3], strict=True)])

    assert released(got) == released(want)
    if max_streams >= 3:  # (fewer: every stream evicts another one)
        t = old.stats.totals
        assert min(t.lost, t.duplicates, t.reordered, t.jumps_held, t.resyncs) > 0
    assert _stats(new) == _stats(old)
    assert sorted(new.flush()) == sorted(old.flush())
    assert _by_stream(new.alerts) == _by_stream(old.alerts)
