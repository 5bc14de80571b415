"""Live, real processes and UDP on 127.0.0.1: ``sfa listen`` killed with SIGKILL and restarted resumes from
its checkpoint; a corrupt, stale or foreign checkpoint is refused; a forged far GROUND TRUTH and a shifted
STROBE stream from another port do not move or silence it; STOP exits with the configured status.

The sensors and the OBCU are mocked by this test (threads: a paced sender, an OBCU that records each
output with its arrival time and acks the newest SEQ once a second).
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from test_listener_pipeline import _datagrams
from test_listener_plausibility import CTL, _with

from interface_modules.presets import GPS_PRESETS, IMU_PRESETS, ODOMETER_PRESETS
from listener import checkpoint as ck
from listener.codec import (
    GroundTruth,
    Strobe,
    decode_output,
    decode_output_extended,
    encode_ack,
    encode_input,
)
from sfa.synthetic import build_track_db, generate
from tools.processes import free_udp_port
from track_db import TrackDatabase

pytestmark = pytest.mark.slow
STOP_STATUS = 10



@pytest.fixture(scope="module")
def world(tmp_path_factory):
    d = tmp_path_factory.mktemp("restart")
    track_path = build_track_db(d / "synthetic.db")
    track = TrackDatabase.open(track_path)
    run = generate(track, 1, 36.0, IMU_PRESETS["mems-train"], ODOMETER_PRESETS["wheel-odometer"],
                   GPS_PRESETS["standalone"], seed=12)
    yield {"track_path": track_path, "track": track, "run": run}
    track.close()


class Obcu:
    """The OBCU: records (monotonic arrival, datagram), acks the newest SEQ every second."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.port = self.sock.getsockname()[1]
        self.rows: list[tuple[float, bytes]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        last_ack = 0.0
        peer = None
        while not self._stop.is_set():
            try:
                data, peer = self.sock.recvfrom(2048)
                self.rows.append((time.monotonic(), data))
            except (TimeoutError, BlockingIOError):
                pass
            except OSError:
                return
            if peer is not None and self.rows and time.monotonic() - last_ack >= 1.0:
                last_ack = time.monotonic()
                try:
                    self.sock.sendto(encode_ack(decode_output(self.rows[-1][1][:18]).seq), peer)
                except OSError:
                    pass

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self.sock.close()


class Sender(threading.Thread):
    """Sends (t, addr, payload) rows paced at real time from t_start (monotonic); one socket per source."""

    def __init__(self, port: int, rows, t_start: float) -> None:
        super().__init__(daemon=True)
        self.port, self.rows, self.t_start = port, rows, t_start
        self.stopped = threading.Event()

    def run(self) -> None:
        socks: dict = {}
        t0 = self.rows[0][0]
        for t, addr, data in self.rows:
            if self.stopped.is_set():
                break
            delay = self.t_start + (t - t0) - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            s = socks.get(addr)
            if s is None:
                s = socks[addr] = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                s.bind(("127.0.0.1", 0))
            try:
                s.sendto(data, ("127.0.0.1", self.port))
            except OSError:
                pass
        for s in socks.values():
            s.close()


def _listener(world, log: Path, lport: int, oport: int, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "sfa", "listen", "--track", str(world["track_path"]), "--bind", "127.0.0.1",
         "--port", str(lport), "--obcu", f"127.0.0.1:{oport}", "--set", f"stop_exit_status={STOP_STATUS}",
         *extra],
        stderr=open(log, "a"), stdout=subprocess.DEVNULL, env=dict(os.environ),
    )


def _run_stream(world, log: Path, rows, settle_s: float, *extra: str) -> Obcu:
    """One listener (``extra`` its arguments) sent ``rows`` once it is READY, stopped with SIGTERM
    ``settle_s`` after the last; the mock OBCU (closed) with what it received."""
    lport, obcu = free_udp_port(), Obcu()
    proc = _listener(world, log, lport, obcu.port, *extra)
    try:
        _wait_ready(proc, log)
        sender = Sender(lport, rows, time.monotonic() + 0.1)
        sender.start()
        sender.join(timeout=60)
        time.sleep(settle_s)
    finally:
        proc.terminate()
        proc.wait(timeout=30)
        obcu.close()
    return obcu


