"""Loopback helpers shared by the live tests (real sockets on 127.0.0.1)."""

from __future__ import annotations

import socket
import time


def free_tcp_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago (UDP: tools.processes.free_udp_port)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def paced_send(port: int, dgrams, speed: float, before=None) -> dict[int, int]:
    """Send ``(t, addr, payload)`` rows to 127.0.0.1:``port`` paced at ``speed`` x real time, from one
    socket per module (per ``addr`` port), as the interface modules send. ``before(i, sock, socks)``
    runs before row i with the module's socket (and all of them) and may send extra datagrams. Returns
    each module socket's own port by module port (the sockets are closed)."""
    socks: dict[int, socket.socket] = {}
    t0 = dgrams[0][0]
    start = time.monotonic()
    try:
        for i, (t, addr, data) in enumerate(dgrams):
            delay = (t - t0) / speed - (time.monotonic() - start)
            if delay > 0:
                time.sleep(delay)
            s = socks.get(addr[1])
            if s is None:
                s = socks[addr[1]] = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                s.bind(("127.0.0.1", 0))
            if before is not None:
                before(i, s, socks)
            s.sendto(data, ("127.0.0.1", port))
        return {p: s.getsockname()[1] for p, s in socks.items()}
    finally:
        for s in socks.values():
            s.close()
