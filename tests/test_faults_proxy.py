"""sfa faults proxy on real UDP sockets: per-client forwarding, replies back, counters, exit log."""

from __future__ import annotations

import asyncio
import io
import json
import socket
import subprocess
import sys

import pytest

from tools.faults.config import Impairments
from tools.faults.core import FaultCore
from tools.faults.proxy import UdpFaultProxy


def _udp(port: int = 0) -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", port))
    s.settimeout(2.0)
    return s


async def _echo_upstream(n_expected: int, received: list, stop: asyncio.Event, port_box: list):
    """An upstream that records (source, payload) and answers each datagram with b'ack' + payload."""
    loop = asyncio.get_running_loop()

    class P(asyncio.DatagramProtocol):
        def connection_made(self, tr):
            self.tr = tr

        def datagram_received(self, data, addr):
            received.append((addr, data))
            self.tr.sendto(b"ack" + data, addr)
            if len(received) >= n_expected:
                stop.set()

    tr, _ = await loop.create_datagram_endpoint(P, local_addr=("127.0.0.1", 0))
    port_box.append(tr.get_extra_info("sockname")[1])
    return tr


def test_forwarding_per_client_and_replies_come_back():
    async def main():
        received: list = []
        stop = asyncio.Event()
        box: list = []
        up = await _echo_upstream(40, received, stop, box)
        log = io.StringIO()
        core = FaultCore(Impairments(), seed=0)
        proxy = UdpFaultProxy(core, ("127.0.0.1", 0), ("127.0.0.1", box[0]), log=log)
        task = asyncio.ensure_future(proxy.run(duration_s=10.0))
        for _ in range(100):
            if proxy.bound:
                break
            await asyncio.sleep(0.01)
        loop = asyncio.get_running_loop()
        clients = [_udp(), _udp()]
        for c in clients:
            c.setblocking(False)
        for i in range(20):
            for k, c in enumerate(clients):
                c.sendto(bytes([k, i]), proxy.bound)
            await asyncio.sleep(0.002)
        await asyncio.wait_for(stop.wait(), 5.0)
        replies = {0: [], 1: []}
        deadline = loop.time() + 3.0
        while loop.time() < deadline and sum(map(len, replies.values())) < 40:
            for k, c in enumerate(clients):
                try:
                    replies[k].append(c.recv(100))
                except BlockingIOError:
                    pass
            await asyncio.sleep(0.005)
        task.cancel()
        try:
            await task
        except asyncio.CancelledError:
            pass
        up.close()
        for c in clients:
            c.close()
        return received, replies, proxy.stats(), log.getvalue()

    received, replies, stats, log = asyncio.run(main())
    sources = {addr for addr, _ in received}
    assert len(sources) == 2  # one upstream socket per client: the upstream still sees two senders
    by_source = {}
    for addr, data in received:
        by_source.setdefault(addr, []).append(data)
    assert sorted(v[0][0] for v in by_source.values()) == [0, 1]
    for v in by_source.values():
        assert [d[1] for d in v] == list(range(20))  # order kept per client
    assert replies[0] == [b"ack" + bytes([0, i]) for i in range(20)]
    assert replies[1] == [b"ack" + bytes([1, i]) for i in range(20)]
    assert stats["received"] == 40 and stats["forwarded"] == 40 and stats["replies_forwarded"] == 40
    assert json.loads(log.splitlines()[0])["event"] == "proxy_ready"
    assert json.loads(log.splitlines()[-1])["event"] == "proxy_exit"


def test_cli_proxy_process_counts_match_what_arrived(tmp_path):
    """The real `sfa faults proxy` process: 20 % loss with a seed; what arrives == forwarded count."""
    upstream = _udp()
    up_port = upstream.getsockname()[1]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        listen_port = probe.getsockname()[1]
    proc = subprocess.Popen(
        [sys.executable, "-m", "sfa", "faults", "proxy", "--listen", f"127.0.0.1:{listen_port}", "--forward",
         f"127.0.0.1:{up_port}", "--loss", "0.2", "--seed", "3", "--duration", "20"],
        stderr=subprocess.PIPE, text=True,
    )
    try:
        line = proc.stderr.readline()
        assert json.loads(line)["event"] == "proxy_ready"
        client = _udp()
        got = []

        def drain(timeout_s: float) -> None:  # read while sending: the receive buffer stays small
            upstream.settimeout(timeout_s)
            while True:
                try:
                    got.append(int.from_bytes(upstream.recv(10), "little"))
                except TimeoutError:
                    return

        for i in range(500):
            client.sendto(i.to_bytes(2, "little"), ("127.0.0.1", listen_port))
            if i % 20 == 19:
                drain(0.02)
        drain(1.0)
        proc.terminate()
        _, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
        upstream.close()
    exit_ev = json.loads(err.strip().splitlines()[-1])
    assert exit_ev["event"] == "proxy_exit"
    assert exit_ev["received"] == 500
    assert exit_ev["forwarded"] == len(got) == 500 - exit_ev["dropped_loss"]
    assert 60 < exit_ev["dropped_loss"] < 140
    assert got == sorted(got)


def test_cli_rejects_bad_options():
    argv = [sys.executable, "-m", "sfa", "faults", "proxy", "--listen", "127.0.0.1:0",
            "--forward", "127.0.0.1:9"]
    res = subprocess.run([*argv, "--loss", "2"], capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and "loss" in res.stderr
    res = subprocess.run([sys.executable, "-m", "sfa", "faults"], capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and "subcommand" in res.stderr


@pytest.mark.parametrize("text", ["nohost", "1.2.3.4:x", ":80"])
def test_address_option_errors(text):
    res = subprocess.run([sys.executable, "-m", "sfa", "faults", "proxy", "--listen", text, "--forward",
                          "127.0.0.1:9"], capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and "HOST:PORT" in res.stderr
