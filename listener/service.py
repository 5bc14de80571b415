"""The asyncio layer of ``sfa listen``: sockets, timers, signals, systemd notifications, logs.

It only moves bytes and time: every decision is the pipeline core's (:mod:`listener.pipeline`).
``now`` is the event loop's monotonic clock. uvloop is used when installed.

The input socket is read in batches (``input.reader = "batched"``, the default): the socket is
non-blocking, ``loop.add_reader`` wakes the service when it is readable, and each wake-up drains up
to ``input.batch_datagrams`` datagrams with ``sock.recvfrom_into`` into one preallocated 64 KiB
buffer (Python's socket module has no ``recvmmsg``, so each datagram is still one system call, but
no Python object is made for a datagram that is rejected). Before a datagram is copied and handed to
the pipeline, :func:`early_reject_reason` checks what the codec would check first (length, SENSOR_TYPE,
the (N_INT, N_DOUBLE) form and the length it implies) and, with authenticated links, the length and
MAGIC byte (:meth:`listener.auth_link.LinkAuth.precheck_input`), before any HMAC. A datagram that
fails there is counted in the pipeline's counters under exactly the reason the pipeline would have
given it (``input.received``, ``input.rejected``, ``input.rejected_by_reason``) and goes no further;
the service counts them too (``service.early_rejected``). Timers are re-armed once per batch.
``input.reader = "protocol"`` keeps the earlier reader (an asyncio ``DatagramProtocol``, one callback
per datagram, every datagram through ``Pipeline.receive``) for comparison: ``benchmarks/bench_flood.py``.
"""

from __future__ import annotations

import asyncio
import os
import signal
import socket
import time
from pathlib import Path
from typing import Any

from listener import checkpoint as ckpt
from listener.codec import HEADER_SIZE, INPUT_FORMS, RejectReason, SensorType
from listener.config import ListenerConfig
from listener.jsonlog import JsonLogger
from listener.netaddr import address_error, kernel_drops, open_udp
from listener.pipeline import BatchCounts, Pipeline
from listener.sdnotify import Notifier, watchdog_interval_s

#: receive buffer of the batched reader: larger than any UDP payload, so nothing is ever cut
RECV_BUFFER_BYTES = 65536

_FORM_SIZES: dict[int, int] = {
    int(t) << 16 | n_int << 8 | n_double: HEADER_SIZE + 4 * n_int + 8 * n_double
    for t, n_int, n_double in INPUT_FORMS
}  # header key (type, N_INT, N_DOUBLE) -> the only valid datagram length
_TYPES = frozenset(int(t) for t in SensorType)
_SHORT, _TYPE, _LENGTH, _FORM = (
    str(r) for r in (RejectReason.SHORT, RejectReason.TYPE, RejectReason.LENGTH, RejectReason.FORM)
)


