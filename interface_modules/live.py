"""Live mode: one OS process per interface module, each with its own UDP socket and schedule.

The datagrams are those of the offline run (same scenario, same seed: same bytes, same sequence
numbers); each module process sends its own at the run's send times (modelled send jitter
included) against the shared monotonic clock, scaled by ``speed`` (2.0 = twice real time), so the
OS adds its own scheduling jitter on top. Each module binds ``bind_host:port`` (its configured
source port; 0 = ephemeral) before the start, so a port in use fails cleanly before anything is sent.

Authenticated links (the listener's ``[auth]`` extension, docs/protocol.md): with a key per module
(:class:`ModuleAuth`), each module process wraps every datagram it sends, its STOP included, with
``listener.auth.wrap`` under its own key and KEY_ID and its own epoch counter (started from the
wall-clock second, so a restarted run never reuses an (epoch, SEQ) pair the listener accepted).

Stopping: at the end of the schedule the control module sends its STOP; on ``stop()`` (the CLI
calls it on Ctrl-C) every module stops sending at once and the control module sends a STOP with its
next sequence number. Shutdown is bounded: processes that do not exit within ``JOIN_GRACE_S`` are
terminated.
"""

from __future__ import annotations

import multiprocessing as mp
import signal
import socket
import time
from dataclasses import dataclass

from .errors import SimError

START_DELAY_S = 0.3  #: time between "all modules ready" and the first send [s]
READY_TIMEOUT_S = 20.0  #: time allowed for the module processes to start and bind [s]
JOIN_GRACE_S = 5.0  #: time allowed for the processes to finish after the schedule ends or a stop [s]


#: KEY_ID of each module on an authenticated input link (the listener derives the key
#: ``modules->listener:<KEY_ID>``): the SENSOR_TYPE a module sends, 0 for the control module
DEFAULT_KEY_IDS = {"control": 0, "imu": 1, "odometer": 2, "gps": 3}


@dataclass(frozen=True)
class ModuleAuth:
    """How one module wraps its datagrams on an authenticated input link."""

    key: bytes  #: the module's link key (``listener.auth_link.input_key(master, key_id)``), >= 16 bytes
    key_id: int  #: KEY_ID byte, 0..255: the id the listener derives this module's key from
    start_epoch: int = 0  #: first epoch counter (the CLI passes the wall-clock second)
    tag_bytes: int = 16  #: tag length [bytes], as the listener's auth.tag_bytes


@dataclass(frozen=True)
class ModuleSchedule:
    """What one module process sends: offsets [s of simulated time from the start] and payloads."""

    name: str
    port: int  #: source port to bind (0: ephemeral)
    offsets_s: tuple[float, ...]
    payloads: tuple[bytes, ...]
    is_control: bool = False
    next_seq_after: tuple[int, ...] = ()  #: control: sequence number following each datagram (for STOP)
    auth: ModuleAuth | None = None  #: wrap every datagram for an authenticated input link


@dataclass(frozen=True)
class LiveReport:
    """What the live run did."""

    sent: dict[str, int]  #: datagrams sent per module
    interrupted: bool  #: stopped before the end of the schedule
    wall_s: float  #: wall time from the first scheduled send to the end [s]


def schedules_from_run(
    run, *, ephemeral_ports: bool = False, auth: dict[str, ModuleAuth] | None = None
) -> list[ModuleSchedule]:
    """Per-module send schedules from an offline run (times relative to the earliest send).

    ``auth``: module name -> :class:`ModuleAuth`; every module of the run needs one (the listener
    rejects an unwrapped datagram on an authenticated link).
    """
    from listener.codec import decode_header

    if auth is not None:
        missing = sorted(set(run.ports) - set(auth))
        if missing:
            raise SimError(f"authenticated link: no key for module(s) {', '.join(missing)}")

    t0 = min(p.send_s for p in run.packets)
    out = []
    for name, port in run.ports.items():
        pkts = run.packets_of(name)
        pkts.sort(key=lambda p: p.send_s)
        next_seq = tuple((decode_header(p.payload)[1] + 1) % 65536 for p in pkts) if name == "control" else ()
        out.append(
            ModuleSchedule(
                name=name,
                port=0 if ephemeral_ports else port,
                offsets_s=tuple(p.send_s - t0 for p in pkts),
                payloads=tuple(p.payload for p in pkts),
                is_control=name == "control",
                next_seq_after=next_seq,
                auth=None if auth is None else auth[name],
            )
        )
    return out


