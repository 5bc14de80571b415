"""OBCU link core with scripted time: SEQ wrap, rate cap, acks, link state, bounded retransmission."""

from listener.codec import decode_output, encode_ack
from listener.config import LinkConfig
from listener.obcu_link import LinkState, ObcuLink


def _est(epoch: float, s: float) -> tuple[float, float]:
    return (epoch, s)


def test_seq_increments_and_wraps():
    link = ObcuLink(LinkConfig(start_seq=65534, max_rate_hz=0))
    seqs = []
    for i in range(4):
        (dgram,) = link.send_estimate(_est(100.0 + i, float(i)), now=i * 0.01)
        assert len(dgram) == 18
        msg = decode_output(dgram)
        seqs.append(msg.seq)
        assert msg.epoch == 100.0 + i and msg.arc_length == float(i)
    assert seqs == [65534, 65535, 0, 1]


def test_rate_cap_sends_freshest_and_counts_superseded():
    link = ObcuLink(LinkConfig(max_rate_hz=10.0))
    assert len(link.send_estimate(_est(1.0, 1.0), 0.0)) == 1
    assert link.send_estimate(_est(1.01, 2.0), 0.01) == []
    assert link.send_estimate(_est(1.02, 3.0), 0.02) == []  # supersedes 2.0
    assert link.next_timer() is not None and abs(link.next_timer() - 0.1) < 1e-9
    assert link.handle_timer(0.05) == []
    (dgram,) = link.handle_timer(0.1)
    assert decode_output(dgram).arc_length == 3.0
    assert decode_output(dgram).seq == 1
    assert link.superseded == 1 and link.outputs == 2


def test_link_state_follows_acks():
    cfg = LinkConfig(max_rate_hz=0, degraded_after_s=2.5, down_after_s=5.0)
    link = ObcuLink(cfg)
    assert link.state is LinkState.IDLE
    link.send_estimate(_est(1.0, 0.0), 0.0)
    assert link.state is LinkState.UP
    link.receive_ack(encode_ack(0), 0.5)
    assert link.acks == 1
    link.handle_timer(3.1)
    assert link.state is LinkState.DEGRADED
    link.handle_timer(5.6)
    assert link.state is LinkState.DOWN
    link.send_estimate(_est(2.0, 1.0), 6.0)
    link.receive_ack(encode_ack(1), 6.1)
    assert link.state is LinkState.UP
    states = [s for _, s in link.transitions]
    assert states == ["up", "degraded", "down", "up"]
    assert [t for t, _ in link.transitions] == [0.0, 3.1, 5.6, 6.1]


def test_bogus_and_malformed_acks_are_counted_and_ignored():
    link = ObcuLink(LinkConfig(max_rate_hz=0))
    link.receive_ack(encode_ack(0), 0.0)  # nothing sent yet
    for i in range(3):
        link.send_estimate(_est(float(i), float(i)), i * 0.1)
    link.receive_ack(encode_ack(7), 0.3)  # never sent (ahead)
    link.receive_ack(encode_ack(60000), 0.3)  # never sent (behind the first output)
    link.receive_ack(b"\x01", 0.3)
    link.receive_ack(b"\x01\x02\x03", 0.3)
    assert link.bogus_acks == 3 and link.bad_acks == 2 and link.acks == 0
    link.receive_ack(encode_ack(2), 0.4)
    link.receive_ack(encode_ack(1), 0.5)  # older than the accepted one
    assert link.acks == 1 and link.bogus_acks == 4
    assert link.stats().last_acked_seq == 2


def test_retransmission_is_bounded_by_count_and_age():
    cfg = LinkConfig(max_rate_hz=0, retransmit_interval_s=0.5, max_retransmits=10, max_output_age_s=1.0)
    link = ObcuLink(cfg)
    (first,) = link.send_estimate(_est(1.0, 5.0), 0.0)
    resent = []
    t = 0.0
    for _ in range(100):  # bounded scripted time
        nxt = link.next_timer()
        if nxt is None or nxt > 60.0:
            break
        t = nxt
        resent.extend(link.handle_timer(t))
    assert resent == [first, first]  # at 0.5 s and 1.0 s; older than 1 s is never resent
    assert link.retransmits == 2


def test_no_retransmission_once_acked():
    link = ObcuLink(LinkConfig(max_rate_hz=0, retransmit_interval_s=0.5))
    link.send_estimate(_est(1.0, 5.0), 0.0)
    link.receive_ack(encode_ack(0), 0.1)
    assert link.handle_timer(0.6) == []
    assert link.retransmits == 0


def test_transition_history_is_bounded():
    link = ObcuLink(LinkConfig(max_rate_hz=0, degraded_after_s=0.1, down_after_s=0.2))
    t = 0.0
    for i in range(1500):
        link.send_estimate(_est(t, float(i)), t)
        link.receive_ack(encode_ack(i & 0xFFFF), t)
        t += 0.15
        link.handle_timer(t)  # degraded
    assert len(link.transitions) <= 1000
