"""Fault proxy core (sans-I/O): determinism, exact counting, each impairment's semantics, profiles."""

from __future__ import annotations

import math

import numpy as np
import pytest

from listener.codec import DecodeError, GroundTruth, ImuSample, Stop, decode_input, encode_input
from tools.faults.config import Impairments, impairments_from_dict, load_profile
from tools.faults.core import FORGE_SENDER, FaultCore
from tools.faults.errors import FaultConfigError
from tools.faults.forge import (
    flip_bits,
    forge_invalid,
    forge_targeted,
    forge_valid,
    garbage,
    garbage_batch,
    truncate,
)

A = ("127.0.0.1", 47001)
B = ("127.0.0.1", 47002)


def stream(n: int, dt: float = 0.01, senders=(A,)):
    """n datagrams per sender, interleaved, (now, sender, seq, bytes)."""
    out = []
    for i in range(n):
        for k, s in enumerate(senders):
            msg = ImuSample(i & 0xFFFF, 0, 0, -9.81, 0, 0, 0)
            out.append((i * dt + k * 1e-4, s, i & 0xFFFF, encode_input(msg)))
    return out


def drive(core: FaultCore, items, until: float | None = None):
    """Feed items, run due timers between them; returns every emission in send-time order."""
    out = []
    for now, sender, _, data in items:
        while (t := core.next_timer()) is not None and t <= now:
            out += core.handle_timer(t)
        out += core.forward(data, sender, now)
    end = (items[-1][0] if items else 0.0) + 1.0 if until is None else until
    for _ in range(100_000):
        t = core.next_timer()
        if t is None or t > end:
            break
        out += core.handle_timer(t)
    return sorted(out, key=lambda e: e[0])


def seqs_of(emits, sender):
    return [int.from_bytes(d[1:3], "little") for _, d, s in emits if s == sender and len(d) >= 3]


def test_same_seed_same_output_different_seed_different():
    imp = Impairments(loss=0.2, reorder=0.05, duplicate=0.05, jitter_s=0.002, bitflip=0.01)
    items = stream(2000)
    a = drive(FaultCore(imp, seed=4), items)
    b = drive(FaultCore(imp, seed=4), items)
    c = drive(FaultCore(imp, seed=5), items)
    assert a == b
    assert a != c


def test_counters_account_for_every_datagram():
    imp = Impairments(loss=0.1, ge_p_good_bad=0.02, ge_p_bad_good=0.3, reorder=0.1, duplicate=0.03,
                      blackouts=((3.0, 1.0),))
    core = FaultCore(imp, seed=1)
    emits = drive(core, stream(1000, senders=(A, B)))
    st = core.stats()
    assert st["received"] == 2000
    assert st["received"] == (st["dropped_loss"] + st["dropped_burst"] + st["dropped_blackout"]
                              + st["forwarded"] + st["held"])
    assert st["held"] == 0
    assert st["emitted"] == len(emits) == st["forwarded"] + st["duplicated"]
    assert st["dropped_blackout"] == 200  # 1 s of 2 x 100 datagrams/s
    assert 0.05 < st["dropped_loss"] / 2000 < 0.15


def test_bernoulli_loss_rate_and_blackout_window():
    core = FaultCore(Impairments(loss=0.2, blackouts=((10.0, 5.0),)), seed=3)
    items = stream(3000)  # 30 s at 100 Hz
    emits = drive(core, items)
    times = np.array([t for t, _, _ in emits])
    assert not np.any((times >= 10.0) & (times < 15.0))
    st = core.stats()
    assert st["dropped_blackout"] == 500
    assert abs(st["dropped_loss"] / 2500 - 0.2) < 0.03


def test_gilbert_elliott_losses_come_in_bursts():
    """Same mean loss as Bernoulli, far longer runs of consecutive losses."""
    def runs(core):
        emits = drive(core, stream(20000))
        got = set(seqs_of(emits, A))
        lost = np.array([i not in got for i in range(20000)])
        edges = np.flatnonzero(np.diff(np.r_[0, lost.astype(int), 0]))
        lengths = edges[1::2] - edges[::2]
        return lost.mean(), lengths.mean()

    ge_rate, ge_len = runs(FaultCore(Impairments(ge_p_good_bad=0.02, ge_p_bad_good=0.2), seed=2))
    expected = 0.02 / (0.02 + 0.2)  # stationary P(BAD), loss 1 in BAD
    assert abs(ge_rate - expected) < 0.03
    b_rate, b_len = runs(FaultCore(Impairments(loss=ge_rate), seed=2))
    assert ge_len > 3.0 * b_len


