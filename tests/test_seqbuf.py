"""Tests of listener.seqbuf: scripted scenarios, properties of the release policy, bounded memory."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from listener.errors import ConfigError, ListenerError, SequenceError
from listener.seqbuf import SeqBufferConfig, SeqStats, SequenceBuffer, StreamTable, stream_key

HOLD = 0.03
CFG = SeqBufferConfig(hold_time_s=HOLD)
NOHOLD_START = SeqBufferConfig(hold_time_s=HOLD, startup_hold=False)


def started(seq0: int = 0, config: SeqBufferConfig = NOHOLD_START) -> SequenceBuffer:
    """A buffer whose stream started (in order) at ``seq0`` at t = 0."""
    buf: SequenceBuffer = SequenceBuffer(config)
    assert buf.push(seq0, seq0, 0.0) == [seq0]
    return buf


def check_identities(s: SeqStats) -> None:
    dropped = s.duplicates + s.late + s.probation_drops + s.jump_drops
    assert s.received == s.in_order + s.reordered + dropped + s.probation_held + s.jump_held
    assert s.in_order + s.reordered == s.released + s.pending


# ---------------------------------------------------------------------------------------------- scripted


def test_in_order_items_go_out_immediately():
    buf = started(10)
    for i, seq in enumerate(range(11, 20), start=1):
        assert buf.push(seq, seq, i * 0.001) == [seq]
    assert buf.next_deadline() is None
    s = buf.stats
    assert (s.received, s.released, s.in_order, s.reordered, s.lost) == (10, 10, 10, 0, 0)


def test_startup_hold_finds_the_true_start():
    buf: SequenceBuffer = SequenceBuffer(CFG)
    assert buf.push(7, 7, 1.0) == []
    assert buf.next_deadline() == pytest.approx(1.0 + HOLD)
    assert buf.push(5, 5, 1.01) == []
    assert buf.push(6, 6, 1.02) == []
    assert buf.poll(1.029) == []
    assert buf.poll(1.0 + HOLD) == [5, 6, 7]
    assert buf.push(8, 8, 1.05) == [8]  # afterwards in-order items are immediate
    s = buf.stats
    assert (s.in_order, s.reordered, s.lost, s.late) == (1 + 1, 2, 0, 0)
    assert buf.push(4, 4, 1.06) == [] and buf.stats.late == 1  # older than the stream start: late


def test_startup_gap_inside_the_hold_is_a_loss():
    buf: SequenceBuffer = SequenceBuffer(CFG)
    buf.push(3, 3, 0.0)
    buf.push(1, 1, 0.001)
    assert buf.poll(HOLD) == [1, 3] and buf.stats.lost == 1
    assert buf.push(2, 2, 0.05) == [] and buf.stats.late == 1


def test_gap_filled_within_hold_time_releases_in_order():
    buf = started(0)
    assert buf.push(2, 2, 0.010) == []
    assert buf.push(3, 3, 0.011) == []
    assert buf.next_deadline() == pytest.approx(0.010 + HOLD)
    assert buf.push(1, 1, 0.020) == [1, 2, 3]
    assert buf.next_deadline() is None
    s = buf.stats
    assert (s.lost, s.reordered, s.in_order, s.late) == (0, 1, 3, 0)


def test_gap_declared_lost_after_hold_time_then_late_copy_dropped():
    buf = started(0)
    buf.push(2, 2, 0.010)
    assert buf.poll(0.010 + HOLD - 1e-9) == []
    assert buf.poll(0.010 + HOLD) == [2]
    assert buf.stats.lost == 1
    assert buf.push(1, 1, 0.1) == []
    assert buf.push(1, 1, 0.1) == []  # a second copy of a late item is a duplicate
    s = buf.stats
    assert (s.late, s.duplicates, s.released) == (1, 1, 2)


def test_each_gap_waits_from_the_arrival_of_the_item_behind_it():
    buf = started(0)
    buf.push(2, 2, 0.000)  # waits for 1 until 0.03
    buf.push(4, 4, 0.020)  # waits for 3 until 0.05
    assert buf.poll(0.030) == [2]
    assert buf.push(3, 3, 0.040) == [3, 4]
    assert buf.stats.lost == 1


def test_one_expiry_releases_everything_that_arrived_before_it():
    buf = started(0)
    buf.push(3, 3, 0.000)
    buf.push(2, 2, 0.001)  # lower, arrived later: still released with 3 (never held past 3's deadline)
    assert buf.poll(HOLD) == [2, 3]
    assert buf.stats.lost == 1  # 1


def test_a_jump_beyond_the_trusted_gap_waits_for_the_gap_below_it_to_shrink():
    buf = started(0)
    buf.push(5, 5, 0.000)  # 4 numbers missing (> trusted_gap 3): not skipped by the hold timer alone
    buf.push(3, 3, 0.001)
    assert buf.poll(HOLD) == [] and buf.stats.jump_held == 1
    assert buf.poll(0.001 + HOLD) == [3, 5]  # 3 skips 1, 2 (small, stream silent); then 5 is 1 ahead
    s = buf.stats
    assert (s.lost, s.jumps_held, s.jump_drops, s.jump_held) == (3, 1, 0, 0)
    check_identities(s)


def test_duplicates_of_released_and_pending_items_are_dropped():
    buf = started(0)
    assert buf.push(0, "again", 0.001) == []
    buf.push(2, 2, 0.002)
    assert buf.push(2, "again", 0.003) == []
    assert buf.push(1, 1, 0.004) == [1, 2]
    assert buf.stats.duplicates == 2


def test_hold_time_zero_never_waits():
    buf = started(0, SeqBufferConfig(hold_time_s=0.0, startup_hold=False))
    assert buf.push(2, 2, 0.0) == [2]
    assert buf.stats.lost == 1
    first: SequenceBuffer = SequenceBuffer(SeqBufferConfig(hold_time_s=0.0))
    assert first.push(9, 9, 0.0) == [9]


def test_wrap_is_seamless():
    buf = started(65533)
    assert buf.push(65534, 65534, 0.001) == [65534]
    assert buf.push(0, 0, 0.002) == []  # 65535 missing
    assert buf.push(1, 1, 0.003) == []
    assert buf.push(65535, 65535, 0.004) == [65535, 0, 1]
    assert buf.expected == 2
    assert buf.push(65534, "old", 0.005) == [] and buf.stats.duplicates == 1


def test_large_forward_jump_resyncs_after_probation_and_releases_the_probation_items():
    buf = started(100)
    buf.push(101, 101, 0.001)
    buf.push(103, 103, 0.002)  # pending behind a gap at 102
    assert buf.push(20000, 20000, 0.003) == []  # a restart candidate
    assert buf.stats.probation_held == 1
    assert buf.push(104, 104, 0.004) == []  # the old sequence goes on meanwhile
    out = buf.push(20001, 20001, 0.005)
    assert out == [103, 104, 20000, 20001]  # old sequence flushed (102 lost), then the new one
    s = buf.stats
    assert (s.resyncs, s.lost, s.probation_drops, s.probation_held) == (1, 1, 0, 0)
    assert buf.push(20002, 20002, 0.006) == [20002]
    assert buf.push(104, "old", 0.007) == []  # an old number is now far away: a new probation run
    check_identities(buf.stats)


def test_restart_behind_the_window_resyncs():
    buf = started(5000)
    for seq in (0, 1, 2):
        buf.push(seq, seq, 0.001 * (seq + 1))
    s = buf.stats
    assert s.resyncs == 1 and buf.expected == 3
    assert s.released == 1 + 3


def test_broken_probation_run_is_dropped_and_counted():
    buf = started(0)
    buf.push(30000, "a", 0.001)
    buf.push(40000, "b", 0.002)  # not consecutive: "a" dropped, "b" starts a new run
    assert buf.stats.probation_drops == 1
    buf.push(40000, "b-dup", 0.003)
    assert buf.stats.duplicates == 1
    assert buf.push(40001, "c", 0.004) == ["b", "c"]
    check_identities(buf.stats)


def test_probation_run_times_out():
    cfg = SeqBufferConfig(hold_time_s=HOLD, startup_hold=False, probation_timeout_s=1.0)
    buf = started(0, cfg)
    buf.push(30000, "stray", 0.5)
    assert buf.next_deadline() == pytest.approx(1.5)
    assert buf.poll(1.5) == []
    s = buf.stats
    assert (s.probation_drops, s.probation_held) == (1, 0)
    assert buf.next_deadline() is None


def test_probation_of_three_needs_three_in_a_row():
    cfg = SeqBufferConfig(startup_hold=False, probation=3)
    buf = started(0, cfg)
    assert buf.push(9000, 9000, 0.1) == [] and buf.push(9001, 9001, 0.2) == []
    assert buf.push(9002, 9002, 0.3) == [9000, 9001, 9002]


def test_overflow_releases_the_lowest_gap_early_and_counts_it():
    cfg = SeqBufferConfig(hold_time_s=10.0, max_pending=4, startup_hold=False)
    buf = started(0, cfg)
    for seq in (2, 3, 5, 6):
        assert buf.push(seq, seq, 0.01) == []
    assert buf.push(8, 8, 0.02) == [2, 3]  # 1 declared lost, 2..3 released; 5, 6, 8 remain
    s = buf.stats
    assert (s.overflow, s.lost, s.pending) == (1, 1, 3)
    assert buf.push(1, 1, 0.03) == [] and buf.stats.late == 1


def test_overflow_with_a_new_lowest_item():
    cfg = SeqBufferConfig(hold_time_s=10.0, max_pending=2, startup_hold=False)
    buf = started(0, cfg)
    buf.push(5, 5, 0.0)
    buf.push(6, 6, 0.0)
    assert buf.push(3, 3, 0.0) == [3]  # the lowest goes out early (1, 2 lost); 5, 6 keep waiting for 4
    assert buf.push(4, 4, 0.0) == [4, 5, 6]
    assert buf.stats.lost == 2


def test_flush_releases_everything_in_order():
    buf = started(0)
    buf.push(3, 3, 0.0)
    buf.push(2, 2, 0.0)
    buf.push(9000, "candidate", 0.0)
    assert buf.flush() == [2, 3]
    s = buf.stats
    assert (s.lost, s.probation_drops, s.pending, s.probation_held) == (1, 1, 0, 0)
    assert buf.next_deadline() is None


def test_time_going_backwards_never_releases_early():
    buf = started(0)
    buf.push(2, 2, 1.0)
    assert buf.poll(0.5) == []
    assert buf.push(3, 3, 0.2) == []  # clamped to 1.0: its deadline is 1.03, not 0.23
    assert buf.poll(1.0 + HOLD) == [2, 3]


@pytest.mark.parametrize("seq", [-1, 65536, 1.0, None, True])
def test_invalid_seq_is_a_sequence_error(seq):
    buf: SequenceBuffer = SequenceBuffer(CFG)
    with pytest.raises(SequenceError):
        buf.push(seq, "x", 0.0)
    assert buf.stats.received == 0


def test_nan_time_is_a_sequence_error():
    buf: SequenceBuffer = SequenceBuffer(CFG)
    with pytest.raises(SequenceError, match="NaN"):
        buf.poll(math.nan)
    buf.push(0, 0, 1.0)
    with pytest.raises(SequenceError, match="NaN"):
        buf.push(1, 1, math.nan)
    assert buf.stats.received == 1


@pytest.mark.parametrize(
    "changes",
    [
        {"hold_time_s": -0.1}, {"hold_time_s": math.inf}, {"hold_time_s": "30ms"}, {"max_pending": 0},
        {"max_forward": 0}, {"max_forward": 32768}, {"max_backward": -1}, {"max_backward": 40000},
        {"probation": 0}, {"probation": 300}, {"probation_timeout_s": 0.0}, {"startup_hold": 1},
        {"max_pending": 2.5},
    ],
)  # fmt: skip
def test_bad_config_is_a_config_error(changes):
    with pytest.raises(ConfigError, match="SeqBufferConfig"):
        dataclasses.replace(SeqBufferConfig(), **changes)
    assert issubclass(ConfigError, ListenerError)


# ---------------------------------------------------------------------------------------------- properties


def _drain(buf: SequenceBuffer, now: float) -> list:
    out = buf.poll(now)
    assert buf.next_deadline() is None
    return out


@given(st.integers(0, 0xFFFF), st.permutations(range(60)), st.booleans())
def test_any_permutation_within_the_hold_window_comes_out_complete_and_in_order(seq0, order, hold_start):
    """All items arrive within one hold time, in any order: nothing lost, nothing twice, all in order."""
    cfg = SeqBufferConfig(hold_time_s=HOLD, startup_hold=hold_start)
    buf: SequenceBuffer = SequenceBuffer(cfg)
    if not hold_start:  # the start must be known without the startup hold: send item 0 first
        order = [0, *[i for i in order if i != 0]]
    out: list[int] = []
    for k, i in enumerate(order):
        out += buf.push((seq0 + i) & 0xFFFF, i, k * HOLD / (2 * len(order)))
    out += _drain(buf, 1.0)
    assert out == list(range(len(order)))
    s = buf.stats
    expected_reordered = sum(1 for k, i in enumerate(order) if k and max(order[:k]) > i)
    assert (s.lost, s.duplicates, s.late, s.resyncs, s.reordered) == (0, 0, 0, 0, expected_reordered)
    check_identities(s)


COPIES = st.lists(st.integers(1, 4), min_size=1, max_size=80)


@given(st.integers(0, 0xFFFF), COPIES, st.randoms(use_true_random=False))
def test_duplicates_never_come_out_twice(seq0, copies, rnd):
    """Every item sent 1..4 times, all copies shuffled within one hold time: each comes out once."""
    arrivals = [i for i, c in enumerate(copies) for _ in range(c)]
    rnd.shuffle(arrivals)
    buf: SequenceBuffer = SequenceBuffer(CFG)
    out: list[int] = []
    for k, i in enumerate(arrivals):
        out += buf.push((seq0 + i) & 0xFFFF, i, k * HOLD / (2 * len(arrivals)))
    out += _drain(buf, 1.0)
    assert out == list(range(len(copies)))
    assert buf.stats.duplicates == len(arrivals) - len(copies)
    check_identities(buf.stats)


@given(st.integers(0, 2**32 - 1), st.integers(0, 0xFFFF), st.integers(20, 400))
def test_jitter_below_hold_time_never_loses_and_keeps_order(seed, seq0, n):
    """Items sent every 2 ms, each delayed by an independent jitter in [0, hold): the output is the
    whole stream in order (each gap fills before the item behind it has waited hold_time_s)."""
    rng = np.random.default_rng(seed)
    send = np.arange(n) * 0.002
    arrive = send + rng.uniform(0.0, HOLD * 0.999, n)
    order = np.argsort(arrive, kind="stable")
    buf: SequenceBuffer = SequenceBuffer(CFG)
    out: list[int] = []
    for i in order:
        out += buf.push(int((seq0 + i) & 0xFFFF), int(i), float(arrive[i]))
    out += _drain(buf, float(arrive.max()) + 1.0)
    assert out == list(range(n))
    assert buf.stats.lost == 0 and buf.stats.late == 0


def test_streams_crossing_65535_several_times_are_seamless():
    rng = np.random.default_rng(20261121)
    n = 4 * 65536 + 123  # four wraps
    send = np.arange(n) * 0.0001
    arrive = send + rng.uniform(0.0, HOLD * 0.5, n) * (rng.random(n) < 0.05)  # 5 % of items jittered
    order = np.argsort(arrive, kind="stable")
    buf: SequenceBuffer = SequenceBuffer(SeqBufferConfig(hold_time_s=HOLD, max_pending=1024))
    out: list[int] = []
    seq0 = 65000
    for i in order.tolist():
        out += buf.push((seq0 + i) & 0xFFFF, i, float(arrive[i]))
    out += _drain(buf, float(arrive.max()) + 1.0)
    assert out == list(range(n))
    s = buf.stats
    assert (s.released, s.lost, s.duplicates, s.late, s.resyncs, s.overflow) == (n, 0, 0, 0, 0, 0)


PERIOD = 0.01  # s between items sent; HOLD is 3 periods


@st.composite
def impaired_stream(draw):
    """A stream of n items with injected losses, duplicates, swaps, late items and sender restarts."""
    n = draw(st.integers(10, 200))
    kinds = ["none"] * n
    i = 1
    while i < n - 2:
        kind = draw(st.sampled_from(["none", "none", "lost", "dup", "swap", "late"]))
        if kind == "swap" or kind == "late":
            kinds[i] = kind
            i += 2  # item i+1 stays "none": it is what the swap/late item is measured against
        else:
            kinds[i] = kind
            i += 1
    # Restarts: from index r on, the sender's numbers jump far away (beyond max_forward, and not within
    # max_backward behind). Items r-6 .. r+1 stay clean so that nothing of the old sequence is still in
    # flight after the resync (r and r+1 are the probation run).
    restarts: list[tuple[int, int]] = []
    r = 8
    while r < n - 2:
        if draw(st.integers(0, 4)) == 0:
            restarts.append((r, draw(st.integers(3100, 65300))))
            for j in range(r - 6, r + 2):
                kinds[j] = "none"
            r += 10
        else:
            r += 1
    return draw(st.integers(0, 0xFFFF)), kinds, restarts


@given(impaired_stream())
def test_counters_equal_what_was_injected(stream):
    seq0, kinds, restarts = stream
    offset = [0] * len(kinds)  # sequence-number offset of item i (after the restarts before it)
    for r, jump in restarts:
        for j in range(r, len(kinds)):
            offset[j] += jump
    arrivals: list[tuple[float, int]] = []
    for i, kind in enumerate(kinds):
        t = i * PERIOD
        if kind == "none":
            arrivals.append((t, i))
        elif kind == "dup":
            arrivals += [(t, i), (t + 0.0001, i)]
        elif kind == "swap":
            arrivals.append((t + PERIOD + 0.001, i))  # after i+1, well within the hold time
        elif kind == "late":
            arrivals.append((t + HOLD + 2.5 * PERIOD, i))  # after i+1 waited HOLD: i was declared lost
    arrivals.sort()
    buf: SequenceBuffer = SequenceBuffer(CFG)
    out: list[int] = []
    for t, i in arrivals:
        out += buf.push((seq0 + i + offset[i]) & 0xFFFF, i, t)
    out += _drain(buf, len(kinds) * PERIOD + 1.0)
    count = kinds.count
    expected_out = [i for i, k in enumerate(kinds) if k not in ("lost", "late")]
    assert out == expected_out
    s = buf.stats
    assert s.received == len(arrivals)
    assert s.released == len(expected_out)
    assert s.lost == count("lost") + count("late")
    assert s.late == count("late")
    assert s.duplicates == count("dup")
    assert s.reordered == count("swap")
    assert s.resyncs == len(restarts)
    assert (s.overflow, s.probation_drops) == (0, 0)
    check_identities(s)


SMALL = SeqBufferConfig(hold_time_s=0.02, max_pending=8, max_forward=50, max_backward=10, probation=2,
                        probation_timeout_s=0.5)  # fmt: skip
STEP = st.tuples(
    st.one_of(st.integers(-12, 60), st.integers(-70000, 70000)),  # seq offset from the last one pushed
    st.sampled_from([0.0, 0.0, 0.001, 0.005, 0.03, 0.7]),  # time step [s]
    st.booleans(),  # also poll after the push
)


@given(st.integers(0, 0xFFFF), st.lists(STEP, min_size=1, max_size=300), st.booleans())
def test_random_schedules_keep_memory_bounded_and_never_release_twice(seq0, steps, hold_start):
    cfg = dataclasses.replace(SMALL, startup_hold=hold_start)
    buf: SequenceBuffer = SequenceBuffer(cfg)
    bound = 2 * cfg.max_pending + cfg.max_forward + cfg.max_backward + cfg.probation + cfg.max_suspects
    seq, now = seq0, 0.0
    released: list[int] = []
    for uid, (delta, dt, poll) in enumerate(steps):
        seq = (seq + delta) & 0xFFFF
        now += dt
        released += buf.push(seq, uid, now)
        if poll:
            released += buf.poll(now)
        s = buf.stats
        check_identities(s)
        assert s.pending <= cfg.max_pending and s.probation_held < cfg.probation
        assert buf.footprint <= bound
        deadline = buf.next_deadline()
        assert (deadline is None) == (buf.pending_count == 0)
        if deadline is not None:
            assert deadline <= now + max(cfg.hold_time_s, cfg.probation_timeout_s, cfg.jump_timeout_s) + 1e-9
    released += buf.flush()
    assert len(released) == len(set(released))  # nothing released twice
    s = buf.stats
    assert s.pending == 0 and s.released == len(released) == s.in_order + s.reordered


# ---------------------------------------------------------------------------------------------- stream table


def test_stream_table_keeps_streams_apart_and_polls_across_them():
    table: StreamTable = StreamTable(CFG, max_streams=8)
    a, b = ("127.0.0.1", 5000), ("127.0.0.1", 5001)
    assert table.push(a, 0, "a0", 0.0) == [] and table.push(b, 40000, "b0", 0.005) == []
    assert table.next_deadline() == pytest.approx(HOLD)
    assert table.poll(HOLD) == ["a0"]
    assert table.next_deadline() == pytest.approx(0.005 + HOLD)
    assert table.poll(0.005 + HOLD) == ["b0"]
    assert table.push(a, 1, "a1", 0.04) == ["a1"] and table.push(b, 40001, "b1", 0.04) == ["b1"]
    assert table.next_deadline() is None
    st_ = table.stats
    assert (st_.streams, st_.evictions, st_.totals.released, st_.totals.received) == (2, 0, 4, 4)


@given(st.integers(0, 2**32 - 1), st.sampled_from([None, 150, 399]))
def test_run_is_the_listeners_timer_and_push_loop(seed, stop_at):
    """StreamTable.run (the fast replay's) equals polling at every due deadline before each push, as the
    listener's timer and receive do: same releases, times, release numbers, counters; the STOP."""
    rng = np.random.default_rng(seed)
    rows = []  # three streams at 100, 50 and 1 Hz with loss, duplicates, reordering and a jump
    for stream, period in (("imu", 0.01), ("odo", 0.02), ("gps", 1.0)):
        seq = int(rng.integers(65536))
        for k in range(int(4.0 / period)):
            seq = (seq + (2 if rng.random() < 0.02 else 1) + (200 if rng.random() < 0.003 else 0)) & 0xFFFF
            # on a 1/256 s grid with a 1/32 s hold: deadlines fall exactly on arrivals too
            rows.append((round((k * period + float(rng.uniform(0.0, 0.004))) * 256) / 256, stream, seq))
            if rng.random() < 0.02:
                rows.append((rows[-1][0] + 1 / 256, stream, seq))
    rows.sort()
    for i in range(len(rows) - 1):
        if rng.random() < 0.02:  # overtaken by its successor, arrival times kept ascending
            (ta, *a), (tb, *b) = rows[i], rows[i + 1]
            rows[i], rows[i + 1] = (ta, *b), (tb, *a)
    keys, seqs, times = [r[1] for r in rows], [r[2] for r in rows], [r[0] for r in rows]
    items = list(range(len(rows)))
    cfg = SeqBufferConfig(hold_time_s=1 / 32)
    ref: StreamTable = StreamTable(cfg)
    want: list[tuple[int, float, int]] = []
    batch, stop = 0, None
    for key, seq, item, t in zip(keys, seqs, items, times, strict=True):
        nd = ref.next_deadline()
        while nd is not None and nd <= t:
            out = ref.poll(nd)
            want += [(x, nd, batch) for x in out]
            batch += bool(out)
            nd = ref.next_deadline()
        out = ref.push(key, seq, item, t)
        want += [(x, t, batch) for x in out]
        batch += bool(out)
        if item == stop_at:
            stop = item in out
            break
    table: StreamTable = StreamTable(cfg)
    rel, rel_t, rel_b, got_stop = table.run(keys, seqs, items, times, stop_at)
    assert list(zip(rel, rel_t, rel_b, strict=True)) == want
    assert got_stop == stop
    assert table.stats == ref.stats
    assert table.flush() == ref.flush()
    if stop_at is None:  # the whole stream was not clean
        assert min(ref.stats.totals.lost, ref.stats.totals.duplicates, ref.stats.totals.reordered) > 0


def test_stream_key_scopes():
    addr = ("10.0.0.2", 7000)
    assert stream_key(addr, 1) == addr == stream_key(addr, 3)
    assert stream_key(addr, 1, per_type=True) == (addr, 1) != stream_key(addr, 3, per_type=True)


def test_spoofed_source_port_flood_is_bounded_and_loses_no_data():
    table: StreamTable = StreamTable(CFG, max_streams=64)
    released: list[tuple[int, int]] = []
    n_ports = 5000
    for port in range(n_ports):
        released += table.push(("198.51.100.7", port), 7, (port, 7), port * 1e-5)
        assert len(table) <= 64
    released += table.flush()
    st_ = table.stats
    assert st_.streams == 64 and st_.evictions == n_ports - 64
    assert sorted(released) == [(port, 7) for port in range(n_ports)]  # evicted streams were flushed
    assert (st_.totals.received, st_.totals.released, st_.totals.pending) == (n_ports, n_ports, 0)


def test_lru_keeps_the_busy_stream():
    table: StreamTable = StreamTable(NOHOLD_START, max_streams=2)
    busy = "busy"
    table.push(busy, 0, 0, 0.0)
    table.push("x", 0, "x", 0.1)
    table.push(busy, 1, 1, 0.2)  # busy is now the most recently used
    table.push("y", 0, "y", 0.3)  # evicts "x"
    assert busy in table and "x" not in table and "y" in table
    assert table.get(busy).expected == 2


def test_stream_table_rejects_a_bad_bound():
    with pytest.raises(ConfigError):
        StreamTable(CFG, max_streams=0)


# ---------------------------------------------------------------------------------------------- forged jumps
# (issue 20: one datagram with SEQ + 100 must not turn the next hundred legitimate ones into "late")


def _run_with_forgery(seq0, n, period, at, offset, config=NOHOLD_START):
    """``n`` legitimate items every ``period`` s; after item ``at`` one forged item with SEQ + ``offset``
    (ahead of the next expected number). Returns (legitimate items released, the buffer)."""
    buf = started(seq0, config)
    out: list = [0]  # (started() pushed item seq0 as number seq0: it is item 0 here)
    forged_seq = (seq0 + at + offset) & 0xFFFF
    for i in range(1, n):
        t = i * period
        out += buf.push((seq0 + i) & 0xFFFF, i, t)
        if i == at:
            out += buf.push(forged_seq, "forged", t + period / 3)
        out += buf.poll(t + period / 2)
    out += buf.poll(n * period + 10.0)
    out += buf.flush()
    return [x for x in out if x != "forged"], buf


@given(
    st.integers(0, 0xFFFF),
    st.sampled_from([0.001, 0.005, 0.01, 0.05, 0.2, 1.0]),  # the stream's period: 1 kHz .. 1 Hz [s]
    st.integers(5, 60),
    st.integers(1, 100),
)
def test_one_forged_jump_costs_the_stream_at_most_the_trusted_gap(seq0, period, at, offset):
    n = 120
    legit, buf = _run_with_forgery(seq0, n, period, at, offset)
    # before: one forgery within max_backward silenced everything after it up to SEQ + offset
    lost = n - len(legit)
    assert lost <= NOHOLD_START.trusted_gap + 1  # the missing numbers of a small skip, and the forged one's
    if offset > NOHOLD_START.trusted_gap + 1:
        # a large jump: at most the forged number's own item, when the stream reaches it within the hold
        # time (the forgery is then in the place of its number; fast streams only)
        assert lost <= 1
        if period >= 0.01:
            assert legit == list(range(n))
    check_identities(buf.stats)


def test_seq_plus_100_on_a_100_hz_stream_is_held_then_dropped():
    legit, buf = _run_with_forgery(0, 300, 0.01, 50, 100)
    assert legit == list(range(300))  # all 300 legitimate items, in order
    s = buf.stats
    assert (s.jumps_held, s.jump_drops, s.lost, s.late, s.duplicates) == (1, 1, 0, 0, 0)


def test_seq_plus_100_on_a_1_hz_stream_is_dropped_when_the_next_one_comes():
    legit, buf = _run_with_forgery(0, 30, 1.0, 10, 100)
    assert legit == list(range(30))
    assert (buf.stats.jump_drops, buf.stats.late) == (1, 0)


def test_small_forgeries_are_rate_limited():
    """A 1 Hz stream and one forgery 2 ahead of the next number (1 missing: a small gap) every 2 s, for
    120 s. A small skip the hold timer makes without confirmation costs the stream at most the missing
    number and the forged one's; the budget (3 at once, one more per 10 s) bounds how many there are; the
    other forgeries wait as suspects and are dropped when the stream's next item shows them forged."""
    cfg = NOHOLD_START
    buf = started(0, cfg)
    out: list = [0]
    n = 120
    for i in range(1, n):
        out += buf.push(i, i, float(i))
        if i % 2 == 0:
            out += buf.push((buf.expected + 1) & 0xFFFF, "forged", i + 0.01)
        out += buf.poll(i + 0.5)
    out += buf.poll(n + 10.0)
    legit = [x for x in out if x != "forged"]
    s = buf.stats
    skips = cfg.gap_budget + math.ceil(n / cfg.gap_refill_s)
    assert out.count("forged") <= skips
    assert n - len(legit) <= 2 * skips  # unlimited: 2 of every 2 items lost (60 skips, 120 items)
    assert s.gap_limited > 0 and s.jump_drops == (n - 1) // 2 - out.count("forged")
    check_identities(s)


@given(
    st.integers(0, 0xFFFF),
    st.sampled_from([0.001, 0.01, 0.05, 1.0]),
    st.lists(st.tuples(st.integers(1, 200), st.integers(1, 60)), min_size=1, max_size=6),
)
def test_legitimate_losses_release_every_item_that_arrives(seq0, period, bursts):
    """Bursts of loss of any length (within max_forward): every item that arrives is released, in order,
    at the latest jump_timeout_s after it arrived (a burst is followed by the stream itself)."""
    n = 400
    dropped: set[int] = set()
    for start, length in bursts:
        dropped.update(range(start, min(start + length, n - 1)))
    buf = started(seq0)
    out: list = [0]
    latest: dict = {}
    for i in range(1, n):
        t = i * period
        if i not in dropped:
            latest[i] = t
            out += buf.push((seq0 + i) & 0xFFFF, i, t)
        out += buf.poll(t)
    out += buf.poll(n * period + 10.0)
    arrived = [0] + [i for i in range(1, n) if i not in dropped]
    assert out == arrived
    assert buf.stats.lost == len(dropped) and buf.stats.jump_drops == 0


def test_stop_after_a_gap_is_released_by_the_hold_timer():
    """GROUND TRUTH SEQ 0, then STOP SEQ 2 (1 lost) and nothing more: the hold timer releases the STOP."""
    buf = started(0)
    assert buf.push(2, "stop", 0.100) == []
    assert buf.next_deadline() == pytest.approx(0.100 + HOLD)
    assert buf.poll(0.100 + HOLD) == ["stop"]
    assert buf.stats.lost == 1


def test_a_last_item_after_a_large_gap_is_released_after_the_jump_timeout():
    buf = started(0)
    assert buf.push(50, "last", 1.0) == []
    assert buf.poll(1.0 + HOLD) == [] and buf.stats.jump_held == 1
    assert buf.next_deadline() == pytest.approx(1.0 + HOLD + NOHOLD_START.jump_timeout_s)
    assert buf.poll(1.0 + HOLD + NOHOLD_START.jump_timeout_s) == ["last"]  # the stream stayed silent
    s = buf.stats
    assert (s.lost, s.jump_drops, s.released) == (49, 0, 2)
    check_identities(s)


def test_a_later_item_confirms_a_large_jump_at_once():
    buf = started(0)
    buf.push(50, 50, 1.0)
    assert buf.poll(1.0 + HOLD) == []
    assert buf.push(51, 51, 1.5) == [50, 51]  # RTP's probation: two in a row from the new position
    assert buf.stats.lost == 49


def test_flush_drops_suspects():
    buf = started(0)
    buf.push(1, 1, 0.0)
    buf.push(100, "forged", 0.001)
    buf.push(2, 2, 0.01)
    assert buf.poll(0.001 + HOLD) == [] and buf.stats.jump_held == 1
    assert buf.flush() == []
    assert buf.stats.jump_drops == 1 and buf.next_deadline() is None


def test_reopen_gives_a_content_rejected_number_back():
    buf = started(0)
    assert buf.push(1, "forged", 0.01) == ["forged"]  # e.g. a future epoch the pipeline then rejects
    assert buf.reopen(1)
    assert buf.push(1, "legit", 0.02) == ["legit"]  # not a duplicate
    assert buf.push(1, "again", 0.03) == []  # once only
    s = buf.stats
    assert (s.reopened, s.duplicates) == (1, 1)
    assert not buf.reopen(5)  # ahead of the stream: nothing to give back
    assert not SequenceBuffer(NOHOLD_START).reopen(0)  # no stream yet
    with pytest.raises(SequenceError):
        buf.reopen(70000)
    check_identities(s)


def test_stream_table_collects_alerts_with_the_stream_key():
    table: StreamTable = StreamTable(NOHOLD_START)
    key = ("127.0.0.1", 47001)
    table.push(key, 0, 0, 0.0)
    table.push(key, 100, "forged", 0.001)
    table.push(key, 1, 1, 0.01)
    table.poll(0.001 + HOLD)
    table.poll(0.001 + HOLD + NOHOLD_START.jump_timeout_s)
    kinds = [a["event"] for a in table.alerts]
    assert kinds == ["sequence_jump_held", "sequence_jump_dropped"]
    assert table.alerts[0]["stream"] == key and table.alerts[0]["seq"] == 100
    assert table.alerts[0]["missing"] == 98


def test_a_jump_the_silence_explains_is_released_by_the_hold_timer():
    """A 1 Hz stream that was silent for 10 s (an outage: 9 numbers missing, beyond trusted_gap): the
    first item after it goes out at its hold time, not after jump_timeout_s; the same jump right behind
    a real item (a forgery) waits as a suspect."""
    buf = started(0)
    for i in range(1, 5):
        assert buf.push(i, i, float(i)) == [i]
    assert buf.push(14, 14, 14.0) == []
    assert buf.poll(14.0 + HOLD) == [14]
    assert (buf.stats.lost, buf.stats.jumps_held) == (9, 0)
    forged = started(0)
    for i in range(1, 5):
        forged.push(i, i, float(i))
    forged.push(14, "forged", 4.01)
    assert forged.poll(4.01 + HOLD) == [] and forged.stats.jump_held == 1