def _sealer(auth: ModuleAuth | None):
    """The module's wrap function for an authenticated link (own epoch counter), or None."""
    if auth is None:
        return None
    from listener.auth import EpochCounter, input_seq, wrap

    counter = EpochCounter(auth.start_epoch)

    def seal(payload: bytes) -> bytes:
        epoch = counter.epoch_for(input_seq(payload))
        return wrap(payload, auth.key, epoch, key_id=auth.key_id, tag_bytes=auth.tag_bytes)

    return seal


def _module_main(
    sched: ModuleSchedule,
    bind_host: str,
    target: tuple[str, int],
    speed: float,
    ready,
    go,
    start,
    stop,
    results,
) -> None:
    """Body of one module process."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C and sets ``stop``
    sent = 0
    try:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.bind((bind_host, sched.port))
        except OSError as exc:
            ready.put((sched.name, f"cannot bind {bind_host}:{sched.port}: {exc}"))
            return
        ready.put((sched.name, None))
        if not go.wait(READY_TIMEOUT_S + 5.0) or stop.is_set():
            return
        seal = _sealer(sched.auth)
        t0 = start.value
        next_seq = (sched.next_seq_after[0] - 1) % 65536 if sched.next_seq_after else 0
        completed = True
        for i, (off, payload) in enumerate(zip(sched.offsets_s, sched.payloads, strict=True)):
            remaining = t0 + off / speed - time.monotonic()
            if (remaining > 0 and stop.wait(remaining)) or stop.is_set():
                completed = False
                break
            sock.sendto(payload if seal is None else seal(payload), target)
            sent += 1
            if sched.is_control:
                next_seq = sched.next_seq_after[i]
        if sched.is_control and not completed:
            from listener.codec import Stop, encode_input

            stop_dgram = encode_input(Stop(next_seq))
            sock.sendto(stop_dgram if seal is None else seal(stop_dgram), target)
            sent += 1
        sock.close()
    finally:
        results.put((sched.name, sent))


class LiveRunner:
    """Start the module processes, run the schedule, stop them (see module doc)."""

    def __init__(
        self,
        schedules: list[ModuleSchedule],
        target: tuple[str, int],
        *,
        speed: float = 1.0,
        bind_host: str = "127.0.0.1",
    ):
        if speed <= 0:
            raise SimError("speed must be > 0")
        self._ctx = mp.get_context("spawn")
        self._schedules = schedules
        self._target = target
        self._speed = speed
        self._bind = bind_host
        self._ready = self._ctx.Queue()
        self._results = self._ctx.Queue()
        self._go = self._ctx.Event()
        self._stop = self._ctx.Event()
        self._start = self._ctx.Value("d", 0.0)
        self._procs: list = []

    def start(self) -> float:
        """Spawn and bind every module; return the monotonic time of the first send."""
        for s in self._schedules:
            p = self._ctx.Process(
                target=_module_main,
                args=(
                    s,
                    self._bind,
                    self._target,
                    self._speed,
                    self._ready,
                    self._go,
                    self._start,
                    self._stop,
                    self._results,
                ),
                name=f"sfa-sim-{s.name}",
                daemon=True,
            )
            p.start()
            self._procs.append(p)
        errors = []
        deadline = time.monotonic() + READY_TIMEOUT_S
        for _ in self._schedules:
            try:
                name, err = self._ready.get(timeout=max(deadline - time.monotonic(), 0.01))
            except Exception as exc:  # queue.Empty
                self.stop()
                self.join()
                raise SimError("module processes did not start in time") from exc
            if err:
                errors.append(f"{name}: {err}")
        if errors:
            self.stop()
            self.join()
            raise SimError("; ".join(errors))
        self._start.value = time.monotonic() + START_DELAY_S
        self._go.set()
        return self._start.value

    def stop(self) -> None:
        """Ask every module to stop now (the control module then sends STOP)."""
        self._stop.set()
        self._go.set()

    def wait(self, timeout_s: float | None = None) -> bool:
        """Wait for the processes to finish; True if they all did."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        for p in self._procs:
            p.join(None if deadline is None else max(deadline - time.monotonic(), 0.0))
        return all(not p.is_alive() for p in self._procs)

    def join(self) -> dict[str, int]:
        """Bounded shutdown: wait, then terminate stragglers; return datagrams sent per module."""
        if not self.wait(JOIN_GRACE_S):
            for p in self._procs:
                if p.is_alive():
                    p.terminate()
            self.wait(JOIN_GRACE_S)
        sent: dict[str, int] = {}
        while len(sent) < len(self._procs):
            try:
                name, n = self._results.get(timeout=0.5)
            except Exception:  # queue.Empty: a terminated process reported nothing
                break
            sent[name] = n
        return sent

    @property
    def schedule_span_s(self) -> float:
        """Wall time the schedule takes at this speed [s]."""
        return max((s.offsets_s[-1] for s in self._schedules if s.offsets_s), default=0.0) / self._speed


