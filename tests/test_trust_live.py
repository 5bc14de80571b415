"""Trust boundaries live (issue 20): a real ``sfa listen`` and ``sfa obcu`` on 127.0.0.1, the sensors
mocked by this test from one socket per module; an attacker's datagrams from other sockets (or the
module's own socket, for the sequence forgery)."""

from __future__ import annotations

import socket
import time

import numpy as np
import pytest
from helpers_net import paced_send
from test_listener_service import _events, _obcu_rows, _start, _wait_quiet, world  # noqa: F401 - fixture

from listener.codec import GroundTruth, ImuSample, Stop, decode_input, encode_input

pytestmark = pytest.mark.slow

SPEED = 4.0  #: the 40 s run is sent in 10 s


def _send(lport: int, dgrams, speed: float, inject=None) -> dict:
    """Send ``dgrams`` paced at ``speed`` x real time, one socket per module (helpers_net.paced_send);
    ``inject(i, socks, attacker, lport, dgrams)`` runs before datagram i and may send forgeries from
    the module sockets or an attacker's own. Returns the sockets' ports by module port."""
    attacker = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    attacker.bind(("127.0.0.1", 0))
    try:
        hook = None if inject is None else (lambda i, _s, socks: inject(i, socks, attacker, lport, dgrams))
        return paced_send(lport, dgrams, speed, hook)
    finally:
        attacker.close()


def _run_attack(world, tmp_path, inject) -> tuple[int, object]:  # noqa: F811 - not the fixture
    """A live listener and OBCU, the world's run sent at SPEED with ``inject(i, socks, attacker, lport,
    dgrams)`` called before datagram i; returns the listener's exit status and the OBCU's CSV."""
    from test_listener_pipeline import _datagrams

    listener, obcu, lport, obcu_csv = _start(world, tmp_path)
    dgrams = _datagrams(world["run"])
    try:
        _send(lport, dgrams, SPEED, inject)
        rc = listener.wait(timeout=60)
        _wait_quiet(obcu_csv)
    finally:
        if listener.poll() is None:
            listener.kill()
        obcu.terminate()
        obcu.wait(timeout=10)
    return rc, obcu_csv


def test_forged_ground_truth_and_stop_from_new_ports_change_nothing(world, tmp_path):  # noqa: F811
    """One GROUND TRUTH (arc 2000 m) and then one STOP from the attacker's own port while the control
    module is bound: both rejected, counted, warned about; the service goes on and stops only at the
    control module's STOP."""
    n_gt = n_stop = None

    def inject(i, socks, attacker, lport, dgrams):
        nonlocal n_gt, n_stop
        if i == 1500:
            n_gt = i
            forged = GroundTruth(0, 10.0, 0.0, 0.0, 2000.0, None, None)
            attacker.sendto(encode_input(forged), ("127.0.0.1", lport))
        if i == 2500:
            n_stop = i
            attacker.sendto(encode_input(Stop(1)), ("127.0.0.1", lport))

    rc, obcu_csv = _run_attack(world, tmp_path, inject)
    events = _events(tmp_path / "listener.log")
    assert rc == 0 and n_gt is not None and n_stop is not None
    exit_ev = next(e for e in events if e["event"] == "exit")
    assert exit_ev["reason"] == "stop datagram"
    assert exit_ev["input"]["rejected_by_reason"].get("sender_unknown") == 2
    assert exit_ev["input"]["stops"] == 1  # the control module's, at the end
    assert exit_ev["senders"]["rejected"] == {"sender_unknown": 2}
    warned = [e for e in events if e["event"] == "sender_rejected"]
    assert warned and warned[0]["level"] == "warning" and warned[0]["type"] == "ground_truth"
    assert any(e["event"] == "senders_mode" and e["mode"] == "tofu" for e in events)
    rows = _obcu_rows(obcu_csv)
    run = world["run"]
    epochs = np.array([float(r["epoch"]) for r in rows])
    err = np.abs(np.array([float(r["arc_length"]) for r in rows]) - np.interp(epochs, run.t_s, run.s_m))
    assert err.max() < 20.0, err.max()  # before: 1,800 m after the forged GROUND TRUTH
    assert epochs.max() > run.t_s[-1] - 1.0  # outputs to the end of the run (STOP did not end it early)


def test_a_forged_seq_jump_does_not_silence_the_imu(world, tmp_path):  # noqa: F811
    """One IMU datagram with SEQ + 100 from the IMU module's own socket: the outputs per second before
    and after it stay the same (before: the IMU was treated as "late" for the next 100 numbers)."""
    forged_at = {}

    def inject(i, socks, attacker, lport, dgrams):
        if i == 2000 and 47001 in socks:
            last = max(k for k in range(i) if dgrams[k][1][1] == 47001)
            msg = decode_input(dgrams[last][2])
            forged = ImuSample((msg.seq + 100) & 0xFFFF, 0.0, 0.0, -9.81, 0.0, 0.0, 0.0, msg.epoch)
            socks[47001].sendto(encode_input(forged), ("127.0.0.1", lport))
            forged_at["epoch"] = msg.epoch

    rc, obcu_csv = _run_attack(world, tmp_path, inject)
    assert rc == 0 and "epoch" in forged_at
    events = _events(tmp_path / "listener.log")
    exit_ev = next(e for e in events if e["event"] == "exit")
    seq = exit_ev["sequencing"]
    assert (seq["late"], seq["lost"], seq["jump_drops"]) == (0, 0, 1)
    assert any(e["event"] == "sequence_jump_held" for e in events)
    rows = _obcu_rows(obcu_csv)
    epochs = np.array([float(r["epoch"]) for r in rows])
    tf = forged_at["epoch"]
    before = int(np.sum((epochs >= tf - 5.0) & (epochs < tf)))
    after = int(np.sum((epochs >= tf) & (epochs < tf + 5.0)))
    print(f"outputs in the 5 s before the forgery: {before}, after: {after}")
    assert before > 400 and after >= 0.95 * before


def test_stop_after_a_gap_exits_within_one_second(world, tmp_path):  # noqa: F811
    """GROUND TRUTH SEQ 0, then STOP SEQ 2 (SEQ 1 lost) from the control socket: the hold timer releases
    the STOP and the listener exits (before: it never did)."""
    listener, obcu, lport, obcu_csv = _start(world, tmp_path)
    ctl = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    ctl.bind(("127.0.0.1", 0))
    try:
        ctl.sendto(encode_input(GroundTruth(0, 10.0, 0.0, 0.0, 100.0, None, 1000.0)), ("127.0.0.1", lport))
        time.sleep(0.2)
        sent = time.monotonic()
        ctl.sendto(encode_input(Stop(2)), ("127.0.0.1", lport))
        rc = listener.wait(timeout=10)
        took = time.monotonic() - sent
    finally:
        ctl.close()
        if listener.poll() is None:
            listener.kill()
        obcu.terminate()
        obcu.wait(timeout=10)
    print(f"STOP after a gap: exit {took * 1000:.0f} ms after it was sent")
    assert rc == 0 and took < 1.0
    exit_ev = next(e for e in _events(tmp_path / "listener.log") if e["event"] == "exit")
    assert exit_ev["reason"] == "stop datagram" and exit_ev["sequencing"]["lost"] == 1