def early_reject_reason(buf: bytes | bytearray, n: int) -> str | None:
    """The codec's reject reason for the datagram ``buf[:n]`` if its header or length rules it out, else None.

    The same checks, in the same order, as :func:`listener.codec.decode_input` makes before it looks at
    a field (SHORT, TYPE, LENGTH, FORM), so a datagram rejected here is counted under the reason the
    pipeline would have given it; None means it may be valid (the full decode still checks the values).
    """
    if n < HEADER_SIZE:
        return _SHORT
    t, n_int, n_double = buf[0], buf[3], buf[4]
    if _FORM_SIZES.get(t << 16 | n_int << 8 | n_double) == n:
        return None
    if t not in _TYPES:
        return _TYPE
    if n != HEADER_SIZE + 4 * n_int + 8 * n_double:
        return _LENGTH
    return _FORM


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
            level=config.log.level,
            warning_interval_s=config.log.warning_interval_s,
            priority_prefix=config.log.priority_prefix,
        )
        self.notifier = notifier or Notifier()
        self.counters: dict[str, int] = {
            "input_socket_errors": 0,
            "obcu_socket_errors": 0,
            "send_errors": 0,
            "early_rejected": 0,
        }
        self._loop: asyncio.AbstractEventLoop | None = None
        self._in: asyncio.DatagramTransport | None = None
        self._sock: socket.socket | None = None  # the input socket (both readers)
        self._reading = False  # the batched reader is registered with the loop
        self._buf = bytearray(RECV_BUFFER_BYTES)
        self._view = memoryview(self._buf)
        self.receive_buffer_granted: int | None = None  # SO_RCVBUF as the kernel set it [bytes]
        self._out: asyncio.DatagramTransport | None = None
        self._timer: asyncio.TimerHandle | None = None
        self._timer_at: float | None = None
        self._done: asyncio.Event | None = None
        self._exit_reason = ""
        self._link_logged = 0
        self._last_status = ""
        self._work_started = 0.0  # loop time the current callback started (output latency)
        self.metrics_server = None  # listener.metrics.MetricsServer when [metrics] port is set
        self._wd_processed = -1  # pipeline 'processed' and 'received' at the last watchdog tick
        self._wd_received = -1
        self.bound_port: int | None = None
        self.checkpoint_path: Path | None = checkpoint_path(config)

    # ------------------------------------------------------------------ I/O callbacks
    def on_input(self, data: bytes, addr: Any) -> None:
        assert self._loop is not None
        self._work_started = self._loop.time()
        self._send(self.pipeline.receive(data, addr, self._work_started))
        if self.pipeline.stopped:
            self._finish("stop datagram")
        self._rearm()

    def _on_readable(self) -> None:
        """The batched reader: drain up to ``input.batch_datagrams`` datagrams from the input socket."""
        loop, sock, buf, view = self._loop, self._sock, self._buf, self._view
        assert loop is not None and sock is not None
        pipeline = self.pipeline
        auth = pipeline.auth
        now = self._work_started = loop.time()
        drain = False  # a rejection was the last thing the pipeline saw: it drains the merge at `now`
        tally: dict[str, int] = {}  # early rejections of this batch by reason, added to the counters once
        for _ in range(self.cfg.input.batch_datagrams):
            try:
                n, addr = sock.recvfrom_into(buf)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                self.counters["input_socket_errors"] += 1
                break
            if not pipeline.stopped:
                reason = early_reject_reason(buf, n) if auth is None else auth.precheck_input(buf, n)
                if reason is not None:
                    tally[reason] = tally.get(reason, 0) + 1
                    drain = True
                    continue
            self._send(pipeline.receive(bytes(view[:n]), addr, now))
            drain = False
            if pipeline.stopped:
                self._finish("stop datagram")
        if tally:
            total = sum(tally.values())
            pipeline.count_batch(BatchCounts(received=total, rejected=tally))
            self.counters["early_rejected"] += total
        if drain and not pipeline.stopped:
            # Pipeline.receive ends every rejection with a drain of the merge at `now`; handle_timer
            # does that drain (and only runs timers already due), once per batch instead of per datagram
            self._send(pipeline.handle_timer(now))
        self._rearm()

    def on_ack(self, data: bytes) -> None:
        assert self._loop is not None
        self._work_started = self._loop.time()
        self._send(self.pipeline.receive_ack(data, self._work_started))
        self._rearm()

    def _on_timer(self) -> None:
        assert self._loop is not None
        self._timer = None
        self._timer_at = None
        self._work_started = self._loop.time()
        self._send(self.pipeline.handle_timer(self._work_started))
        if self.pipeline.stopped:  # a STOP the hold timer released (it came after a gap in its stream)
            self._finish("stop datagram")
        self._rearm()

    # ------------------------------------------------------------------ checkpoint (thin I/O)
    def _write_checkpoint(self, body: dict[str, Any]) -> None:
        """Write ``body`` atomically (temporary file, fsync, rename, fsync of the directory)."""
        path = self.checkpoint_path
        if path is None:
            return
        body["taken"] = {
            **body["taken"],
            "monotonic": time.monotonic(),
            "wall": time.time(),
            "boot_id": boot_id(),
        }
        try:
            write_atomic(path, ckpt.encode(body))
            self.counters["checkpoints_written"] = self.counters.get("checkpoints_written", 0) + 1
        except (OSError, ValueError) as exc:
            self.counters["checkpoint_errors"] = self.counters.get("checkpoint_errors", 0) + 1
            self.log.warning("checkpoint_write_failed", path=str(path), error=str(exc))

    def _load_checkpoint(self, now: float) -> None:
        """Resume from the checkpoint file if there is an acceptable one; else say why and wait for
        GROUND TRUTH. Then checkpoints start."""
        path = self.checkpoint_path
        if path is None:
            self.log.info(
                "checkpoint_off",
                why="checkpoint.enabled is false, or no checkpoint.path and no STATE_DIRECTORY",
            )
            return
        res = self.pipeline.resilience
        try:
            data = path.read_bytes()
        except FileNotFoundError:
            self.log.info("checkpoint_none", path=str(path))
            data = None
        except OSError as exc:
            res.refused(ckpt.CheckpointError("unreadable", str(exc)), now)
            data = None
        res.load(data, now, wall_now=time.time(), mono_now=time.monotonic(), boot_id=boot_id())
        self._log_events()

    def _send(self, datagrams: list[bytes]) -> None:
        if datagrams and self._out is not None:
            for payload in datagrams:
                try:
                    self._out.sendto(payload)
                except OSError:
                    self.counters["send_errors"] += 1
            if self.metrics_server is not None:
                self.metrics_server.outputs_sent(len(datagrams), self._work_started)
        if self.pipeline.events or self.pipeline.link.transitions_total != self._link_logged:
            self._log_events()
        body = self.pipeline.resilience.take_checkpoint()  # taken by a timer the pipeline ran (1/s)
        if body is not None:
            self._write_checkpoint(body)

    def _log_events(self) -> None:
        """Every status, decay and link-state change as its own line, at once (never rate limited)."""
        self._link_logged = self.pipeline.link.transitions_total
        for ev in self.pipeline.take_events():
            kind = ev.pop("event")
            self.log.log(_event_level(kind, ev), kind, limit=False, **ev)

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
        m = self.metrics()
        est = self.pipeline.last_estimate
        pos = "-" if est is None else f"s={est.arc_length_m:.1f}m v={est.speed_mps:.1f}m/s"
        decay = self.pipeline.vital
        state = f"DECAY({decay.phase.value}) " if decay.latched else ""
        status = m.get("vital", {}).get("status") or m["filter"]["status"] or "waiting"  # timer-aware
        return (
            f"{state}{status} {pos} line={m['filter']['line_id']} "
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

    def filter_progress(self) -> bool:
        """The filter makes progress: it processed a measurement since the last call, or no new valid
        measurement arrived that it could have processed (idle is not a failure: silent sensors are
        the vital supervision's business, not the service manager's)."""
        by_type = self.pipeline.by_type  # valid measurements (STROBE and STOP are not the filter's)
        processed = self.pipeline.counters["processed"]
        received = by_type["imu"] + by_type["odometer"] + by_type["gps"] + by_type["ground_truth"]
        ok = processed != self._wd_processed or received == self._wd_received or self._wd_processed < 0
        self._wd_processed, self._wd_received = processed, received
        return ok

    async def _watchdog(self, period_s: float) -> None:
        """WATCHDOG=1 only while the event loop wakes on time and the filter makes progress."""
        assert self._loop is not None
        expected = self._loop.time() + period_s
        while True:
            await asyncio.sleep(max(0.0, expected - self._loop.time()))
            lag = self._loop.time() - expected
            expected = self._loop.time() + period_s
            progress = self.filter_progress()
            if lag <= self.cfg.watchdog_max_lag_s and progress:
                self.notifier.watchdog()
                self.counters["watchdog_sent"] = self.counters.get("watchdog_sent", 0) + 1
            else:
                self.counters["watchdog_withheld"] = self.counters.get("watchdog_withheld", 0) + 1
                self.log.warning("watchdog_withheld", loop_lag_s=lag, filter_progress=progress)

    def metrics(self) -> dict[str, Any]:
        m = self.pipeline.metrics(None if self._loop is None else self._loop.time())
        m["service"] = dict(self.counters)
        if self._sock is not None and self._sock.fileno() >= 0:
            m["service"]["kernel_drops"] = kernel_drops(self._sock)
        return m

    def _open_input_socket(self) -> socket.socket:
        inp = self.cfg.input
        sock, self.receive_buffer_granted = open_udp(inp.bind, inp.port, inp.receive_buffer_bytes,
                                                     "input socket (input.bind, input.port)")
        sock.setblocking(False)
        return sock

    async def run(self, warm_up: bool = True) -> int:
        """Bind, warm up, notify READY, serve until STOP or a signal; 0 on a clean exit."""
        loop = asyncio.get_running_loop()
        self._loop = loop
        self._done = asyncio.Event()
        inp = self.cfg.input
        if self.cfg.metrics.port:  # first: a port in use fails the start before any socket is open
            self.metrics_server = _start_metrics(self)
        sock = self._sock = self._open_input_socket()
        self.bound_port = sock.getsockname()[1]
        if inp.reader == "protocol":
            self._in, _ = await loop.create_datagram_endpoint(lambda: _InputProtocol(self), sock=sock)
        link = self.cfg.link
        try:
            self._out, _ = await loop.create_datagram_endpoint(
                lambda: _ObcuProtocol(self), remote_addr=(link.obcu_host, link.obcu_port)
            )
        except OSError as exc:
            what = "OBCU (link.obcu_host, link.obcu_port)"
            raise address_error(exc, what, link.obcu_host, link.obcu_port) from None
        self._load_checkpoint(loop.time())
        if warm_up:
            t0 = time.perf_counter()
            self.pipeline.filter.warm_up()
            from sfa.engine_build import jit_entry_points

            jit_entry_points()  # the listener's own kernels too, before READY (on the JIT only)
            lines = self.pipeline.filter.preload_lines()
            from sfa.engine import active

            self.log.info("warm_up", seconds=round(time.perf_counter() - t0, 3), lines=lines, engine=active())
        for sig in (signal.SIGTERM, signal.SIGINT):
            try:
                loop.add_signal_handler(sig, self._finish, signal.Signals(sig).name)
            except (NotImplementedError, RuntimeError):  # pragma: no cover - non-main thread / Windows
                pass
        if inp.reader == "batched":  # after the warm-up, as the protocol reader's datagrams wait for it
            loop.add_reader(sock.fileno(), self._on_readable)
            self._reading = True
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
            reader=inp.reader,
            receive_buffer_bytes=self.receive_buffer_granted,
            metrics_port=None if self.metrics_server is None else self.metrics_server.port,
        )
        self.notifier.ready(f"listening on {inp.bind}:{self.bound_port}")
        self._log_events()  # the sender table's mode (loud when permissive or trust on first use)
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
            self._final_checkpoint(loop.time())
            self.log.info("exit", reason=self._exit_reason, **self.metrics())
            if self._reading:
                loop.remove_reader(sock.fileno())
                self._reading = False
            for transport in (self._in, self._out):
                if transport is not None:
                    transport.close()
            if self._in is None:
                sock.close()
            if self.metrics_server is not None:
                self.metrics_server.stop()
            for sig in (signal.SIGTERM, signal.SIGINT):
                try:
                    loop.remove_signal_handler(sig)
                except (NotImplementedError, RuntimeError):  # pragma: no cover
                    pass
        return self.cfg.stop_exit_status if self.pipeline.stopped else 0

    def _final_checkpoint(self, now: float) -> None:
        """At a signal: one last checkpoint (a planned restart resumes); after a STOP datagram the file is
        removed (the operator ended the run: the next start waits for GROUND TRUTH)."""
        path = self.checkpoint_path
        res = self.pipeline.resilience
        if path is None or res.checkpointer is None:
            return
        if self.pipeline.stopped:
            try:
                path.unlink()
                self.log.info("checkpoint_removed", path=str(path), why="STOP")
            except FileNotFoundError:
                pass
            except OSError as exc:
                self.log.warning("checkpoint_remove_failed", path=str(path), error=str(exc))
            return
        self._write_checkpoint(res.body(now))