def test_reorder_swaps_with_the_next_datagram_of_the_same_sender():
    core = FaultCore(Impairments(reorder=0.1), seed=8)
    emits = drive(core, stream(3000))
    seq = seqs_of(emits, A)
    assert sorted(seq) == list(range(3000))  # nothing lost or duplicated
    inversions = sum(1 for x, y in zip(seq, seq[1:], strict=False) if y < x)
    assert inversions == core.stats()["reordered"] > 200
    assert core.stats()["reorder_expired"] == 0  # 10 ms spacing < 20 ms hold


def test_reorder_hold_expires_when_no_next_datagram_comes():
    core = FaultCore(Impairments(reorder=1.0, reorder_max_s=0.02), seed=0)
    assert core.forward(b"\x01\x00\x00\x00\x00", A, 0.0) == []
    assert core.next_timer() == pytest.approx(0.02)
    out = core.handle_timer(0.02)
    assert out == [(pytest.approx(0.02), b"\x01\x00\x00\x00\x00", A)]
    assert core.stats()["reorder_expired"] == 1 and core.stats()["reordered"] == 0


def test_jitter_keeps_per_sender_order_and_delay_is_applied():
    core = FaultCore(Impairments(delay_s=0.05, jitter_s=0.03), seed=1)
    items = stream(500)
    emits = drive(core, items)
    assert seqs_of(emits, A) == list(range(500))
    delays = np.array([t for t, _, _ in emits]) - np.array([now for now, *_ in items])
    assert delays.min() >= 0.05 - 1e-9 and delays.max() <= 0.08 + 1e-3


def test_duplicates_and_replays_are_exact_copies():
    core = FaultCore(Impairments(duplicate=0.1, replay=0.05), seed=9)
    items = stream(2000)
    emits = drive(core, items)
    originals = {d for *_, d in items}
    assert all(d in originals for _, d, _ in emits)
    st = core.stats()
    assert len(emits) == 2000 + st["duplicated"] + st["replayed"]
    assert st["duplicated"] > 100 and st["replayed"] > 50


def test_bitflip_and_truncation_change_datagrams_as_counted():
    core = FaultCore(Impairments(bitflip=0.2, bitflip_bits=3, truncate=0.1), seed=6)
    items = stream(2000)
    emits = drive(core, items)
    st = core.stats()
    short = sum(1 for _, d, _ in emits if len(d) < 53)
    assert short == st["truncated"]
    changed = sum(1 for (_, d, _), (*_, o) in zip(emits, items, strict=True) if d != o)
    assert changed <= st["bitflipped"] + st["truncated"]
    assert changed >= st["truncated"]


def test_injections_follow_rate_count_and_window():
    imp = Impairments(forge_rate_hz=100.0, forge_count=250, garbage_rate_hz=1000.0, inject_start_s=1.0,
                      inject_end_s=4.0)
    core = FaultCore(imp, seed=2, start=0.0)
    out = drive(core, [], until=10.0)
    st = core.stats()
    assert st["forged_invalid"] == 250  # the count ends it at 3.5 s
    assert st["garbage"] == 3000  # 3 s at 1000/s
    times = np.array([t for t, _, _ in out])
    assert times.min() >= 1.0 and times.max() < 4.0
    assert all(s == FORGE_SENDER for _, _, s in out)


def test_forged_invalid_and_garbage_are_always_rejected_forged_valid_accepted():
    rng = np.random.default_rng(11)
    for _ in range(3000):
        for data in (forge_invalid(rng), garbage(rng, 64)):
            with pytest.raises(DecodeError):
                decode_input(data)
        decode_input(forge_valid(rng, 1.7e9))  # raises if not valid
    batch = garbage_batch(rng, 5000, 64)
    assert len(batch) == 5000 and max(map(len, batch)) <= 64 and any(len(b) == 0 for b in batch)
    for data in batch:
        with pytest.raises(DecodeError):
            decode_input(data)


