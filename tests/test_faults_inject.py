"""The live campaign's injector process (tools.faults.inject) and the live mode's split and lag helpers."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from listener.codec import DecodeError, decode_input
from tools.faults.config import Impairments
from tools.faults.inject import Injector
from tools.faults.live import (
    FLOOD_SCHEDULE_SLACK,
    behind_schedule,
    injection_window_s,
    lag_ages,
    split_injections,
    window_p99_ms,
)


def _receiver() -> tuple[socket.socket, list[tuple[float, bytes]], threading.Thread]:
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(0.5)
    got: list[tuple[float, bytes]] = []

    def run() -> None:
        # done 0.5 s after the last datagram; before the first, the sender may still be starting (a
        # process on a loaded machine took longer than 0.5 s to send its first); bounded either way
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline:
            try:
                data = rx.recv(4096)
            except TimeoutError:
                if got:
                    return
                continue
            got.append((time.monotonic(), data))

    th = threading.Thread(target=run, daemon=True)
    th.start()
    return rx, got, th


def test_injector_sends_the_schedule_it_counts_and_nothing_it_should_not():
    """Window, rate, count cap and a blackout: what arrives == what it counted; all of it invalid."""
    rx, got, th = _receiver()
    imp = Impairments(forge_rate_hz=200.0, forge_count=50, garbage_rate_hz=2000.0, inject_start_s=0.3,
                      inject_end_s=0.8, blackouts=((0.5, 0.1),))
    t0 = time.monotonic()
    stats = Injector(imp, seed=4, target=rx.getsockname(), t0=t0).run(duration_s=5.0)
    th.join(5.0)
    rx.close()
    assert stats["send_errors"] == 0
    # 0.5 s of window, 0.1 s of it blacked out: 80 % of 1,000 garbage and of 100 forgeries (capped at 50)
    assert stats["garbage"] == 800
    assert stats["forged_invalid"] == 40  # the cap counts schedule slots: 10 of the 50 fell in the blackout
    assert stats["skipped_blackout"] == 200 + 10
    assert stats["emitted"] == stats["garbage"] + stats["forged_invalid"] == len(got)
    times = np.array([t for t, _ in got]) - t0
    assert times.min() >= 0.3 and stats["t_first"] - t0 >= 0.3
    assert stats["t_last"] - t0 < 0.8 + 0.05  # nothing due after the window's end (sent promptly)
    assert not np.any((times > 0.52) & (times < 0.59))  # the blackout (minus scheduling slack)
    for _, data in got:
        with pytest.raises(DecodeError):
            decode_input(data)


def test_injector_same_seed_same_datagrams():
    """Garbage blocks of 4096 drawn while forgeries are drawn one by one: the seed alone fixes both."""
    imp = Impairments(forge_rate_hz=200.0, forge_count=20, forge_valid_fraction=0.5, garbage_rate_hz=2e4,
                      inject_end_s=0.25)
    runs = []
    for _ in range(2):
        rx, got, th = _receiver()
        Injector(imp, seed=9, target=rx.getsockname(), t0=time.monotonic()).run(duration_s=3.0)
        th.join(5.0)
        rx.close()
        runs.append(sorted(d for _, d in got))
    assert len(runs[0]) == 20 + 5000  # forge_count caps the 50 forgery slots
    assert runs[0] == runs[1]
    rx, got, th = _receiver()
    Injector(imp, seed=10, target=rx.getsockname(), t0=time.monotonic()).run(duration_s=3.0)
    th.join(5.0)
    rx.close()
    assert sorted(d for _, d in got) != runs[0]


def test_injector_process_reports_its_counters_on_sigterm(tmp_path):
    """The process as the live runner starts it: an endless flood stopped by SIGTERM still reports."""
    rx, got, th = _receiver()
    profile = tmp_path / "links.toml"
    profile.write_text("[input_injector]\ngarbage_rate_hz = 500.0\n")
    host, port = rx.getsockname()
    proc = subprocess.Popen([sys.executable, "-m", "tools.faults.inject", "--target", f"{host}:{port}",
                             "--profile", str(profile), "--table", "input_injector", "--seed", "1",
                             "--duration", "30"], stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 30.0
        while len(got) < 200 and time.monotonic() < deadline:
            time.sleep(0.05)
        proc.terminate()
        err = proc.communicate(timeout=10.0)[1]
    finally:
        if proc.poll() is None:
            proc.kill()
    th.join(5.0)
    rx.close()
    events = [json.loads(line) for line in err.splitlines() if line.startswith("{")]
    assert events[0]["event"] == "injector_ready" and events[-1]["event"] == "injector_exit"
    assert events[-1]["garbage"] == events[-1]["emitted"] == len(got) >= 200


def test_injector_rejects_a_bad_profile(tmp_path):
    profile = tmp_path / "p.toml"
    profile.write_text("garbage_rate_hz = -1.0\n")
    res = subprocess.run([sys.executable, "-m", "tools.faults.inject", "--target", "127.0.0.1:9",
                          "--profile", str(profile)], capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and "garbage_rate_hz" in res.stderr


def test_split_keeps_forwarding_in_the_proxy_and_moves_the_injections():
    imp = Impairments(loss=0.1, forge_rate_hz=1000.0, forge_count=10, garbage_rate_hz=5e4, inject_start_s=3.0,
                      inject_end_s=4.0, blackouts=((1.0, 1.0),))
    proxy, inj = split_injections(imp)
    assert proxy.loss == 0.1 and proxy.garbage_rate_hz == 0.0 and proxy.forge_rate_hz == 0.0
    assert proxy.blackouts == imp.blackouts
    assert inj is not None and inj.loss == 0.0 and inj.garbage_rate_hz == 5e4 and inj.forge_count == 10
    assert (inj.inject_start_s, inj.inject_end_s, inj.blackouts) == (3.0, 4.0, imp.blackouts)
    # forgeries posing as a real sender need that sender's upstream socket: they stay in the proxy
    on_stream = Impairments(forge_rate_hz=50.0, forge_on_stream=True, forge_valid_fraction=1.0)
    proxy, inj = split_injections(on_stream)
    assert proxy.forge_rate_hz == 50.0 and inj is None
    assert split_injections(Impairments(loss=0.2)) == (Impairments(loss=0.2), None)


def test_lag_reference_skips_the_initialisation_outputs():
    epoch = np.array([0.0, 0.0, 0.01, 0.02, 0.03, 0.04])
    arrival = np.array([0.0, 0.1, 0.09, 0.1, 0.115, 0.12])  # the first output leads the stream by 80 ms
    age = lag_ages(arrival, epoch, speed=1.0)
    assert np.allclose(age, [-0.08, 0.02, 0.0, 0.0, 0.005, 0.0])
    assert np.allclose(lag_ages(arrival[:2], epoch[:2], 1.0), [0.0, 0.1])  # only the first epoch
    assert lag_ages(np.array([]), np.array([]), 1.0).size == 0
    sched = arrival - age
    p99, n = window_p99_ms(sched, age, 0.095, 0.115)  # sched = epoch + 80 ms
    assert n == 2 and p99 == pytest.approx(4.95, abs=0.01)
    assert window_p99_ms(sched, age, 5.0, 6.0) == (None, 0)


def test_a_starved_injector_is_behind_schedule():
    """The flood row's latency check only counts when the injector kept its rate: 510,000 datagrams
    sent over 10.00 s of a 10 s window is on schedule, over 12.67 s (measured once with a test suite
    running beside it: 40,252/s instead of 51,000/s) is not."""
    imp = Impairments(garbage_rate_hz=50_000.0, inject_start_s=30.0, inject_end_s=40.0)
    assert injection_window_s(imp) == 10.0
    assert not behind_schedule(10.0, injection_window_s(imp))
    assert not behind_schedule(FLOOD_SCHEDULE_SLACK * 10.0, 10.0)
    assert behind_schedule(12.67, injection_window_s(imp))
    assert not behind_schedule(1e6, injection_window_s(Impairments(garbage_rate_hz=10.0)))  # no end
    assert injection_window_s(None) == float("inf")
