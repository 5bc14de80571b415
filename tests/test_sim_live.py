"""Live mode: one process per module on 127.0.0.1 delivers the same datagrams as the offline run."""

from __future__ import annotations

import socket
import threading
import time

import pytest

from interface_modules.live import LiveRunner, run_live, schedules_from_run
from interface_modules.offline import generate
from interface_modules.scenario import scenario_from_dict
from listener.codec import Stop, decode_input
from tools.processes import free_udp_port

RECEIVE_LIMIT_S = 30.0  #: hard bound on every receive loop


def short_scenario(port_base: int) -> dict:
    return {
        "scenario": {"name": "live-test", "seed": 3, "tail_s": 1.0},
        "track": {"database": "synthetic", "line_speed_kmh": 40.0, "segments": [{"length_m": 400.0}]},
        "train": {"preset": "tram"},
        "journey": {"points": [{"name": "A", "s_m": 10.0, "departure_s": 1.0}, {"name": "B", "s_m": 300.0}]},
        "sensors": {
            "imu": {"port": port_base + 1, "seq_start": 65530},
            "odometer": {"port": port_base + 2},
            "gps": {"port": port_base + 3},
            "control": {"port": port_base},
        },
    }


class Receiver:
    """A UDP socket on 127.0.0.1 collecting datagrams until STOP (bounded in time)."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.2)
        self.got: list[tuple[int, bytes]] = []
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    @property
    def address(self) -> tuple[str, int]:
        return self.sock.getsockname()

    def _run(self) -> None:
        deadline = time.monotonic() + RECEIVE_LIMIT_S
        while time.monotonic() < deadline:
            try:
                data, addr = self.sock.recvfrom(2048)
            except TimeoutError:
                continue
            self.got.append((addr[1], data))
            if data[0] == 10:  # STOP
                return

    def join(self) -> None:
        self.thread.join(RECEIVE_LIMIT_S + 1.0)
        self.sock.close()


def free_port_base() -> int:
    """Four consecutive free UDP ports on 127.0.0.1 (checked by binding them)."""
    for base in range(47100, 47900, 7):
        socks = []
        try:
            for k in range(4):
                s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                socks.append(s)
                s.bind(("127.0.0.1", base + k))
            return base
        except OSError:
            continue
        finally:
            for s in socks:
                s.close()
    raise RuntimeError("no free ports")


def test_live_run_delivers_the_offline_datagrams():
    base = free_port_base()
    run = generate(scenario_from_dict(short_scenario(base)), max_duration_s=8.0)
    rx = Receiver()
    t0 = time.monotonic()
    report = run_live(run, rx.address, speed=10.0)
    rx.join()
    assert not report.interrupted
    assert time.monotonic() - t0 < 15.0
    offline: dict[int, list[bytes]] = {}
    for p in run.packets:
        offline.setdefault(p.src_port, []).append(p.payload)
    live: dict[int, list[bytes]] = {}
    for port, data in rx.got:
        live.setdefault(port, []).append(data)
    assert set(live) == {base, base + 1, base + 2, base + 3}  # one socket per module
    for port, payloads in offline.items():
        assert live[port] == payloads  # same bytes, same order per sender (loopback does not drop here)
    assert report.sent == {name: len(run.packets_of(name)) for name in run.ports}
    assert isinstance(decode_input(rx.got[-1][1]), Stop)
    # real time scaled by 10: 8 s of scenario take about 0.8 s of wall time
    assert 0.6 < report.wall_s < 5.0


def test_stop_mid_run_sends_stop_with_the_next_sequence_number():
    run = generate(scenario_from_dict(short_scenario(47000)), max_duration_s=60.0)
    rx = Receiver()
    runner = LiveRunner(schedules_from_run(run, ephemeral_ports=True), rx.address, speed=5.0)
    runner.start()
    time.sleep(1.0)
    runner.stop()
    sent = runner.join()
    rx.join()
    control = [d for _, d in rx.got if d[0] in (8, 9, 10)]
    assert isinstance(decode_input(control[-1]), Stop)
    seqs = [decode_input(d).seq for d in control]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))  # STOP takes the next number
    assert sum(sent.values()) == len(rx.got) < len(run.packets)


def test_port_in_use_fails_cleanly():
    blocker = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    blocker.bind(("127.0.0.1", 0))
    port = blocker.getsockname()[1]
    try:
        data = short_scenario(47000)
        data["sensors"]["gps"]["port"] = port
        run = generate(scenario_from_dict(data), max_duration_s=2.0)
        from interface_modules.errors import SimError

        with pytest.raises(SimError, match="cannot bind"):
            run_live(run, ("127.0.0.1", 9), speed=10.0)
    finally:
        blocker.close()


def test_live_and_offline_agree_on_a_shipped_scenario():
    from interface_modules.scenario import load_scenario

    run = generate(load_scenario("tram-faults"), max_duration_s=6.0)
    rx = Receiver()
    report = run_live(run, rx.address, speed=10.0, ephemeral_ports=True)
    rx.join()
    assert not report.interrupted
    live: dict[int, list[bytes]] = {}
    for port, data in rx.got:
        live.setdefault(port, []).append(data)
    offline = sorted([p.payload for p in run.packets_of(m)] for m in run.ports)
    assert sorted(live.values()) == offline  # per sender: the same datagrams in the same order


def _sent_total(stderr: str) -> int:
    """Datagrams a `sfa sim --live` run reports as sent ("sent control 12, gps 30, ... to ...")."""
    line = next(ln for ln in stderr.splitlines() if ln.startswith("live run"))
    part = line.split(" sent ", 1)[1].split(" to ", 1)[0]
    return sum(int(item.split()[-1]) for item in part.split(","))


@pytest.mark.slow
def test_authenticated_live_senders_against_sfa_listen(tmp_path):
    """`sfa sim --live --auth-key-file` against `sfa listen` with auth on: every datagram accepted;
    the same run with a wrong key is rejected at the tag, datagram for datagram (its STOP included)."""
    import json
    import subprocess
    import sys

    from tools.processes import listen_argv

    key, wrong = tmp_path / "master.hex", tmp_path / "wrong.hex"
    key.write_text(bytes(range(32)).hex() + "\n")
    wrong.write_text(bytes(range(1, 33)).hex() + "\n")
    lport, oport = free_udp_port(), free_udp_port()
    log = tmp_path / "listener.log"
    obcu = subprocess.Popen(
        [sys.executable, "-m", "sfa", "obcu", "--port", str(oport), "--quiet", "--auth-key-file", str(key)],
        stderr=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
    )
    listener = subprocess.Popen(
        listen_argv(lport, oport, "auth.enabled=true", f"auth.key_file={key}"),
        stderr=open(log, "w"),  # noqa: SIM115
        stdout=subprocess.DEVNULL,
    )

    def sim(key_file, duration: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            [
                sys.executable,
                "-m",
                "sfa",
                "sim",
                "tram-urban",
                "--live",
                "--target",
                f"127.0.0.1:{lport}",
                "--speed",
                "8",
                "--duration",
                duration,
                "--ephemeral-ports",
                "--auth-key-file",
                str(key_file),
            ],
            capture_output=True,
            text=True,
            timeout=120,
        )

    try:
        end = time.monotonic() + 180
        while '"event":"ready"' not in log.read_text():
            assert listener.poll() is None, log.read_text()
            assert time.monotonic() < end
            time.sleep(0.05)
        forged = sim(wrong, "4")  # its STOP is wrapped under the wrong key too: the listener keeps running
        assert forged.returncode == 0, forged.stderr
        assert listener.poll() is None
        real = sim(key, "20")
        assert real.returncode == 0, real.stderr
        assert listener.wait(timeout=60) == 0  # the authenticated STOP ended it
    finally:
        for p in (listener, obcu):
            if p.poll() is None:
                p.kill()
                p.wait(timeout=10)
    exit_ev = [json.loads(ln) for ln in log.read_text().splitlines() if '"event":"exit"' in ln][-1]
    n_forged, n_real = _sent_total(forged.stderr), _sent_total(real.stderr)
    auth = exit_ev["auth"]
    assert n_forged > 100 and n_real > 1000
    assert auth["input_rejected"] == {"auth_tag": n_forged}
    assert auth["input_accepted"] == n_real
    assert exit_ev["input"]["received"] == n_forged + n_real
    assert exit_ev["input"]["rejected_by_reason"] == {"auth_tag": n_forged}
    assert exit_ev["sequencing"]["lost"] == 0
    assert exit_ev["link"]["outputs"] > 1000 and exit_ev["link"]["acks"] > 0  # authenticated acks came back
