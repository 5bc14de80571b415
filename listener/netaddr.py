"""UDP socket helpers: one-line errors for socket addresses, the receive buffer, the kernel's drops.

The errors say which host and port failed, and why, in the user's words.

``OSError("[Errno 98] Address already in use")`` names neither the address nor the setting that chose
it. These helpers turn a bind, connect or name-resolution failure into a :class:`ConfigError` whose
message names the setting, the host and the port (``sfa listen`` / ``sfa obcu`` print it as their
one-line reason).
"""

from __future__ import annotations

import errno
import os
import socket

from listener.errors import ConfigError

__all__ = ["address_error", "bind_udp", "kernel_drops", "open_udp", "request_receive_buffer", "resolve_udp"]

SO_RCVBUFFORCE = getattr(socket, "SO_RCVBUFFORCE", 33)  #: Linux; not exported by Python 3.11


def address_error(exc: OSError, what: str, host: str, port: int) -> ConfigError:
    """A ConfigError naming ``what`` (the setting or option), ``host:port`` and the cause of ``exc``."""
    where = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
    if isinstance(exc, socket.gaierror):
        why = f"cannot resolve the host {host!r} ({exc.strerror or exc})"
    elif exc.errno == errno.EADDRINUSE:
        why = f"address already in use (another process holds UDP port {port} on {host})"
    elif exc.errno == errno.EADDRNOTAVAIL:
        why = f"{host!r} is not an address of this host"
    elif exc.errno == errno.EACCES:
        why = "permission denied (ports below 1024 need privileges)"
    else:
        why = exc.strerror or str(exc)
    return ConfigError(f"{what} {where}: {why}")


def resolve_udp(host: str, port: int, what: str) -> None:
    """Raise a ConfigError naming ``host`` if it does not resolve to a UDP address."""
    try:
        socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)
    except OSError as exc:  # socket.gaierror
        raise address_error(exc, what, host, port) from None


def bind_udp(sock: socket.socket, host: str, port: int, what: str) -> None:
    """``sock.bind((host, port))``; on failure close ``sock`` and raise a ConfigError naming the address."""
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        raise address_error(exc, what, host, port) from None


def request_receive_buffer(sock: socket.socket, size_bytes: int) -> int | None:
    """Ask for a ``size_bytes`` receive buffer (SO_RCVBUFFORCE first: root may exceed net.core.rmem_max,
    others get at most that); returns what the kernel granted (Linux reports twice the size asked for,
    its bookkeeping overhead), or None where it cannot say."""
    for option in (SO_RCVBUFFORCE, socket.SO_RCVBUF):
        try:
            sock.setsockopt(socket.SOL_SOCKET, option, size_bytes)
            break
        except OSError:
            continue
    try:
        return sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
    except OSError:  # pragma: no cover
        return None


def open_udp(host: str, port: int, receive_buffer_bytes: int, what: str) -> tuple[socket.socket, int | None]:
    """A UDP socket (IPv6 when ``host`` has a colon) with a ``receive_buffer_bytes`` receive buffer
    asked for (:func:`request_receive_buffer`), bound to ``host:port`` (:func:`bind_udp`: a failure is a
    ConfigError naming ``what``); returns it and the buffer size the kernel granted."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_DGRAM)
    granted = request_receive_buffer(sock, receive_buffer_bytes)
    bind_udp(sock, host, port, what)
    return sock, granted


def kernel_drops(sock: socket.socket) -> int | None:
    """Datagrams the kernel dropped for ``sock`` (receive buffer full), from /proc; None where unreadable."""
    try:
        inode = str(os.fstat(sock.fileno()).st_ino)
        name = "udp6" if sock.family == socket.AF_INET6 else "udp"
        with open(f"/proc/self/net/{name}") as fh:
            for line in fh:
                fields = line.split()
                if len(fields) > 12 and fields[9] == inode:
                    return int(fields[-1])
    except (OSError, ValueError):
        return None
    return None