def checkpoint_path(cfg: ListenerConfig, environ: dict[str, str] | None = None) -> Path | None:
    """Where checkpoints go: ``checkpoint.path``, else ``$STATE_DIRECTORY/listener-checkpoint.json`` (the
    first directory when systemd lists several), else None (no checkpoint)."""
    ck = cfg.checkpoint
    if not ck.enabled:
        return None
    if ck.path:
        return Path(ck.path)
    state = (os.environ if environ is None else environ).get("STATE_DIRECTORY", "")
    first = state.split(":")[0]
    return Path(first) / "listener-checkpoint.json" if first else None


def write_atomic(path: Path, data: bytes) -> None:
    """Replace ``path`` by ``data`` so that a crash leaves either the old or the new file, whole."""
    tmp = path.with_name(f".{path.name}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    try:
        os.write(fd, data)
        os.fsync(fd)
    finally:
        os.close(fd)
    os.replace(tmp, path)
    dfd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dfd)
    finally:
        os.close(dfd)


def boot_id() -> str | None:
    """This boot's id (Linux), so a checkpoint's monotonic time is compared only within one boot."""
    try:
        return Path("/proc/sys/kernel/random/boot_id").read_text().strip()
    except OSError:
        return None


#: log level of each event kind (journald priority follows: journalctl -p warning shows all but info)
_EVENT_LEVELS = {
    "decay_entered": "error",
    "decay_fault": "error",
    "decay_recovery_reset": "warning",
    "decay_recovery_rejected": "warning",
    "decay_standstill": "info",
    "decay_reinitialised": "info",
    "decay_released": "warning",
    "reasons": "info",
    # issue 20 (listener.resilience): warnings, rate limited where they are raised
    "strobe_rejected": "warning",
    "clock_reset": "warning",
    "clock_rate_mismatch": "warning",
    "epoch_future": "warning",
    "stale_not_sent": "warning",
    "ground_truth_unconfirmed": "warning",
    "ground_truth_rejected": "warning",
    "ground_truth_confirmed": "warning",
    "output_implausible": "warning",
    "checkpoint_refused": "warning",
    "checkpoint_superseded": "warning",
    "checkpoint_loaded": "info",
    "resumed": "warning",
}