def test_flip_and_truncate_helpers():
    rng = np.random.default_rng(0)
    data = bytes(range(40))
    flipped = flip_bits(rng, data, 5)
    diff = sum(bin(a ^ b).count("1") for a, b in zip(data, flipped, strict=True))
    assert diff == 5
    assert flip_bits(rng, b"", 3) == b""
    assert all(len(truncate(rng, data)) < 40 for _ in range(100))


def test_replies_pass_except_in_blackout():
    core = FaultCore(Impairments(loss=1.0, blackouts=((1.0, 1.0),)), seed=0, start=0.0)
    assert core.reply(b"\x02\x01", A, 0.5) == [(0.5, b"\x02\x01", A)]  # loss does not apply to replies
    assert core.reply(b"\x02\x01", A, 1.5) == []
    st = core.stats()
    assert st["replies_forwarded"] == 1 and st["replies_dropped_blackout"] == 1


def test_leading_and_trailing_drops():
    core = FaultCore(Impairments(blackouts=((0.0, 0.05), (0.95, 1.0))), seed=0, start=0.0)
    drive(core, stream(100))
    st = core.stats()
    assert st["leading_drops"] == 5 and st["trailing_drops"] == 5


@pytest.mark.parametrize(
    "imp",
    [
        Impairments(loss=0.2, reorder=0.05, duplicate=0.01),  # the 10-minute campaign row
        Impairments(loss=0.3, reorder=0.3, truncate=0.1, jitter_s=0.02),
        Impairments(loss=0.2, reorder=0.3, replay=0.05),
    ],
)
def test_visible_drops_are_the_gaps_a_receiver_sees(imp):
    """lost_inj's identity, datagram by datagram: drops - leading - trailing == gaps in what went out.

    A reorder hold (20 ms) outlives the 10 ms spacing, so a held datagram can go out after its
    sender's next datagram was dropped: that drop lies after it in sequence order. Counting it as
    settled when the held datagram finally left made the live 10-minute row count one loss more than
    the listener could see (14,583 against 14,582, run 04:01)."""
    items = stream(60)
    whole = len(items[0][3])  # shorter: truncated, rejected by the receiver
    for seed in range(300):
        core = FaultCore(imp, seed=seed)
        emits = drive(core, items)
        seqs = sorted({int.from_bytes(d[1:3], "little") for _, d, _ in emits if len(d) == whole})
        gaps = seqs[-1] - seqs[0] + 1 - len(seqs) if seqs else 0
        st = core.stats()
        visible = (st["dropped_loss"] + st["truncated"] - st["leading_drops"] - st["trailing_drops"])
        assert visible == gaps, seed


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"loss": 1.5}, "loss"),
        ({"loss": "x"}, "loss"),
        ({"nope": 1}, "unknown key"),
        ({"blackouts": [[1.0]]}, "blackouts"),
        ({"blackouts": [[-1.0, 2.0]]}, "blackouts"),
        ({"bitflip_bits": 0}, "bitflip_bits"),
        ({"inject_start_s": 5.0, "inject_end_s": 1.0}, "inject_end_s"),
        ({"forge_on_stream": 1}, "forge_on_stream"),
        ({"jitter_s": math.inf}, "jitter_s"),
        ({"forge_kind": "teleport"}, "forge_kind"),
        ({"forge_kind": 3}, "forge_kind"),
        ({"forge_kind": "seq_jump"}, "forge_on_stream"),
        ({"forge_kind": "seq_jump", "forge_on_stream": True, "forge_seq_offset": 0}, "forge_seq_offset"),
    ],
)
def test_profile_errors_name_the_key(data, message):
    with pytest.raises(FaultConfigError, match=message):
        impairments_from_dict(data)


