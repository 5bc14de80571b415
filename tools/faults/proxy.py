"""The asyncio layer of ``sfa faults proxy``: sockets and timers around a :class:`FaultCore`.

Clients send to ``listen``; each client gets its own upstream socket (so the upstream sees one
source per client, as without the proxy: the listener keeps sequencing per sender), and whatever the
upstream answers on that socket goes back to that client (ACKs from the OBCU reach the listener).
Forged and garbage datagrams that do not pose as a client leave from one extra socket. ``now`` is the
event loop's monotonic clock; every decision is the core's. On exit one JSON line
``{"event": "proxy_exit", ...counters}`` is written to the log stream.
"""

from __future__ import annotations

import asyncio
import json
import signal
import sys
from collections import OrderedDict
from collections.abc import Hashable
from typing import Any, TextIO

from tools.faults.core import FORGE_SENDER, FaultCore
from tools.faults.forge import inner_payload

_IMMEDIATE_S = 0.0005  #: emissions due within this are sent at once rather than on a timer [s]


class _Listen(asyncio.DatagramProtocol):
    def __init__(self, proxy: UdpFaultProxy) -> None:
        self._proxy = proxy

    def datagram_received(self, data: bytes, addr: Any) -> None:
        self._proxy.on_client(data, addr)

    def error_received(self, exc: Exception) -> None:
        self._proxy.counters["socket_errors"] += 1


class _Upstream(asyncio.DatagramProtocol):
    def __init__(self, proxy: UdpFaultProxy, client: Hashable) -> None:
        self._proxy = proxy
        self._client = client

    def datagram_received(self, data: bytes, addr: Any) -> None:
        self._proxy.on_upstream(data, self._client)

    def error_received(self, exc: Exception) -> None:  # ICMP unreachable while upstream is down
        self._proxy.counters["socket_errors"] += 1


