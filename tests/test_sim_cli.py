"""``sfa sim``: offline outputs, listing, errors as one line and exit status 2 (real processes)."""

from __future__ import annotations

import subprocess
import sys

import dpkt

from listener.codec import decode_input

SFA = [sys.executable, "-m", "sfa"]
SCENARIO = """
[scenario]
name = "cli-test"
seed = 4

[track]
database = "synthetic"
segments = [{ length_m = 600.0 }]

[train]
preset = "tram"

[[journey.points]]
name = "A"
s_m = 10.0
departure_s = 1.0

[[journey.points]]
name = "B"
s_m = 500.0
"""


def sfa(*args: str, timeout: float = 120.0) -> subprocess.CompletedProcess:
    return subprocess.run([*SFA, *args], capture_output=True, text=True, timeout=timeout)


def test_offline_run_writes_capture_truth_and_events(tmp_path):
    scenario = tmp_path / "s.toml"
    scenario.write_text(SCENARIO, encoding="utf-8")
    out = tmp_path / "out"
    res = sfa("sim", str(scenario), "--out-dir", str(out), "--duration", "20", "--seed", "9")
    assert res.returncode == 0, res.stderr
    assert "seed 9" in res.stderr and "datagrams" in res.stderr
    with open(out / "capture.pcap", "rb") as fh:
        frames = [dpkt.ethernet.Ethernet(buf) for _, buf in dpkt.pcap.Reader(fh)]
    assert len(frames) > 2000
    for eth in frames:
        decode_input(eth.data.data.data)
    lines = (out / "truth.csv").read_text(encoding="utf-8").splitlines()
    assert lines[0].startswith("epoch,arc_length,speed,accel,lat,lon,line_id") and len(lines) == 2001
    assert (out / "events.csv").read_text(encoding="utf-8").startswith("epoch,kind,detail")
    only = tmp_path / "only.pcap"
    res = sfa("sim", str(scenario), "--pcap", str(only), "--duration", "5")
    assert res.returncode == 0 and only.is_file() and not (tmp_path / "sim-cli-test").exists()


def test_list_and_errors(tmp_path):
    res = sfa("sim", "--list")
    assert res.returncode == 0 and "tram-urban:" in res.stdout and "regional-long:" in res.stdout
    res = sfa("sim", "no-such-scenario")
    assert res.returncode == 2 and res.stderr.strip().startswith("sfa sim: error: unknown scenario")
    assert len(res.stderr.strip().splitlines()) == 1
    bad = tmp_path / "bad.toml"
    bad.write_text(SCENARIO.replace('preset = "tram"', 'preset = "tram"\nwheels = 8'), encoding="utf-8")
    res = sfa("sim", str(bad))
    assert res.returncode == 2 and "unknown key train.wheels" in res.stderr
    res = sfa("sim", "tram-urban", "--live", "--target", "nohostport")
    assert res.returncode == 2 and "HOST:PORT" in res.stderr
    res = sfa("sim", "tram-urban", "--speed", "0")
    assert res.returncode == 2 and "--speed must be > 0" in res.stderr


def test_live_cli_ctrl_c_sends_stop_and_exits_cleanly(tmp_path):
    import signal
    import socket
    import time

    from listener.codec import Stop

    scenario = tmp_path / "s.toml"
    scenario.write_text(SCENARIO, encoding="utf-8")
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(0.2)
    port = rx.getsockname()[1]
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "sfa",
            "sim",
            str(scenario),
            "--live",
            "--target",
            f"127.0.0.1:{port}",
            "--ephemeral-ports",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    got: list[bytes] = []
    try:
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline and len(got) < 200:  # about 1.5 s of real-time sending
            try:
                got.append(rx.recvfrom(2048)[0])
            except TimeoutError:
                continue
        assert len(got) >= 200, "no live datagrams"
        proc.send_signal(signal.SIGINT)
        while time.monotonic() < deadline:
            try:
                data = rx.recvfrom(2048)[0]
            except TimeoutError:
                continue
            got.append(data)
            if data[0] == 10:
                break
        _, err = proc.communicate(timeout=15.0)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        rx.close()
    assert isinstance(decode_input(got[-1]), Stop)
    assert proc.returncode == 130 and "interrupted, STOP sent" in err


def test_live_target_that_does_not_resolve_is_named_before_anything_is_sent():
    res = sfa("sim", "tram-urban", "--live", "--target", "no-such-host.invalid:48000", "--duration", "1")
    assert res.returncode == 2, res.stderr
    assert res.stderr.strip().splitlines() == [
        "sfa sim: error: --target 'no-such-host.invalid:48000': cannot resolve the host"
        " 'no-such-host.invalid' (Name or service not known)"
    ]