def _wait_ready(proc, log: Path, n: int = 1, timeout: float = 180.0) -> float:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if log.read_text().count('"event":"ready"') >= n:
            return time.monotonic()
        if proc.poll() is not None:
            raise AssertionError(f"listener died: {log.read_text()[-2000:]}")
        time.sleep(0.02)
    raise AssertionError("listener not ready")


def _events(log: Path) -> list[dict]:
    return [json.loads(line) for line in log.read_text().splitlines() if line.startswith("{")]


def _story(log: Path) -> str:
    """The listener log without its routine lines (outputs, metrics, status): starts, checkpoints,
    resumes, warnings and exits, which a failure message needs to name its cause."""
    routine = ("metrics", "status", "reasons", "link_state", "sender_bound")
    return "\n".join(json.dumps(e)[:400] for e in _events(log) if e.get("event") not in routine)


def _truth_error(world, rows) -> np.ndarray:
    run = world["run"]
    msgs = [decode_output(d[:18]) for _, d in rows]
    epochs = np.array([m.epoch for m in msgs])
    return np.abs(np.array([m.arc_length for m in msgs]) - np.interp(epochs, run.t_s, run.s_m))


def _kill_and_restart(world, tmp_path: Path, kill_after: float):
    """One listener killed with SIGKILL kill_after seconds into the stream, a second started on its
    checkpoint and run to the stream's STOP: (OBCU rows, t_kill, t_restart, log, the checkpoint's body as
    the kill left it)."""
    lport, obcu = free_udp_port(), Obcu()
    log, ckpt = tmp_path / "listener.log", tmp_path / "state" / "ck.json"
    ckpt.parent.mkdir(parents=True)
    # the moment fit of the GNSS error model (the default until session 35): the tail's 2 m below is
    # what this world's GNSS allows (its fixes' own along-track p95 over the tail is 1.9-2.2 m), and the
    # maximum-likelihood model, which re-learns from its prior after a restart as both do, gave 1.57-2.09 m
    # in seven runs of these two seeds (the restart gap varies from run to run; 2.09 m twice on seed 1)
    # against the moment fit's 1.50 and 1.91 m; uninterrupted on this 36 s world, 1.04 against 0.84 m.
    # docs/filter.md, "Session 35"
    args = ("--set", f'checkpoint.path="{ckpt}"', "--set", "filter.set.gps_adaptive_ml=false")
    procs = []
    try:
        first = _listener(world, log, lport, obcu.port, *args)
        procs.append(first)
        _wait_ready(first, log)
        dgrams = _datagrams(world["run"], start_seq=100)
        sender = Sender(lport, dgrams, time.monotonic() + 0.2)
        sender.start()
        time.sleep(kill_after)
        first.kill()  # SIGKILL: no flush, no final checkpoint
        first.wait(timeout=10)
        t_kill = time.monotonic()
        assert ckpt.exists()
        at_kill = ck.decode(ckpt.read_bytes())
        t_restart = time.monotonic()
        second = _listener(world, log, lport, obcu.port, *args)
        procs.append(second)
        _wait_ready(second, log, n=2)
        sender.join(timeout=60)
        assert second.wait(timeout=30) == STOP_STATUS  # the stream's STOP; the unit does not restart it
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
        obcu.close()
    return obcu.rows, t_kill, t_restart, log, ckpt, at_kill


