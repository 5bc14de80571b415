"""One-line errors for socket addresses: which host and port failed, and why, in the user's words.

``OSError("[Errno 98] Address already in use")`` names neither the address nor the setting that chose
it. These helpers turn a bind, connect or name-resolution failure into a :class:`ConfigError` whose
message names the setting, the host and the port (``sfa listen`` / ``sfa obcu`` print it as their
one-line reason).
"""

from __future__ import annotations

import errno
import socket

from listener.errors import ConfigError

__all__ = ["address_error", "bind_udp", "resolve_udp"]


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
