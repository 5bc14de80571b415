"""listener.netaddr: bind and resolution failures name the setting, the host and the port (one line)."""

from __future__ import annotations

import os
import socket
import subprocess
import sys

import pytest

from listener.errors import ConfigError
from listener.netaddr import address_error, bind_udp, kernel_drops, request_receive_buffer, resolve_udp

BAD_HOST = "no-such-host.invalid"  # RFC 6761: .invalid never resolves


@pytest.fixture
def busy_port():
    """A UDP port on 127.0.0.1 held by this test (so a second bind fails with EADDRINUSE)."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    yield s.getsockname()[1]
    s.close()


def test_bind_in_use_names_the_address_and_closes_the_socket(busy_port):
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    with pytest.raises(ConfigError) as err:
        bind_udp(sock, "127.0.0.1", busy_port, "input socket")
    assert str(err.value) == (
        f"input socket 127.0.0.1:{busy_port}: address already in use "
        f"(another process holds UDP port {busy_port} on 127.0.0.1)"
    )
    assert sock.fileno() == -1


def test_unresolvable_host_is_named():
    with pytest.raises(ConfigError, match=rf"^OBCU {BAD_HOST}:48001: cannot resolve the host '{BAD_HOST}'"):
        resolve_udp(BAD_HOST, 48001, "OBCU")
    resolve_udp("127.0.0.1", 48001, "OBCU")  # a literal address resolves without any lookup


def test_other_errors_keep_the_address_and_the_cause():
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    with pytest.raises(ConfigError, match=r"^x 192\.0\.2\.1:5000: '192\.0\.2\.1' is not an address of this"):
        bind_udp(sock, "192.0.2.1", 5000, "x")  # TEST-NET-1: never local
    err = address_error(OSError(1, "Operation not permitted"), "y", "::1", 7)
    assert str(err) == "y [::1]:7: Operation not permitted"


def _sfa(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "sfa", *args], capture_output=True, text=True, timeout=120)


def _one_line(res: subprocess.CompletedProcess) -> str:
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1, res.stderr
    return lines[0]


def test_listen_and_obcu_name_the_port_in_use(busy_port):
    line = _one_line(_sfa("listen", "--bind", "127.0.0.1", "--port", str(busy_port), "--no-warm-up"))
    assert f"input socket (input.bind, input.port) 127.0.0.1:{busy_port}: address already in use" in line
    line = _one_line(_sfa("obcu", "--bind", "127.0.0.1", "--port", str(busy_port), "--quiet"))
    assert f"OBCU socket (--bind, --port) 127.0.0.1:{busy_port}: address already in use" in line


def test_listen_and_obcu_name_an_unresolvable_host():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        free = s.getsockname()[1]  # released before the listener binds it
    line = _one_line(_sfa("listen", "--bind", "127.0.0.1", "--port", str(free), "--obcu", f"{BAD_HOST}:48001",
                          "--no-warm-up"))  # fmt: skip
    assert f"OBCU (link.obcu_host, link.obcu_port) {BAD_HOST}:48001: cannot resolve the host" in line
    line = _one_line(_sfa("listen", "--bind", BAD_HOST, "--port", str(free), "--no-warm-up"))
    assert f"input socket (input.bind, input.port) {BAD_HOST}:{free}: cannot resolve the host" in line
    line = _one_line(_sfa("obcu", "--bind", BAD_HOST, "--port", str(free), "--quiet"))
    assert f"OBCU socket (--bind, --port) {BAD_HOST}:{free}: cannot resolve the host" in line


def test_fault_proxy_names_its_addresses(busy_port):
    line = _one_line(_sfa("faults", "proxy", "--listen", f"127.0.0.1:{busy_port}", "--forward", "127.0.0.1:9",
                          "--duration", "1"))  # fmt: skip
    assert f"proxy listen socket (--listen) 127.0.0.1:{busy_port}: address already in use" in line
    line = _one_line(_sfa("faults", "proxy", "--listen", "127.0.0.1:0", "--forward", f"{BAD_HOST}:9",
                          "--duration", "1"))  # fmt: skip
    assert f"proxy forward address (--forward) {BAD_HOST}:9: cannot resolve the host" in line


def test_kernel_drops_counts_what_a_full_receive_buffer_lost():
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        small = request_receive_buffer(rx, 4096)  # the kernel's minimum: a few datagrams at most
        rx.bind(("127.0.0.1", 0))
        assert small is not None and small < 65536
        assert kernel_drops(rx) == 0
        for _ in range(200):  # bounded: far more than 4 KiB holds
            tx.sendto(b"\x00" * 18, rx.getsockname())
        rx.setblocking(False)
        kept = 0
        for _ in range(200):
            try:
                rx.recv(64)
            except BlockingIOError:
                break
            kept += 1
        assert 0 < kept < 200
        assert kernel_drops(rx) == 200 - kept
    finally:
        rx.close()
        tx.close()


def test_a_larger_receive_buffer_is_granted_up_to_what_the_kernel_allows():
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        asked = 4 * 1024 * 1024
        granted = request_receive_buffer(sock, asked)
        with open("/proc/sys/net/core/rmem_max") as fh:
            rmem_max = int(fh.read())
        # Linux doubles the size asked for; root (SO_RCVBUFFORCE) gets it whole, others at most rmem_max
        expected = asked if os.geteuid() == 0 else min(asked, rmem_max)
        assert granted == 2 * expected
    finally:
        sock.close()