def test_profile_file_and_table(tmp_path):
    path = tmp_path / "p.toml"
    path.write_text('[input_link]\nloss = 0.25\nblackouts = [[1.0, 2.0]]\n[output_link]\nduplicate = 0.1\n')
    imp = load_profile(path, "input_link")
    assert imp.loss == 0.25 and imp.blackouts == ((1.0, 2.0),)
    assert load_profile(path, "output_link").duplicate == 0.1
    with pytest.raises(FaultConfigError, match="no table"):
        load_profile(path, "missing")
    (tmp_path / "bad.toml").write_text("loss = [")
    with pytest.raises(FaultConfigError, match="not valid TOML"):
        load_profile(tmp_path / "bad.toml")


def test_injection_timers_advance_at_large_absolute_times():
    """At t ~ 1.7e9 s a float step is ~2e-7 s: the flood's timer must still move on every call."""
    core = FaultCore(Impairments(garbage_rate_hz=1000.0, forge_rate_hz=100.0, inject_end_s=2.0), seed=1,
                     start=1.7e9)
    calls = 0
    while (t := core.next_timer()) is not None and calls < 10_000:
        core.handle_timer(t)
        calls += 1
    assert core.next_timer() is None
    assert core.stats()["garbage"] == 2000 and core.stats()["forged_invalid"] == 200


@pytest.mark.parametrize("kind", ["ground_truth", "stop"])
def test_targeted_forgeries_from_their_own_source(kind):
    """issue 20: valid GROUND TRUTH / STOP datagrams from the forger's own source, counted forged_foreign."""
    imp = Impairments(forge_rate_hz=2.0, forge_valid_fraction=1.0, forge_kind=kind, inject_end_s=5.0)
    core = FaultCore(imp, seed=3, start=0.0)
    out = drive(core, [], until=10.0)
    msgs = [decode_input(d) for _, d, _ in out]
    assert len(msgs) == 10 and core.stats()["forged_foreign"] == 10
    assert all(isinstance(m, GroundTruth if kind == "ground_truth" else Stop) for m in msgs)
    assert all(s == FORGE_SENDER for _, _, s in out)


def test_seq_jump_forgeries_copy_the_senders_last_datagram_ahead():
    imp = Impairments(forge_rate_hz=10.0, forge_valid_fraction=1.0, forge_kind="seq_jump",
                      forge_on_stream=True, forge_seq_offset=100, inject_start_s=0.5, inject_end_s=1.0)
    core = FaultCore(imp, seed=4, start=0.0)
    sender = ("127.0.0.1", 47001)
    real = [(i * 0.01, sender, i, encode_input(ImuSample(i, 0.0, 0.0, -9.81, 0.0, 0.0, 0.0, i * 0.01)))
            for i in range(100)]  # fmt: skip
    out = drive(core, real, until=2.0)
    forged = [(t, decode_input(d)) for t, d, s in out if decode_input(d).seq >= 100]
    assert len(forged) == 5 and core.stats()["forged_jump"] == 5
    for t, m in forged:  # the newest real datagram before it, 100 ahead
        last = max(i for i in range(100) if i * 0.01 < t - 1e-9)  # (timers before a datagram at t)
        assert m.seq == last + 100 and m.epoch == pytest.approx(last * 0.01)
    assert forge_targeted(np.random.default_rng(1), "seq_jump", None) is None  # nothing to copy yet


# ---------------------------------------------------------------- issue 20: masquerades, STOP gap, bursts
C = ("127.0.0.1", 47000)  # the control module: GROUND TRUTH, STROBE, STOP from one socket


def _control_and_imu(n: int = 300):
    """A GROUND TRUTH (seq 0) from C, then IMU samples from A, and a STOP (seq 1) from C at the end."""
    out = [(0.0, C, 0, encode_input(GroundTruth(0, 0.0, 0.0, 0.0, 100.0, None, None)))]
    out += [(0.01 + t, s, q, d) for t, s, q, d in stream(n)]
    out.append((0.02 + n * 0.01, C, 1, encode_input(Stop(1))))
    return out


