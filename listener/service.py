"""The asyncio layer of ``sfa listen``: sockets, timers, signals, systemd notifications, logs.

It only moves bytes and time: every decision is the pipeline core's (:mod:`listener.pipeline`).
``now`` is the event loop's monotonic clock. uvloop is used when installed.
"""

from __future__ import annotations

import asyncio
import signal
import socket
import time
from typing import Any

from listener.config import ListenerConfig
from listener.jsonlog import JsonLogger
from listener.pipeline import Pipeline
from listener.sdnotify import Notifier, watchdog_interval_s


class _InputProtocol(asyncio.DatagramProtocol):
    def __init__(self, service: ListenerService) -> None:
        self._service = service

    def datagram_received(self, data: bytes, addr: Any) -> None:
        self._service.on_input(data, addr)

    def error_received(self, exc: Exception) -> None:
        self._service.counters["input_socket_errors"] += 1


class _ObcuProtocol(asyncio.DatagramProtocol):
    def __init__(self, service: ListenerService) -> None:
        self._service = service

    def datagram_received(self, data: bytes, addr: Any) -> None:
        self._service.on_ack(data)

    def error_received(self, exc: Exception) -> None:
        # ICMP port unreachable while the OBCU is down: expected, counted, never fatal
        self._service.counters["obcu_socket_errors"] += 1


