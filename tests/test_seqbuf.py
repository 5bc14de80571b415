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
    dropped = s.duplicates + s.late + s.probation_drops
    assert s.received == s.in_order + s.reordered + dropped + s.probation_held
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
    buf.push(5, 5, 0.000)
    buf.push(3, 3, 0.001)  # lower, arrived later: still released with 5 (never held past 5's deadline)
    assert buf.poll(HOLD) == [3, 5]
    assert buf.stats.lost == 3  # 1, 2, 4


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
    bound = 2 * cfg.max_pending + cfg.max_forward + cfg.max_backward + cfg.probation
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
            assert deadline <= now + max(cfg.hold_time_s, cfg.probation_timeout_s) + 1e-9
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