@pytest.mark.parametrize("seed", [1, 2])
def test_kill_9_at_a_random_time_resumes_within_3_s_and_seq_continues(world, tmp_path, seed):
    rng = np.random.default_rng(seed)
    kill_after = float(rng.uniform(8.0, 16.0))
    # The premise is a filter the first listener vouched for at its last checkpoint. The mock sensors are
    # threads of this (test) process: under CI load they once fell silent for 0.7 s, the filter had no
    # motion sensor (LOST), the vital supervision latched decay as it must (tests/test_listener_vital*),
    # and the checkpoint held no filter to resume. Such a run says nothing about resuming: it is run
    # again, once, and a second one fails with the log.
    for attempt in range(2):  # bounded: at most two streams of 36 s
        rows, t_kill, t_restart, log, ckpt, at_kill = _kill_and_restart(world, tmp_path / f"try{attempt}",
                                                                        kill_after)
        if at_kill.get("filter") is not None:
            break
    assert at_kill.get("filter") is not None, f"no filter vouched at the kill, twice:\n{_story(log)}"
    before = [r for r in rows if r[0] <= t_kill]
    after = [r for r in rows if r[0] > t_kill]
    assert before and after, f"{len(before)} outputs before the kill, {len(after)} after:\n{_story(log)}"
    resumed_in = after[0][0] - t_restart
    assert resumed_in < 3.0, resumed_in
    last_before = decode_output(before[-1][1]).seq
    seqs = [decode_output(d).seq for _, d in after]
    assert 0 < (seqs[0] - last_before) & 0xFFFF < 32768  # newer in serial order: a spec OBCU takes it
    assert all((b - a) & 0xFFFF == 1 for a, b in zip(seqs, seqs[1:], strict=False))
    events = _events(log)
    names = [e["event"] for e in events]
    assert names.count("checkpoint_loaded") == 1 and names.count("resumed") == 1
    resumed = next(e for e in events if e["event"] == "resumed")
    err = _truth_error(world, after)
    assert err.max() < 3.0 * resumed["sigma_s_m"]  # inside the widened interval from the first output on
    tail = [r for r in after if r[0] > after[0][0] + 5.0]
    assert np.percentile(_truth_error(world, tail), 95) < 2.0
    assert not ckpt.exists()  # STOP removes it: the next start waits for GROUND TRUTH
    exit_ev = [e for e in events if e["event"] == "exit"][-1]
    assert exit_ev["reason"] == "stop datagram"
    print(f"seed {seed}: killed at {kill_after:.2f} s, first output {resumed_in:.2f} s after the restart, "
          f"gap {resumed['gap_s']:.2f} s, seed sigma {resumed['sigma_s_m']:.1f} m, "
          f"max error after {err.max():.2f} m")


def _valid_body(world, **over) -> dict:
    body = {"track": ck.track_fingerprint(world["track"]), "taken": {"monotonic": time.monotonic(),
            "wall": time.time(), "boot_id": "not-this-boot"},
            "filter": {"t_s": 1000.0, "line_id": 1, "s_m": 20.0, "v_mps": 0.0, "direction": 1,
                       "sigma_s_m": 0.2, "sigma_v_mps": 0.05, "errors": {}, "status": 1},
            "link": {"next_seq": 5}, "auth": None, "extra": {}}
    body.update(over)
    return body


