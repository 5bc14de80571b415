"""Authenticated links wired into the pipeline and the mock OBCU (extension, off by default)."""

from __future__ import annotations

import numpy as np
import pytest
from test_listener_pipeline import _datagrams, _feed, _pipeline, run  # noqa: F401 - fixtures

from listener.auth import EpochCounter, derive_link_key, input_seq, output_seq, unwrap, wrap
from listener.auth_link import LINK_ACK, LINK_OUTPUT, input_key
from listener.codec import decode_output, encode_ack
from listener.config import AuthSettings, ListenerConfig, config_from_dict
from listener.errors import ConfigError
from listener.obcu import MockObcu, ObcuConfig
from listener.pipeline import Pipeline

MASTER = bytes(range(32))


@pytest.fixture()
def key_file(tmp_path):
    p = tmp_path / "master.key"
    p.write_text(MASTER.hex() + "\n")
    return p


def _auth_pipeline(track, key_file) -> Pipeline:  # noqa: F811
    cfg = ListenerConfig(auth=AuthSettings(enabled=True, key_file=str(key_file)))
    return Pipeline(track, cfg, start_epoch=7)


def _module_id(addr) -> int:
    return addr[1] - 47000  # the test's modules use ports 47000..47003


def _wrapped(dgrams):
    counters: dict = {}
    out = []
    for t, addr, data in dgrams:
        c = counters.setdefault(addr, EpochCounter(3))
        mid = _module_id(addr)
        out.append((t, addr, wrap(data, input_key(MASTER, mid), c.epoch_for(input_seq(data)), key_id=mid)))
    return out


def test_authenticated_stream_gives_the_same_estimates(track, run, key_file):  # noqa: F811
    plain = [decode_output(o) for o in _feed(_pipeline(track), _datagrams(run))]
    pipe = _auth_pipeline(track, key_file)
    sealed = _feed(pipe, _wrapped(_datagrams(run)))
    okey = derive_link_key(MASTER, LINK_OUTPUT)
    from listener.auth import AuthState

    state = AuthState()
    opened = [decode_output(unwrap(o, okey, state, "listener", seq_of=output_seq)) for o in sealed]
    assert opened == plain
    assert pipe.metrics()["auth"]["input_accepted"] == len(_datagrams(run))


def test_forged_replayed_and_flipped_datagrams_are_all_rejected(track, run, key_file):  # noqa: F811
    good = _wrapped(_datagrams(run))
    rng = np.random.default_rng(1)
    hostile = []
    wrong = input_key(bytes(32), 1)  # the attacker knows the format, not the key
    for i in range(0, len(good), 9):
        t, addr, data = good[i]
        flipped = bytearray(data)
        bit = int(rng.integers(0, len(data) * 8))
        flipped[bit // 8] ^= 1 << (bit % 8)
        hostile.append((t, addr, bytes(flipped)))
        hostile.append((t, addr, wrap(data[6:-16], wrong, 3, key_id=data[1])))  # forged, wrong key
        if i > 50:
            hostile.append((t, addr, good[i - 40][2]))  # replayed, possibly from another module's address
    mixed = sorted(good + hostile, key=lambda r: r[0])
    clean_pipe = _auth_pipeline(track, key_file)
    clean = _feed(clean_pipe, good)
    pipe = _auth_pipeline(track, key_file)
    dirty = _feed(pipe, mixed)
    m = pipe.metrics()
    assert m["input"]["rejected"] == len(hostile)  # 100 % rejected
    assert m["auth"]["input_accepted"] == len(good)
    assert set(m["input"]["rejected_by_reason"]) <= {"auth_tag", "auth_replay", "auth_old", "auth_magic"}
    # the outputs carry the same estimates (the wrapped bytes differ only by nothing: same epochs)
    assert dirty == clean


def test_acks_must_be_authentic(track, run, key_file):  # noqa: F811
    pipe = _auth_pipeline(track, key_file)
    outs = _feed(pipe, _wrapped(_datagrams(run))[:500])
    seq = output_seq(outs[-1][6:])
    pipe.receive_ack(encode_ack(seq), 10.0)  # a plain ack is not accepted
    assert pipe.metrics()["link"]["acks"] == 0 and pipe.metrics()["link"]["bad_acks"] == 1
    ack = wrap(encode_ack(seq), derive_link_key(MASTER, LINK_ACK), 5)
    pipe.receive_ack(ack, 10.1)
    assert pipe.metrics()["link"]["acks"] == 1
    pipe.receive_ack(ack, 10.2)  # the same ack again is a replay: ignored
    assert pipe.metrics()["link"]["acks"] == 1


def test_mock_obcu_speaks_the_extension(track, run, key_file):  # noqa: F811
    pipe = _auth_pipeline(track, key_file)
    outs = _feed(pipe, _wrapped(_datagrams(run))[:300])
    obcu = MockObcu(ObcuConfig(auth_master_key=MASTER), start=0.0)
    for k, o in enumerate(outs):
        assert obcu.receive(o, ("127.0.0.1", 1), 0.001 * k) is not None
    assert obcu.receive(outs[-1][:-1] + bytes([outs[-1][-1] ^ 1]), ("127.0.0.1", 1), 1.0) is None
    assert obcu.stats.auth_rejected == 1
    ((ack, _),) = obcu.handle_timer(1.0)
    pipe.receive_ack(ack, 1.0)
    assert pipe.metrics()["link"]["acks"] == 1


def test_auth_configuration_errors(tmp_path):
    with pytest.raises(ConfigError, match="auth.key_file"):
        config_from_dict({"auth": {"enabled": True}})
    with pytest.raises(ConfigError, match="auth.tag_bytes"):
        config_from_dict({"auth": {"tag_bytes": 8}})
    bad = tmp_path / "short.key"
    bad.write_text("abcd")
    from listener.config import read_master_key

    with pytest.raises(ConfigError, match="at least 16"):
        read_master_key(str(bad))
    bad.write_text("not hex at all")
    with pytest.raises(ConfigError, match="not a hex"):
        read_master_key(str(bad))
    with pytest.raises(ConfigError, match="cannot read"):
        read_master_key(str(tmp_path / "none"))