def _event_level(kind: str, ev: dict[str, Any]) -> str:
    level = ev.pop("level", None)  # the trust checks' events say theirs (listener.senders, seqbuf jumps)
    if level is not None:
        return level
    if kind == "status":
        return {"lost": "error", "degraded": "warning"}.get(ev.get("status"), "info")
    if kind == "link_state":
        return {"down": "error", "degraded": "warning"}.get(ev.get("state"), "info")
    return _EVENT_LEVELS.get(kind, "info")


def _start_metrics(service: ListenerService):
    """The Prometheus endpoint of ``[metrics]``; ConfigError (one line) when it cannot be served."""
    from listener.errors import ConfigError

    m = service.cfg.metrics
    try:
        from listener.metrics import MetricsServer
    except ImportError as exc:
        raise ConfigError(
            f"metrics.port={m.port}: the Prometheus endpoint needs prometheus_client ({exc.name} missing: "
            "pip install prometheus_client)"
        ) from exc
    server = MetricsServer(service, m)
    try:
        server.start()
    except OSError as exc:
        why = exc.strerror or exc
        raise ConfigError(f"metrics.port={m.port}: cannot serve on {m.bind}:{m.port}: {why}") from exc
    return server


def run_service(service: ListenerService, warm_up: bool = True) -> int:
    """Run ``service`` on a fresh event loop (uvloop when installed)."""
    try:
        import uvloop

        factory = uvloop.new_event_loop
    except ImportError:  # pragma: no cover - uvloop is optional
        factory = None
    with asyncio.Runner(loop_factory=factory) as runner:
        return runner.run(service.run(warm_up=warm_up))