@pytest.mark.parametrize("kind", ["corrupt", "stale", "track", "checksum"])
def test_a_bad_checkpoint_is_refused_with_a_reason_and_ground_truth_awaited(world, tmp_path, kind):
    ckpt = tmp_path / "ck.json"
    if kind == "corrupt":
        ckpt.write_bytes(b'{"format": "sfa-listener-checkpoint", "vers')  # torn write
    elif kind == "stale":
        old = {"wall": time.time() - 3600.0, "monotonic": 0.0}
        ckpt.write_bytes(ck.encode(_valid_body(world, taken=old)))
    elif kind == "track":
        ckpt.write_bytes(ck.encode(_valid_body(world, track="0123456789abcdef")))
    else:
        ckpt.write_bytes(ck.encode(_valid_body(world)).replace(b'"s_m":20.0', b'"s_m":900.0'))
    log = tmp_path / "listener.log"
    dgrams = _datagrams(world["run"], start_seq=7)[:1500]  # starts with the GROUND TRUTH
    obcu = _run_stream(world, log, dgrams, 0.5, "--set", f'checkpoint.path="{ckpt}"')
    events = _events(log)
    refused = [e for e in events if e["event"] == "checkpoint_refused"]
    reason = {"corrupt": "corrupt", "stale": "stale", "track": "track", "checksum": "checksum"}[kind]
    assert len(refused) == 1 and refused[0]["reason"] == reason, refused
    assert not any(e["event"] in ("checkpoint_loaded", "resumed") for e in events)
    assert len(obcu.rows) > 1000  # the GROUND TRUTH initialised the filter as without a checkpoint
    assert decode_output(obcu.rows[0][1]).seq == 0  # and SEQ starts as configured
    assert np.percentile(_truth_error(world, obcu.rows), 95) < 2.0
    assert json.loads(ckpt.read_text())["format"] == ck.FORMAT  # replaced by a good one (SIGTERM)


def _shifted(rows, a0: float, a1: float, rate_hz: float, make) -> list:
    """Forgeries from the control module's own socket (a spoofed source), at rate_hz from a0 to a1 s."""
    t0 = rows[0][0]
    n = int((a1 - a0) * rate_hz)
    return [(t0 + a0 + k / rate_hz + 0.0003, CTL, make(a0 + k / rate_hz)) for k in range(n)]


def test_forged_ground_truth_and_shifted_strobes_from_the_control_socket(world, tmp_path):
    """At 6 s a GROUND TRUTH at 2,000 m (issue 20: 1,800 m error); from 10 s to 20 s STROBE at 2 Hz
    shifted by +100 s (issue 20: no output for the whole attack, status nominal); both from the
    control module's own socket, inside its SEQ stream (a spoofed source: a sender table cannot tell).
    The filter is not moved, outputs keep their rate, the extended status is DEGRADED
    (clock_untrusted) during the attack, and both are logged as warnings."""
    run = world["run"]
    dgrams = [d for d in _datagrams(run, start_seq=3) if d[2][0] != 10]
    epoch0 = run.t_s[0]
    forged = _shifted(dgrams, 6.0, 6.5, 2.0,
                      lambda t: encode_input(GroundTruth(0, 5.0, 0.0, 0.0, 2000.0, 1, epoch0 + t)))
    forged += _shifted(dgrams, 10.0, 20.0, 2.0, lambda t: encode_input(Strobe(0, epoch0 + t + 100.0)))
    rows = _with(dgrams, forged)  # inside the control module's SEQ stream
    log = tmp_path / "listener.log"
    obcu = _run_stream(world, log, rows[: next(i for i, r in enumerate(rows) if r[0] - rows[0][0] > 26.0)],
                       0.3, "--set", "link.extended=true")
    ext = [decode_output_extended(d) for _, d in obcu.rows]
    epochs = np.array([e.epoch for e in ext]) - epoch0
    err = _truth_error(world, obcu.rows)
    assert err.max() < 5.0, err.max()

    def rate(a, b):
        return np.count_nonzero((epochs >= a) & (epochs < b)) / (b - a)

    assert rate(11.0, 20.0) >= 0.9 * rate(1.0, 6.0) > 50.0
    during = {e.status for e, t in zip(ext, epochs, strict=True) if 11.0 <= t < 20.0}
    assert during == {2}  # DEGRADED
    events = _events(log)
    warned = [e["event"] for e in events if e["level"] == "warning"]
    assert warned.count("ground_truth_unconfirmed") == 1
    assert 2 <= warned.count("strobe_rejected") <= 3  # 10 s of attack, one warning per 5 s at most
    exit_ev = [e for e in events if e["event"] == "exit"][-1]
    assert exit_ev["clock"]["rejected_strobes"] == 20 and exit_ev["clock"]["resets"] == 0
    assert exit_ev["resilience"]["ground_truth"]["held"] == 1