class UdpFaultProxy:
    """One proxy: ``listen`` (host, port) -> ``forward`` (host, port), impaired by ``core``."""

    def __init__(self, core: FaultCore, listen: tuple[str, int], forward: tuple[str, int],
                 log: TextIO | None = None, max_clients: int = 256) -> None:
        self.core = core
        self.listen = listen
        self.forward_to = forward
        self.log = log or sys.stderr
        self.max_clients = max_clients
        self.counters: dict[str, int] = {"socket_errors": 0, "send_errors": 0, "clients": 0,
                                         "clients_closed": 0}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._listen_tr: asyncio.DatagramTransport | None = None
        self._up: OrderedDict[Hashable, asyncio.DatagramTransport] = OrderedDict()
        self._pending_up: dict[Hashable, list[bytes]] = {}
        self._timer: asyncio.TimerHandle | None = None
        self._timer_at: float | None = None
        self.bound: tuple[str, int] | None = None

    # ------------------------------------------------------------------ I/O
    def on_client(self, data: bytes, addr: Any) -> None:
        assert self._loop is not None
        client = (addr[0], addr[1])
        first = self.core.start is None
        self._dispatch_up(self.core.forward(data, client, self._loop.time()))
        if first:  # the windows (blackouts, injections) count from here: say when, for alignment
            # (the loop's clock is time.monotonic(): the live campaign's injector process counts from it)
            print(json.dumps({"event": "proxy_started", "t_monotonic": self.core.start}), file=self.log,
                  flush=True)
        inner = inner_payload(data) if data else None
        if inner is not None and inner[0] == 10:  # a STOP: when it passed (the live campaign times the exit)
            print(json.dumps({"event": "proxy_stop_seen", "t_monotonic": self._loop.time()}), file=self.log,
                  flush=True)
        self._rearm()

    def on_upstream(self, data: bytes, client: Hashable) -> None:
        assert self._loop is not None
        for t, payload, dest in self.core.reply(data, client, self._loop.time()):
            self._at(t, self._send_client, payload, dest)

    def _send_client(self, payload: bytes, client: Any) -> None:
        if self._listen_tr is None:
            return
        try:
            self._listen_tr.sendto(payload, client)
        except OSError:
            self.counters["send_errors"] += 1

    def _dispatch_up(self, emits) -> None:
        for t, payload, sender in emits:
            self._at(t, self._send_up, payload, sender)

    def _at(self, t: float, fn, *args) -> None:
        assert self._loop is not None
        if t - self._loop.time() <= _IMMEDIATE_S:
            fn(*args)
        else:
            self._loop.call_at(t, fn, *args)

    def _send_up(self, payload: bytes, sender: Hashable) -> None:
        tr = self._up.get(sender)
        if tr is not None:
            self._up.move_to_end(sender)
            try:
                tr.sendto(payload)
            except OSError:
                self.counters["send_errors"] += 1
            return
        queue = self._pending_up.get(sender)
        if queue is not None:  # the socket is being created: keep order
            queue.append(payload)
            return
        self._pending_up[sender] = [payload]
        asyncio.ensure_future(self._open_upstream(sender))

    async def _open_upstream(self, sender: Hashable) -> None:
        assert self._loop is not None
        try:
            tr, _ = await self._loop.create_datagram_endpoint(
                lambda: _Upstream(self, sender), remote_addr=self.forward_to
            )
        except OSError:
            self.counters["socket_errors"] += 1
            self._pending_up.pop(sender, None)
            return
        self.counters["clients"] += 1
        self._up[sender] = tr
        if len(self._up) > self.max_clients:
            _, old = self._up.popitem(last=False)
            old.close()
            self.counters["clients_closed"] += 1
        for payload in self._pending_up.pop(sender, []):
            try:
                tr.sendto(payload)
            except OSError:
                self.counters["send_errors"] += 1

    def _on_timer(self) -> None:
        assert self._loop is not None
        self._timer = None
        self._timer_at = None
        self._dispatch_up(self.core.handle_timer(self._loop.time()))
        self._rearm()

    def _rearm(self) -> None:
        assert self._loop is not None
        when = self.core.next_timer()
        if when == self._timer_at:
            return
        if self._timer is not None:
            self._timer.cancel()
        self._timer_at = when
        self._timer = None if when is None else self._loop.call_at(when, self._on_timer)

    # ------------------------------------------------------------------ lifecycle
    def stats(self) -> dict[str, Any]:
        return {**self.core.stats(), **self.counters}

    async def run(self, duration_s: float | None = None, idle_exit_s: float | None = None) -> dict[str, Any]:
        """Serve until SIGTERM/SIGINT, ``duration_s``, or ``idle_exit_s`` without client datagrams."""
        loop = asyncio.get_running_loop()
        self._loop = loop
        from listener.netaddr import address_error, resolve_udp

        resolve_udp(self.forward_to[0], self.forward_to[1], "proxy forward address (--forward)")
        try:
            self._listen_tr, _ = await loop.create_datagram_endpoint(
                lambda: _Listen(self), local_addr=self.listen
            )
        except OSError as exc:
            raise address_error(exc, "proxy listen socket (--listen)", *self.listen) from None
        sock = self._listen_tr.get_extra_info("sockname")
        self.bound = (sock[0], sock[1])
        done = asyncio.Event()
        for sig in (signal.SIGTERM, signal.SIGINT):
            try:
                loop.add_signal_handler(sig, done.set)
            except (NotImplementedError, RuntimeError):  # pragma: no cover - non-main thread
                pass
        print(json.dumps({"event": "proxy_ready", "listen": f"{sock[0]}:{sock[1]}",
                          "forward": f"{self.forward_to[0]}:{self.forward_to[1]}", "seed": self.core.seed,
                          "profile": self.core.imp.as_dict()}), file=self.log, flush=True)
        self._rearm()
        start = loop.time()
        last_received = -1
        idle_since = start
        try:
            while not done.is_set():
                try:
                    await asyncio.wait_for(done.wait(), timeout=0.25)
                except TimeoutError:
                    pass
                now = loop.time()
                if duration_s is not None and now - start >= duration_s:
                    break
                received = self.core.counters.get("received", 0)
                if received != last_received:
                    last_received, idle_since = received, now
                elif idle_exit_s is not None and received > 0 and now - idle_since >= idle_exit_s:
                    break
        finally:
            if self._timer is not None:
                self._timer.cancel()
            stats = self.stats()
            print(json.dumps({"event": "proxy_exit", **stats}), file=self.log, flush=True)
            for tr in [self._listen_tr, *self._up.values()]:
                if tr is not None:
                    tr.close()
            for sig in (signal.SIGTERM, signal.SIGINT):
                try:
                    loop.remove_signal_handler(sig)
                except (NotImplementedError, RuntimeError):  # pragma: no cover
                    pass
        return stats


__all__ = ["FORGE_SENDER", "UdpFaultProxy"]