class ListenerService:
    """Runs one :class:`Pipeline` on real sockets until STOP, SIGTERM or SIGINT."""

    def __init__(
        self,
        pipeline: Pipeline,
        config: ListenerConfig,
        logger: JsonLogger | None = None,
        notifier: Notifier | None = None,
    ) -> None:
        self.pipeline = pipeline
        self.cfg = config
        self.log = logger or JsonLogger(
            level=config.log.level, warning_interval_s=config.log.warning_interval_s
        )
        self.notifier = notifier or Notifier()
        self.counters: dict[str, int] = {"input_socket_errors": 0, "obcu_socket_errors": 0, "send_errors": 0}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._in: asyncio.DatagramTransport | None = None
        self._out: asyncio.DatagramTransport | None = None
        self._timer: asyncio.TimerHandle | None = None
        self._timer_at: float | None = None
        self._done: asyncio.Event | None = None
        self._exit_reason = ""
        self._last_link_state = ""
        self._last_status = ""
        self.bound_port: int | None = None

    # ------------------------------------------------------------------ I/O callbacks
    def on_input(self, data: bytes, addr: Any) -> None:
        assert self._loop is not None
        self._send(self.pipeline.receive(data, addr, self._loop.time()))
        if self.pipeline.stopped:
            self._finish("stop datagram")
        self._rearm()

    def on_ack(self, data: bytes) -> None:
        assert self._loop is not None
        self._send(self.pipeline.receive_ack(data, self._loop.time()))
        self._rearm()

    def _on_timer(self) -> None:
        assert self._loop is not None
        self._timer = None
        self._timer_at = None
        self._send(self.pipeline.handle_timer(self._loop.time()))
        self._rearm()

    def _send(self, datagrams: list[bytes]) -> None:
        if not datagrams or self._out is None:
            return
        for payload in datagrams:
            try:
                self._out.sendto(payload)
            except OSError:
                self.counters["send_errors"] += 1
        state = self.pipeline.link.state.value
        if state != self._last_link_state:
            self._last_link_state = state
            self.log.info("link_state", state=state)

    def _rearm(self) -> None:
        assert self._loop is not None
        when = self.pipeline.next_timer()
        if when == self._timer_at:
            return
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self._timer_at = when
        if when is not None:
            self._timer = self._loop.call_at(when, self._on_timer)

    # ------------------------------------------------------------------ lifecycle
    def _finish(self, reason: str) -> None:
        if self._done is not None and not self._done.is_set():
            self._exit_reason = reason
            self._done.set()

    def status_line(self) -> str:
        m = self.pipeline.metrics()
        est = self.pipeline.last_estimate
        pos = "-" if est is None else f"s={est.arc_length_m:.1f}m v={est.speed_mps:.1f}m/s"
        return (
            f"{m['filter']['status'] or 'waiting'} {pos} line={m['filter']['line_id']} "
            f"rx={m['input']['received']} rej={m['input'].get('rejected', 0)} "
            f"out={m['link']['outputs']} link={m['link']['state']}"
        )

    async def _periodic_metrics(self) -> None:
        while True:
            await asyncio.sleep(self.cfg.log.metrics_interval_s)
            self.log.info("metrics", **self.metrics())
            status = self.status_line()
            if status != self._last_status:
                self._last_status = status
                self.notifier.status(status)

    async def _watchdog(self, period_s: float) -> None:
        """WATCHDOG=1 only while the loop is healthy: it wakes on time and the pipeline is not wedged."""
        assert self._loop is not None
        expected = self._loop.time() + period_s
        while True:
            await asyncio.sleep(max(0.0, expected - self._loop.time()))
            lag = self._loop.time() - expected
            expected = self._loop.time() + period_s
            if lag <= self.cfg.watchdog_max_lag_s:
                self.notifier.watchdog()
            else:
                self.log.warning("watchdog_withheld", loop_lag_s=lag)

    def metrics(self) -> dict[str, Any]:
        m = self.pipeline.metrics()
        m["service"] = dict(self.counters)
        return m

    async def run(self, warm_up: bool = True) -> int:
        """Bind, warm up, notify READY, serve until STOP or a signal; 0 on a clean exit."""
        loop = asyncio.get_running_loop()
        self._loop = loop
        self._done = asyncio.Event()
        inp = self.cfg.input
        family = socket.AF_INET6 if ":" in inp.bind else socket.AF_INET
        sock = socket.socket(family, socket.SOCK_DGRAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, inp.receive_buffer_bytes)
        except OSError:
            pass
        sock.bind((inp.bind, inp.port))
        sock.setblocking(False)
        self._in, _ = await loop.create_datagram_endpoint(lambda: _InputProtocol(self), sock=sock)
        self.bound_port = sock.getsockname()[1]
        link = self.cfg.link
        self._out, _ = await loop.create_datagram_endpoint(
            lambda: _ObcuProtocol(self), remote_addr=(link.obcu_host, link.obcu_port)
        )
        if warm_up:
            t0 = time.perf_counter()
            self.pipeline.filter.warm_up()
            lines = self.pipeline.filter.preload_lines()
            self.log.info("warm_up", seconds=round(time.perf_counter() - t0, 3), lines=lines)
        for sig in (signal.SIGTERM, signal.SIGINT):
            try:
                loop.add_signal_handler(sig, self._finish, signal.Signals(sig).name)
            except (NotImplementedError, RuntimeError):  # pragma: no cover - non-main thread / Windows
                pass
        tasks = [asyncio.ensure_future(self._periodic_metrics())]
        wd = watchdog_interval_s()
        if wd is not None:
            tasks.append(asyncio.ensure_future(self._watchdog(wd)))
        self.log.info(
            "ready",
            port=self.bound_port,
            bind=inp.bind,
            obcu=f"{link.obcu_host}:{link.obcu_port}",
            watchdog_s=wd,
        )
        self.notifier.ready(f"listening on {inp.bind}:{self.bound_port}")
        try:
            await self._done.wait()
        finally:
            for task in tasks:  # no WATCHDOG=1 after STOPPING=1
                task.cancel()
            self.notifier.stopping(f"stopping: {self._exit_reason or 'cancelled'}")
            if not self.pipeline.stopped:
                self._send(self.pipeline.flush(loop.time()))
            if self._timer is not None:
                self._timer.cancel()
            self.log.info("exit", reason=self._exit_reason, **self.metrics())
            for transport in (self._in, self._out):
                if transport is not None:
                    transport.close()
            for sig in (signal.SIGTERM, signal.SIGINT):
                try:
                    loop.remove_signal_handler(sig)
                except (NotImplementedError, RuntimeError):  # pragma: no cover
                    pass
        return 0


def run_service(service: ListenerService, warm_up: bool = True) -> int:
    """Run ``service`` on a fresh event loop (uvloop when installed)."""
    try:
        import uvloop

        factory = uvloop.new_event_loop
    except ImportError:  # pragma: no cover - uvloop is optional
        factory = None
    with asyncio.Runner(loop_factory=factory) as runner:
        return runner.run(service.run(warm_up=warm_up))
