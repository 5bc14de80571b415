"""Fuzzing the listener's pipeline core with hypothesis: any mix of valid, mutated, duplicated,
reordered and garbage datagrams from any senders, acks and timer calls at any times never raises,
keeps every counter identity, and only ever emits valid OUTPUT datagrams.

Short in CI; ``SFA_FUZZ_EXAMPLES`` sets the number of examples for the documented long run.
"""

from __future__ import annotations

import os

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from listener.codec import (
    GpsFix,
    GroundTruth,
    ImuSample,
    OdometerSample,
    Stop,
    Strobe,
    decode_output_any,
    encode_ack,
    encode_input,
)
from listener.config import config_from_dict
from listener.pipeline import Pipeline
from sfa.synthetic import build_track_db
from track_db import TrackDatabase

EXAMPLES = max(1, int(os.environ.get("SFA_FUZZ_EXAMPLES", "300")) // 6)
T0 = 1_700_000_000.0


@pytest.fixture(scope="module")
def track(tmp_path_factory):
    with TrackDatabase.open(build_track_db(tmp_path_factory.mktemp("fz") / "synthetic.db")) as db:
        yield db


def _valid(kind: int, seq: int, t: float) -> bytes:
    if kind == 0:
        return encode_input(ImuSample(seq, 0.1, 0.0, -9.81, 0.0, 0.0, 0.001, T0 + t))
    if kind == 1:
        return encode_input(OdometerSample(seq, 8.0, 0.05, T0 + t))
    if kind == 2:
        return encode_input(GpsFix(seq, 50.9, 11.6, 150.0, 1, 9, 2.0, T0 + t))
    if kind == 3:
        return encode_input(GroundTruth(seq, 8.0, 0.0, 0.0, 120.0, None, T0 + t))
    if kind == 4:
        return encode_input(Strobe(seq, T0 + t))
    return encode_input(Stop(seq))


event = st.one_of(
    st.tuples(st.just("valid"), st.integers(0, 5), st.integers(0, 65535), st.integers(0, 3)),
    st.tuples(st.just("mutated"), st.integers(0, 4), st.integers(0, 65535),
              st.binary(min_size=1, max_size=4)),
    st.tuples(st.just("garbage"), st.binary(max_size=64), st.integers(0, 3), st.none()),
    st.tuples(st.just("ack"), st.binary(max_size=4), st.integers(0, 65535), st.none()),
    st.tuples(st.just("timer"), st.none(), st.none(), st.none()),
)


@settings(max_examples=EXAMPLES, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(events=st.lists(st.tuples(event, st.floats(0.0, 0.5)), max_size=60))
def test_pipeline_never_raises_and_keeps_its_books(track, events):
    pipe = Pipeline(track, config_from_dict({"link": {"extended": True}}))
    now = 100.0
    t = 0.0
    outputs: list[bytes] = []
    for (kind, a, b, c), dt in events:
        now += dt
        t += dt
        if kind == "valid":
            outputs += pipe.receive(_valid(a, b, t), ("127.0.0.1", 47000 + c), now)
        elif kind == "mutated":
            raw = bytearray(_valid(a, b, t))
            for i, x in enumerate(c):
                raw[(x + i * 7) % len(raw)] ^= x | 1
            outputs += pipe.receive(bytes(raw), ("127.0.0.1", 47000 + (b % 4)), now)
        elif kind == "garbage":
            outputs += pipe.receive(a, ("10.0.0.9", 40000 + b), now)
        elif kind == "ack":
            outputs += pipe.receive_ack(a if len(a) != 2 else encode_ack(b), now)
        else:
            due = pipe.next_timer()
            if due is not None:
                now = max(now, due)
                outputs += pipe.handle_timer(now)
    outputs += pipe.flush(now + 1.0)
    m = pipe.metrics()
    inp, seq = m["input"], m["sequencing"]
    # every datagram is rejected on arrival, sequenced (by_type; an epoch_future one is rejected after
    # that, rejected_after_sequencing), or arrives after STOP
    before = inp.get("rejected", 0) - inp.get("rejected_after_sequencing", 0)
    assert inp["received"] == before + sum(inp["by_type"].values()) + inp.get("after_stop", 0)
    assert seq["received"] == sum(inp["by_type"].values())
    assert seq["in_order"] + seq["reordered"] == seq["released"] + seq["pending"]
    assert m["link"]["outputs"] <= len(outputs)
    for out in outputs:
        decoded = decode_output_any(out)
        assert decoded.interval_low <= decoded.arc_length <= decoded.interval_high