def test_forge_as_poses_as_the_control_module_with_its_next_sequence_numbers():
    imp = Impairments(forge_on_stream=True, forge_as="ground_truth", forge_kind="ground_truth",
                      forge_rate_hz=10.0, forge_valid_fraction=1.0, inject_start_s=1.0, inject_end_s=1.5)
    core = FaultCore(imp, seed=3, start=0.0)
    out = drive(core, _control_and_imu())
    forged = [(t, d) for t, d, s in out if s == C and d[0] == 8 and t >= 1.0]
    assert len(forged) == core.stats()["forged_masquerade"] == 5
    assert [int.from_bytes(d[1:3], "little") for _, d in forged] == [1, 2, 3, 4, 5]  # in sequence
    assert all(isinstance(decode_input(d), GroundTruth) for _, d in forged)
    assert core.stats()["forged_foreign"] == 0
    # posing as the IMU's socket: a GROUND TRUTH from a source not bound to it (the sender table's case)
    as_imu = Impairments(**{**imp.as_dict(), "forge_as": "imu", "blackouts": ()})
    core = FaultCore(as_imu, seed=3, start=0.0)
    out = drive(core, _control_and_imu())
    assert core.stats()["forged_foreign"] == 5 and core.stats()["forged_masquerade"] == 0
    assert sum(1 for _, d, s in out if s == A and d[0] == 8) == 5


def test_forge_as_needs_forge_on_stream_and_a_known_type():
    with pytest.raises(FaultConfigError, match="forge_as"):
        Impairments(forge_as="ground_truth").validate()
    with pytest.raises(FaultConfigError, match="forge_as"):
        Impairments(forge_on_stream=True, forge_as="radar").validate()


def test_stop_seq_gap_moves_only_the_stop():
    core = FaultCore(Impairments(stop_seq_gap=1), seed=0, start=0.0)
    out = drive(core, _control_and_imu(50))
    control = [(d[0], int.from_bytes(d[1:3], "little")) for _, d, s in out if s == C]
    assert control == [(8, 0), (10, 2)]  # GROUND TRUTH seq 0, then STOP seq 2: seq 1 never sent
    assert core.stats()["stop_gapped"] == 1
    assert seqs_of(out, A) == list(range(50))


def test_replay_burst_resends_each_senders_first_datagrams_once_at_its_time():
    items = _control_and_imu(200)
    core = FaultCore(Impairments(replay_burst=5, replay_burst_at_s=1.005), seed=0, start=0.0)
    out = drive(core, items)
    late = [(d, s) for t, d, s in out if 1.005 <= t < 1.005 + 1e-3]  # between two real datagrams
    firsts = [d for _, s, _, d in items if s == A][:5]
    assert [d for d, s in late if s == A] == firsts
    assert [d for d, s in late if s == C] == [items[0][3]]  # the control module's GROUND TRUTH
    assert core.stats()["burst_replayed"] == 6
    assert sum(1 for e in out if e[1] == items[0][3]) == 2  # the original and one replay, no more


def test_cross_key_forgeries_are_signed_as_the_posed_as_module():
    """On an authenticated stream a masquerade is signed with that module's key and epoch: the MAC
    accepts it (a compromised key), so only the sender table can refuse it."""
    from listener.auth import wrap
    from listener.auth_link import LinkAuth, input_key
    from tools.faults.forge import module_signer

    master = bytes(range(32))
    kid = 3
    items = [(t, s, q, wrap(d, input_key(master, kid), 7, key_id=kid)) for t, s, q, d in stream(100)]
    imp = Impairments(forge_on_stream=True, forge_as="imu", forge_kind="stop", forge_rate_hz=4.0,
                      forge_valid_fraction=1.0, inject_start_s=0.2, inject_end_s=0.8)
    unsigned = FaultCore(imp, seed=1, start=0.0)
    drive(unsigned, items)
    assert unsigned.stats()["forge_unsigned"] > 0 and unsigned.stats()["forged_foreign"] == 0
    core = FaultCore(imp, seed=1, start=0.0, sign=module_signer(master))
    out = drive(core, items)
    from listener.auth import AuthError, AuthReason

    link = LinkAuth(master)
    opened, refused = [], []
    for _, d, s in out:
        try:
            opened.append(link.open_input(d, s))
        except AuthError as exc:
            refused.append(exc.reason)
    stops = [p for p in opened if p[0] == 10]
    assert len(stops) == core.stats()["forged_foreign"] == 3  # authentic under the IMU's key
    # each took the IMU's next SEQ: that real sample is then a replay for the MAC layer
    assert refused == [AuthReason.REPLAY] * 3