def run_live(
    run,
    target: tuple[str, int],
    *,
    speed: float = 1.0,
    bind_host: str = "127.0.0.1",
    ephemeral_ports: bool = False,
    auth: dict[str, ModuleAuth] | None = None,
) -> LiveReport:
    """Send the run live; Ctrl-C (KeyboardInterrupt) stops it cleanly with a STOP.

    ``auth``: per-module keys for an authenticated input link (see :class:`ModuleAuth`)."""
    runner = LiveRunner(
        schedules_from_run(run, ephemeral_ports=ephemeral_ports, auth=auth),
        target,
        speed=speed,
        bind_host=bind_host,
    )
    interrupted = False
    t_first = runner.start()
    try:
        runner.wait(runner.schedule_span_s + START_DELAY_S + JOIN_GRACE_S)
    except KeyboardInterrupt:
        interrupted = True
        runner.stop()
    sent = runner.join()
    return LiveReport(sent=sent, interrupted=interrupted, wall_s=max(time.monotonic() - t_first, 0.0))


def _read_hex_key(path: str, what: str) -> bytes:
    from listener.config import read_master_key
    from listener.errors import ConfigError

    try:
        return read_master_key(path)
    except ConfigError as exc:
        raise SimError(f"{what}: {str(exc).split(': ', 1)[-1]}") from None


def module_auth(
    modules: list[str],
    *,
    master_key_file: str | None = None,
    module_keys: list[str] = (),
    start_epoch: int = 0,
    tag_bytes: int = 16,
) -> dict[str, ModuleAuth]:
    """Per-module keys for ``modules`` from the CLI's options.

    ``master_key_file``: the listener's ``auth.key_file`` (hex); each module's key is derived as the
    listener derives it, ``modules->listener:<KEY_ID>`` with the ids of :data:`DEFAULT_KEY_IDS`.
    ``module_keys``: ``NAME=KEY_ID:FILE`` items, a module's own key (hex file, what
    ``python -m listener.auth_link MASTER_FILE KEY_ID`` prints) and id; they take precedence, so a
    deployment gives each module only its own key, never the master.
    """
    from listener.auth_link import input_key

    out: dict[str, ModuleAuth] = {}
    if master_key_file:
        master = _read_hex_key(master_key_file, f"--auth-key-file {master_key_file}")
        for name in modules:
            if name not in DEFAULT_KEY_IDS:
                raise SimError(
                    f"--auth-key-file: module {name!r} has no default KEY_ID; use --auth-module-key"
                )
            kid = DEFAULT_KEY_IDS[name]
            out[name] = ModuleAuth(input_key(master, kid), kid, start_epoch, tag_bytes)
    for item in module_keys:
        name, sep, rest = item.partition("=")
        kid_text, sep2, path = rest.partition(":")
        if not sep or not sep2 or not name or not path:
            raise SimError(f"--auth-module-key must be NAME=KEY_ID:FILE, not {item!r}")
        if name not in modules:
            raise SimError(f"--auth-module-key: no module {name!r} (modules: {', '.join(modules)})")
        try:
            kid = int(kid_text)
        except ValueError:
            raise SimError(f"--auth-module-key {item!r}: KEY_ID must be an integer") from None
        if not 0 <= kid <= 255:
            raise SimError(f"--auth-module-key {item!r}: KEY_ID must be in 0..255")
        out[name] = ModuleAuth(_read_hex_key(path, f"--auth-module-key {name}"), kid, start_epoch, tag_bytes)
    return out
