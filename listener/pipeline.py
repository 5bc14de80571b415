"""The listener's pipeline core (sans-I/O): datagrams in, OUTPUT_PROTOCOL datagrams out.

    codec -> per-sender sequence buffer -> dating (epoch or STROBE clock) -> time-ordered merge
          -> SFA filter -> OBCU link

Every entry point takes ``now`` (listener seconds: the monotonic clock live, the capture timestamp in
replay) and returns the datagrams to send to the OBCU. Nothing here reads a clock, opens a socket or
sleeps, so ``sfa listen`` and ``sfa replay`` run this same object and a replay is deterministic.

Dating: a measurement that carries an ``epoch`` is dated by it; one without is dated by its arrival
time mapped into sensor-set time through :class:`~listener.clock.StrobeClock`. Measurements without
an epoch that arrive before the first STROBE wait (bounded) until it comes.

Merge: released measurements wait in a heap ordered by sensor time until the sensor-set "now"
(the newest time known: the STROBE clock's estimate of now, or the newest epoch seen) has passed
them by ``merge.hold_s``. With the default hold of 0 they go to the filter at once; whatever then
arrives older than what the filter has already processed is handled by the filter's documented
late-measurement policy (counted per sensor in the filter's counters).
"""

from __future__ import annotations

import heapq
import math
from collections import Counter, deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from listener import resilience
from listener.auth import AuthError
from listener.auth_link import LinkAuth
from listener.clock import StrobeClock
from listener.codec import (
    DecodeError,
    GpsFix,
    GroundTruth,
    ImuSample,
    OdometerSample,
    OutputExtended,
    OutputMessage,
    Stop,
    Strobe,
    encode_output,
    encode_output_extended,
    sensor_type_of,
)
from listener.config import ListenerConfig
from listener.obcu_link import ObcuLink
from listener.senders import SenderTable, source_of
from listener.seqbuf import SeqBufferConfig, StreamTable, stream_key
from listener.vital import MODULES, DecaySupervisor, ModuleHealth
from listener.warnlimit import WarningLimiter

#: input counters present in every metrics snapshot, even while zero
_ALWAYS_REPORTED = (
    "received",
    "rejected",
    "processed",
    "strobes",
    "stops",
    "dated_by_epoch",
    "dated_by_strobe",
    "undated_overflow",
    "merge_overflow",
    "after_stop",
    "stale_not_sent",
)
_TYPE_NAMES = {1: "imu", 2: "odometer", 3: "gps", 8: "ground_truth", 9: "strobe", 10: "stop"}
_MODULE_OF_TYPE = {t: name for name, t in MODULES.items()}
_LOST = 3  #: FilterStatus.LOST (also what the extended output says while decay is latched)
_DEGRADED = 2
_EVENTS_KEPT = 1000  #: events queued for the log at most (the service takes them after every call)
_TIMEOUT_REASON = {"imu": "imu_timeout", "odometer": "odometer_timeout", "gnss": "gnss_timeout"}
_RECHECK_STEP_S = 0.002  #: re-check period of a time-out the filter does not show yet [s]
_RECHECK_FOR_S = 0.05  #: how long past the deadline re-checks go on [s]
_EPOCH_FUTURE = "epoch_future"  #: reject reason of an epoch ahead of the STROBE clock (Pipeline._date)


@dataclass(frozen=True, slots=True)
class BatchCounts:
    """Datagrams counted in bulk, for :meth:`Pipeline.count_batch`, which books them as
    :meth:`Pipeline.receive` and the stages after it book each one: the listener service's datagrams
    rejected by their header alone, and the compiled replay (``tools.fast_replay``), which takes a
    capture's datagrams without ``receive``. Only what happened is given (every count >= 0)."""

    received: int = 0  #: datagrams received (``input.received``), the rejected ones included
    #: reject reason (``listener.reject.RejectReason`` or the sender table's) -> datagrams rejected
    #: before sequencing
    rejected: Mapping[Any, int] = field(default_factory=dict)
    #: SENSOR_TYPE -> datagrams accepted (``input.by_type``; STROBE and STOP included)
    by_type: Mapping[int, int] = field(default_factory=dict)
    #: accepted datagrams that each continued their stream in order and were released at once, taken
    #: without the sequence buffers (``sequencing``: received, in order, released)
    in_order: int = 0
    strobes: int = 0  #: STROBEs released to the clock
    stops: int = 0  #: STOPs released
    dated_by_epoch: int = 0  #: measurements dated by their own epoch
    dated_by_strobe: int = 0  #: measurements dated by the STROBE clock at their arrival
    #: measurements rejected after sequencing: an epoch ahead of the STROBE clock (``clock.max_future_s``)
    epoch_future: int = 0
    #: (``Update.kind``, ``Update.outcome``) -> measurements the filter processed with that outcome
    outcomes: Mapping[tuple[str, Any], int] = field(default_factory=dict)
    stale_not_sent: int = 0  #: estimates behind the freshness bound, not sent
    outputs: int = 0  #: new estimates sent on the OBCU link
    retransmits: int = 0  #: resends of the newest estimate on the OBCU link


@dataclass(frozen=True, slots=True)
class _Arrived:
    """A decoded message and the listener time it arrived."""

    msg: Any
    arrival: float
    key: Any = None  #: its stream's key (a content rejection gives its SEQ back to that stream)


def to_measurement(msg: Any, t_s: float):
    """Map a decoded wire message onto the filter's measurement type, dated ``t_s`` (sensor-set time)."""
    from sfa.measurements import GpsMeas, ImuMeas, InitMeas, OdoMeas

    if isinstance(msg, ImuSample):
        return ImuMeas(t_s, (msg.ax, msg.ay, msg.az), (msg.gx, msg.gy, msg.gz))
    if isinstance(msg, OdometerSample):
        return OdoMeas(t_s, msg.speed, msg.sigma)
    if isinstance(msg, GpsFix):
        return GpsMeas(t_s, msg.lat, msg.lon, msg.alt, msg.sigma_h, msg.fix_quality, msg.num_sv)
    if isinstance(msg, GroundTruth):
        return InitMeas(t_s, msg.arc_length, msg.vx, msg.line_id)
    raise TypeError(f"not a measurement message: {type(msg).__name__}")  # pragma: no cover


class Pipeline:
    """One listener: feed it datagrams and acks with their arrival time; send what it returns."""

    def __init__(self, track, config: ListenerConfig | None = None, filt=None, start_epoch: int = 0) -> None:
        """``start_epoch``: the authenticated output link's first epoch counter (the daemon passes the
        wall-clock second at start, so a restarted listener never reuses an (epoch, SEQ) pair)."""
        self.cfg = config or ListenerConfig()
        if filt is None:
            from sfa.filter import TrackFilter

            filt = TrackFilter(track, self.cfg.filter.filter_config())
        self.filter = filt
        self.track = track
        inp = self.cfg.input
        self.streams: StreamTable = StreamTable(
            SeqBufferConfig(
                hold_time_s=inp.hold_time_s, max_pending=inp.max_pending, startup_hold=inp.startup_hold
            ),
            max_streams=inp.max_streams,
        )
        self.clock = StrobeClock(self.cfg.clock)
        self.link = ObcuLink(self.cfg.link, encoder=self._encode_estimate)
        self.auth = LinkAuth.from_config(self.cfg.auth, start_epoch) if self.cfg.auth.enabled else None
        self._undated: deque[_Arrived] = deque()
        self._heap: list[tuple[float, int, Any]] = []
        self._order = 0
        self._newest_epoch = -math.inf
        self._last_output_epoch = -math.inf
        self.stopped = False
        self.stop_time: float | None = None
        self.counters: Counter[str] = Counter()
        self.rejected: Counter[str] = Counter()
        self.by_type: Counter[str] = Counter()
        self.last_estimate = None
        #: optional observers (replay, benchmarks): called with each filter Update, each dated
        #: measurement before the filter sees it, and (seq, Estimate) for each new output
        self.on_update: Callable[[Any], None] | None = None
        self.on_measurement: Callable[[Any], None] | None = None
        self.on_output: Callable[[int, Any], None] | None = None
        # ---- vital supervision (listener.vital; docs/listener.md, "Vital supervision")
        vc = self.cfg.vital
        self.vital = DecaySupervisor(vc)
        self._vital_on = vc.enabled
        rates = {"imu": vc.imu_rate_hz, "odometer": vc.odometer_rate_hz, "gnss": vc.gnss_rate_hz}
        self.modules = {name: ModuleHealth(name, rates[name], vc.rate_window_s) for name in MODULES}
        fc = getattr(filt, "config", None)
        self._timeouts = {
            "imu": float(getattr(fc, "imu_timeout_s", 0.5)),
            "odometer": float(getattr(fc, "odo_timeout_s", 1.0)),
            "gnss": float(getattr(fc, "gps_timeout_s", 3.0)),
        }
        self._module_streams: dict[str, set] = {name: set() for name in MODULES}
        self._timed_out: set[str] = set()  # modules whose time-out the timer has evaluated since heard
        self._recheck_at: float | None = None  # a time-out due but not yet seen by the filter: look again
        self._rechecking: set[str] = set()  # the modules that re-check is for
        self._init_now: float | None = None  # listener time of the last (re)initialisation
        self._newest_epoch_arrival = 0.0  # listener time the newest epoch arrived
        self._status: int | None = None  # last status observed (outputs and timer), FilterStatus value
        self._reasons: tuple[str, ...] = ()
        self._status_since: float | None = None
        self.events: deque[dict[str, Any]] = deque(maxlen=_EVENTS_KEPT)
        self.vital_counters: Counter[str] = Counter()
        # ---- trust boundaries (issue 20): sender identity, sequence-jump warnings
        self.senders = SenderTable(self.cfg.senders)
        self._sources: dict[Any, str] = {}  # addr -> source string (bounded cache)
        self._seq_warnings = WarningLimiter(self.cfg.senders.warning_interval_s)
        self.events.extend(self.senders.start_events(0.0))
        # ---- plausibility, clock trouble, checkpoint and resume (listener.resilience)
        #: name -> (save() -> JSON-serialisable, restore(saved) or None): components' state kept in the
        #: checkpoint's ``extra`` dict (docs/listener.md, "Checkpoint and restart")
        self.checkpoint_extra: dict[str, tuple[Callable[[], Any], Callable[[Any], None] | None]] = {}
        self.resilience = resilience.Resilience(self, track)
        # the sender bindings (trust on first use) survive a restart in the checkpoint
        self.checkpoint_extra["senders"] = (self.senders.snapshot, self.senders.restore)

    @property
    def observed_status(self) -> int | None:
        """The status last observed (outputs and timer), a FilterStatus value; None before any."""
        return self._status

    def mark_initialised(self, now: float) -> None:
        """The filter was (re)initialised at ``now`` other than by a measurement (a checkpoint seed)."""
        self._init_now = now
        self._timed_out.clear()

    # ------------------------------------------------------------------ inputs
    def receive(self, data: bytes, addr: Any, now: float) -> list[bytes]:
        """One INPUT_PROTOCOL datagram from ``addr`` arrived at ``now``."""
        self._count("received")
        if self.stopped:
            self.counters["after_stop"] += 1
            return []
        key_id = None
        if self.auth is not None:
            try:
                data = self.auth.open_input(data, addr)
            except AuthError as exc:
                self._count_rejected(exc.reason)
                return self._drain(now)
            key_id = self.auth.last_key_id
        try:
            msg = self._decode(data)
        except DecodeError as exc:
            self._count_rejected(exc.reason)
            return self._drain(now)
        stype = int(sensor_type_of(msg))
        why = self._check_sender(addr, key_id, stype, now)
        if why is not None:
            self._count_rejected(why)
            return self._drain(now)
        self._count_accepted(stype)
        key = stream_key(addr, stype, self.cfg.input.per_type_sequence)
        module = _MODULE_OF_TYPE.get(stype)
        if module is not None:
            self.modules[module].heard(now)
            self._timed_out.discard(module)
            self._rechecking.discard(module)
            streams = self._module_streams[module]
            if key not in streams and len(streams) < 16:
                streams.add(key)
        released = self.streams.push(key, msg.seq, _Arrived(msg, now, key), now)
        if self.streams.alerts:
            self._sequence_alerts()
        return self._dispatch(released, now)

    def _check_sender(self, addr: Any, key_id: int | None, stype: int, now: float) -> str | None:
        """listener.senders: None if this source may send ``stype``, else the reject reason."""
        if key_id is None:
            source = self._sources.get(addr)
            if source is None:
                if len(self._sources) >= 1024:
                    self._sources.clear()
                source = self._sources[addr] = source_of(addr)
        else:
            source = source_of(addr, key_id)
        why = self.senders.check(source, stype, now)
        if self.senders.events:
            self.events.extend(self.senders.events)
            self.senders.events.clear()
        return why

    def _sequence_alerts(self) -> None:
        """The sequence buffers' jump records as warning events (rate limited per kind)."""
        alerts = self.streams.alerts
        for a in alerts:
            kind = a.pop("event")
            at = a.pop("at")
            stream = a.pop("stream")
            ev = self._seq_warnings.event(kind, at, stream=_stream_name(stream), **a)
            if ev is not None:
                self.events.append(ev)
        alerts.clear()

    @staticmethod
    def _decode(data: bytes):
        from listener.codec import decode_input

        return decode_input(data)

    def receive_ack(self, data: bytes, now: float) -> list[bytes]:
        """A datagram from the OBCU (an ACK, or garbage that is counted)."""
        if self.auth is not None:
            try:
                data = self.auth.open_ack(data)
            except AuthError:
                self.link.bad_acks += 1
                return self.link.handle_timer(now)
        self.link.receive_ack(data, now)
        return self.link.handle_timer(now)

    def next_timer(self) -> float | None:
        """Listener time at which :meth:`handle_timer` should run next."""
        times = [
            t
            for t in (self.streams.next_deadline(), self.link.next_timer(), self._supervision_deadline(),
                      self.resilience.next_timer())
            if t is not None
        ]
        return min(times) if times else None

    def handle_timer(self, now: float) -> list[bytes]:
        """Release sequence-buffer holds, run the OBCU link's timers and the vital supervision due at
        ``now`` (a silent sensor's time-out, a fault's budget)."""
        out = self._dispatch(self.streams.poll(now), now)
        if self.streams.alerts:
            self._sequence_alerts()
        due = self._supervision_deadline()
        if due is not None and now >= due:
            out.extend(self._supervise(now))
        out.extend(self.link.handle_timer(now))
        self.resilience.tick(now)
        return out

    def take_events(self) -> list[dict[str, Any]]:
        """The status, decay and link-state events since the last call, oldest first (each with ``at``,
        the listener time it happened)."""
        link = self.link
        new = link.transitions_total - self.vital_counters["link_transitions_seen"]
        if new > 0:
            self.vital_counters["link_transitions_seen"] = link.transitions_total
            trans = link.transitions[-min(new, len(link.transitions)) :]
            for t, state in trans:
                self.events.append({"event": "link_state", "at": t, "state": state, **self._heard(t)})
        if not self.events:
            return []
        out = sorted(self.events, key=lambda e: e["at"])
        self.events.clear()
        return out

    def flush(self, now: float) -> list[bytes]:
        """Release everything held (sequence buffers, undated queue, merge) and process it."""
        out = self._dispatch(self.streams.flush(), now, stopping=True)
        while self._undated:
            self.counters["undated_dropped_at_stop"] += 1
            self._undated.popleft()
        out.extend(self._drain(now, everything=True))
        out.extend(self.link.handle_timer(now))
        return out

    # ------------------------------------------------------------------ stages
    def _dispatch(self, released: list[_Arrived], now: float, stopping: bool = False) -> list[bytes]:
        stop_seen = False
        for item in released:
            msg = item.msg
            if isinstance(msg, Strobe):
                self._count("strobes")
                self.clock.on_strobe(msg.timestamp, item.arrival)
                self.resilience.after_strobe(msg, item.arrival)
                self._date_undated()
            elif isinstance(msg, Stop):
                self._count("stops")
                stop_seen = True
            else:
                self._date(item)
        out = self._drain(now)
        if stop_seen and not stopping:
            out.extend(self.flush(now))
            self.stopped = True
            self.stop_time = now
        return out

    def _date(self, item: _Arrived) -> None:
        epoch = item.msg.epoch
        if epoch is None:
            epoch = self.clock.to_sensor_time(item.arrival)
            if epoch is None:
                if len(self._undated) >= self.cfg.clock.max_pending_undated:
                    self._undated.popleft()
                    self.counters["undated_overflow"] += 1
                self._undated.append(item)
                return
            self._count_dated(by_strobe=True)
        else:
            ref = self.clock.to_sensor_time(item.arrival)
            if ref is not None and epoch > ref + self.cfg.clock.max_future_s:
                # e.g. a flipped exponent bit: one such epoch would drag the filter far into the future
                self.count_rejected_after_sequencing(_EPOCH_FUTURE)
                self.give_back_seq(item)
                self.resilience.warn(_EPOCH_FUTURE, item.arrival, epoch=epoch, sensor_now=ref)
                return
            self._count_dated(by_strobe=False)
        if epoch > self._newest_epoch:
            self._newest_epoch = epoch
            self._newest_epoch_arrival = item.arrival
        self._order += 1
        heapq.heappush(self._heap, (epoch, self._order, item.msg))
        if len(self._heap) > self.cfg.merge.max_pending:
            self.counters["merge_overflow"] += 1  # released early rather than lost

    def count_rejected_after_sequencing(self, reason: str, n: int = 1) -> None:
        """The books of ``n`` datagrams rejected for ``reason`` after they were sequenced: in
        ``input.rejected`` and its reason, and in ``rejected_after_sequencing`` (they are in ``by_type``
        too: received = rejected - rejected_after_sequencing + sum(by_type) + after_stop)."""
        if n:
            self._count_rejected(reason, n)
            self.counters["rejected_after_sequencing"] += n

    def count_batch(self, counts: BatchCounts) -> None:
        """Book ``counts`` (datagrams taken without :meth:`receive`) as the per-datagram path books each
        datagram: the same counters, through the same helpers. A count of 0 books nothing (a counter
        appears once something is counted, as with single datagrams)."""
        b = counts
        self._count("received", b.received)
        for reason, n in b.rejected.items():
            self._count_rejected(reason, n)
        for stype, n in b.by_type.items():
            self._count_accepted(stype, n)
        self.streams.count_in_order(b.in_order)
        self._count("strobes", b.strobes)
        self._count("stops", b.stops)
        self._count_dated(False, b.dated_by_epoch)
        self._count_dated(True, b.dated_by_strobe)
        self.count_rejected_after_sequencing(_EPOCH_FUTURE, b.epoch_future)
        for (kind, outcome), n in b.outcomes.items():
            self._count_processed(kind, outcome, n)
        self._count("stale_not_sent", b.stale_not_sent)
        self.link.count_sent(b.outputs, b.retransmits)

    # the input and filter counters (``metrics()["input"]``, ``["filter"]["outcomes"]``): the one place
    # each rule is written, for single datagrams (n = 1) and for :meth:`count_batch`
    def _count(self, name: str, n: int = 1) -> None:
        if n:
            self.counters[name] += n

    def _count_rejected(self, reason: Any, n: int = 1) -> None:
        """``n`` datagrams rejected for ``reason`` (a RejectReason, or the sender table's string)."""
        if n:
            self.counters["rejected"] += n
            self.rejected[str(reason)] += n

    def _count_accepted(self, stype: int, n: int = 1) -> None:
        """``n`` datagrams of SENSOR_TYPE ``stype`` accepted (decoded, the sender allowed)."""
        if n:
            self.by_type[_TYPE_NAMES.get(stype, str(stype))] += n

    def _count_dated(self, by_strobe: bool, n: int = 1) -> None:
        if n:
            self.counters["dated_by_strobe" if by_strobe else "dated_by_epoch"] += n

    def _count_processed(self, kind: str, outcome: Any, n: int = 1) -> None:
        """``n`` measurements of ``Update.kind`` the filter processed with ``outcome``."""
        if n:
            self.counters["processed"] += n
            self.counters[f"outcome_{kind}_{_outcome_name(outcome)}"] += n

    def give_back_seq(self, item: _Arrived) -> None:
        """A released datagram was rejected for its content: its SEQ does not count as used, so the
        legitimate datagram with that number is still accepted (listener.seqbuf, reopen)."""
        buf = self.streams.get(item.key) if item.key is not None else None
        if buf is not None:
            buf.reopen(item.msg.seq)  # counted as sequencing.reopened when a datagram takes it

    def _date_undated(self) -> None:
        while self._undated:
            self._date(self._undated.popleft())

    def _drain(self, now: float, everything: bool = False) -> list[bytes]:
        """Hand due measurements to the filter, in time order; one output per estimate that advanced."""
        heap = self._heap
        if not heap:
            return []
        if everything or len(heap) > self.cfg.merge.max_pending:
            horizon = math.inf
        else:
            sensor_now = self.clock.to_sensor_time(now)
            newest = self._newest_epoch if sensor_now is None else max(sensor_now, self._newest_epoch)
            horizon = newest - self.cfg.merge.hold_s
        out: list[bytes] = []
        filt = self.filter
        while heap and (heap[0][0] <= horizon or len(heap) > self.cfg.merge.max_pending):
            t, _, msg = heapq.heappop(heap)
            meas = to_measurement(msg, t)
            if not self.resilience.before_measurement(meas, now):
                continue  # a GROUND TRUTH held for confirmation
            if self.on_measurement is not None:
                self.on_measurement(meas)
            update = filt.process(meas)
            if self.on_update is not None:
                self.on_update(update)
            self._count_processed(update.kind, update.outcome)
            if update.kind == "init" and int(update.outcome) == 6:  # Outcome.INITIALISED
                self._init_now = now
                self._timed_out.clear()
            est = self.resilience.vet(filt.estimate(), update, now)
            if math.isfinite(est.epoch_s):
                self._observe(est, now, "update")
                self._note(self.vital.on_update(update.kind, int(update.outcome), int(est.status),
                                                est.reasons, now), now)
            out.extend(self._maybe_output(now, est))
        return out

    # ------------------------------------------------------------------ vital supervision
    def _sensor_now(self, now: float) -> float | None:
        """Sensor-set time at listener time ``now``: the STROBE clock, else the newest epoch carried
        forward at the nominal clock rate; None before either exists."""
        t = self.clock.to_sensor_time(now)
        if t is None and math.isfinite(self._newest_epoch):
            t = self._newest_epoch + (now - self._newest_epoch_arrival) * self.cfg.clock.rate
        return t

    def _supervision_deadline(self) -> float | None:
        """Next listener time a silent module's time-out is due (its last datagram, or the
        initialisation, plus its ``*_timeout_s``), or a fault's budget runs out."""
        if not self._vital_on or self.stopped:
            return None
        best = self.vital.next_timer()
        init = self._init_now
        if init is None:
            return best
        rate = self.cfg.clock.rate
        margin = self.cfg.vital.timeout_margin_s
        if self._recheck_at is not None and (best is None or self._recheck_at < best):
            best = self._recheck_at
        for name, mod in self.modules.items():
            if name in self._timed_out or name in self._rechecking:  # (a re-check: _recheck_at)
                continue
            ref = init if mod.last_heard is None or mod.last_heard < init else mod.last_heard
            due = ref + self._timeouts[name] / rate + margin
            if best is None or due < best:
                best = due
        return best

    def _supervise(self, now: float) -> list[bytes]:
        """The timer: evaluate the filter's status at the sensor time of ``now`` (so a silent sensor is
        timed out without waiting for another measurement) and act on a change."""
        self.vital_counters["timer_checks"] += 1
        self._recheck_at = None
        self._rechecking.clear()
        t = self._sensor_now(now)
        if t is None or not self.filter.initialised:
            self._timed_out.update(self.modules)  # nothing to evaluate: until each is heard again
            self._recheck_at = None
            self._note(self.vital.observe(self._status or 0, self._reasons, now), now)
            return []
        est = self.resilience.vet(self.filter.estimate(at_s=t, propagate=True), None, now)
        if self._init_now is not None:
            rate, margin = self.cfg.clock.rate, self.cfg.vital.timeout_margin_s
            for name, mod in self.modules.items():
                ref = self._init_now if mod.last_heard is None else max(mod.last_heard, self._init_now)
                due = ref + self._timeouts[name] / rate + margin
                if now < due or name in self._timed_out:
                    continue
                if _TIMEOUT_REASON[name] in est.reasons or now >= due + _RECHECK_FOR_S:
                    self._timed_out.add(name)
                else:
                    # the sensor-time mapping (STROBE clock fit, still settling) puts now a little
                    # before the filter's own deadline: look again shortly rather than wait for the
                    # next measurement
                    self.vital_counters["timer_rechecks"] += 1
                    self._recheck_at = now + _RECHECK_STEP_S
                    self._rechecking.add(name)
        was_latched = self.vital.latched
        changed = self._observe(est, now, "timer")
        if not (changed or self.vital.latched != was_latched) or self.last_estimate is None:
            return []
        # a change between measurements: the standard output stops if it may no longer carry the
        # position; the extended output announces the new status with the estimate it has
        if not self._standard_sendable(int(est.status)) and not self.cfg.link.extended:
            self.link.withhold(now)
            return []
        if self.cfg.link.extended and self.resilience.publishable(est, now):
            self.vital_counters["timer_outputs"] += 1
            self.last_estimate = est
            self.resilience.sent(est)
            return self.link.send_estimate(est, now)
        return []

    def _standard_sendable(self, status: int) -> bool:
        """Whether the 18-byte output (no status field) may carry a position of this status."""
        if not self._vital_on:
            return True
        if self.vital.latched or status >= _LOST:
            return False
        return status != _DEGRADED or self.cfg.vital.standard_output == "degraded"

    def _heard(self, now: float) -> dict[str, Any]:
        return {"since_heard_s": {name: _round(mod.age(now)) for name, mod in self.modules.items()}}

    def _observe(self, est, now: float, source: str) -> bool:
        """Record the status of ``est`` as of ``now``; queue an event when it changed. True if it did."""
        status = int(est.status)
        reasons = est.reasons
        changed = status != self._status or reasons != self._reasons
        if changed:
            if status != self._status:
                self.vital_counters["status_changes"] += 1
                self.events.append(
                    {
                        "event": "status",
                        "at": now,
                        "status": est.status.name.lower(),
                        "previous": None if self._status is None else _STATUS_NAMES.get(self._status),
                        "reasons": list(reasons),
                        "source": source,
                        "previous_for_s": None
                        if self._status_since is None
                        else _round(now - self._status_since),
                        **self._heard(now),
                    }
                )
                self._status_since = now
            else:
                self.vital_counters["reason_changes"] += 1
                self.events.append(
                    {"event": "reasons", "at": now, "status": est.status.name.lower(),
                     "reasons": list(reasons), "previous_reasons": list(self._reasons), "source": source}
                )
            self._status = status
            self._reasons = reasons
        if self._vital_on:
            # a module never heard is not fitted (e.g. no IMU on a car), not a sensor that failed: its
            # time-out is not a declared fault for the decay budget (LOST still is)
            absent = [_TIMEOUT_REASON[n] for n, m in self.modules.items() if m.count == 0]
            if absent and any(r in reasons for r in absent):
                reasons = tuple(r for r in reasons if r not in absent)
            self._note(self.vital.observe(status, reasons, now), now)
        return changed

    def _note(self, events: list[dict[str, Any]], now: float) -> None:
        for ev in events:
            self.vital_counters[ev["event"]] += 1
            self.events.append({**ev, "at": now, **self._heard(now)})

    def _maybe_output(self, now: float, est=None) -> list[bytes]:
        if est is None:
            est = self.filter.estimate()
        if not math.isfinite(est.epoch_s) or not math.isfinite(est.arc_length_m):
            return []
        sensor_now = self.clock.to_sensor_time(now)
        stale_before = self.cfg.link.max_output_age_s + self.cfg.merge.hold_s  # the hold is intended
        if sensor_now is not None and est.epoch_s < sensor_now - stale_before:
            # behind by more than the freshness bound (a backlog): never sent as a fresh estimate
            self._count("stale_not_sent")
            self.resilience.warn("stale_not_sent", now, epoch=est.epoch_s, sensor_now=sensor_now)
            return []
        if est.epoch_s < self._last_output_epoch:
            return []
        if (
            est.epoch_s == self._last_output_epoch
            and self.last_estimate is not None
            and (est.arc_length_m == self.last_estimate.arc_length_m)
        ):
            return []
        if not self.resilience.publishable(est, now):
            return []
        self._last_output_epoch = est.epoch_s
        self.last_estimate = est
        if not self.cfg.link.extended and not self._standard_sendable(int(est.status)):
            self.vital_counters["withheld"] += 1
            self.link.withhold(now)
            return []
        self.resilience.sent(est)
        return self.link.send_estimate(est, now)

    def _encode_estimate(self, seq: int, est) -> bytes:
        if self.on_output is not None:
            self.on_output(seq, est)
        payload = self._encode_plain(seq, est)
        return payload if self.auth is None else self.auth.seal_output(payload, seq)

    def _encode_plain(self, seq: int, est) -> bytes:
        if self.cfg.link.extended:
            return encode_output_extended(
                OutputExtended(
                    seq,
                    est.epoch_s,
                    est.arc_length_m,
                    est.speed_mps if math.isfinite(est.speed_mps) else 0.0,
                    est.interval_low_m,
                    est.interval_high_m,
                    _LOST if self.vital.latched else int(est.status),
                    est.line_id,
                )
            )
        return encode_output(OutputMessage(seq, est.epoch_s, est.arc_length_m))

    # ------------------------------------------------------------------ metrics
    def vitality(self, now: float) -> dict[str, Any]:
        """Per interface module: last heard, rate against nominal, sequence health; the status as last
        observed and the decay state (JSON-serialisable)."""
        vc = self.cfg.vital
        modules = {}
        for name, mod in self.modules.items():
            rate = mod.rate(now)
            seq = None
            for key in self._module_streams[name]:
                buf = self.streams.get(key)
                if buf is not None:
                    seq = buf.stats if seq is None else seq + buf.stats
            age = mod.age(now)
            modules[name] = {
                "heard": mod.count,
                "last_heard_age_s": _round(age),
                "rate_hz": round(rate, 3),
                "nominal_rate_hz": mod.nominal_hz,
                "rate_ok": mod.count > 0 and rate >= vc.min_rate_fraction * mod.nominal_hz,
                "timeout_s": self._timeouts[name],
                "timed_out": age is not None and age > self._timeouts[name] / self.cfg.clock.rate,
                "sequence": None
                if seq is None
                else {
                    "streams": len(self._module_streams[name]),
                    "in_order": seq.in_order,
                    "reordered": seq.reordered,
                    "duplicates": seq.duplicates,
                    "lost": seq.lost,
                    "late": seq.late,
                    "resyncs": seq.resyncs,
                },
            }
        return {
            "status": None if self._status is None else _STATUS_NAMES.get(self._status),
            "reasons": list(self._reasons),
            "status_since": self._status_since,
            "decay": self.vital.stats(),
            "modules": modules,
            "counters": {
                k: v for k, v in sorted(self.vital_counters.items()) if k != "link_transitions_seen"
            },
        }

    def metrics(self, now: float | None = None) -> dict[str, Any]:
        """A snapshot of every stage's counters (JSON-serialisable); ``now`` adds the vitality section."""
        seq = self.streams.stats
        link = self.link.stats()
        est = self.last_estimate
        return {
            "input": {
                **dict.fromkeys(_ALWAYS_REPORTED, 0),
                **{k: v for k, v in sorted(self.counters.items()) if not k.startswith("outcome_")},
                "rejected_by_reason": dict(sorted(self.rejected.items())),
                "by_type": dict(sorted(self.by_type.items())),
            },
            "sequencing": {
                "streams": seq.streams,
                "evictions": seq.evictions,
                **{
                    k: getattr(seq.totals, k)
                    for k in (
                        "received",
                        "released",
                        "in_order",
                        "reordered",
                        "duplicates",
                        "lost",
                        "late",
                        "resyncs",
                        "overflow",
                        "probation_drops",
                        "pending",
                        "jumps_held",
                        "jump_drops",
                        "gap_limited",
                        "reopened",
                        "jump_held",
                    )
                },
            },
            "senders": self.senders.stats(),
            "clock": {
                "synced": self.clock.synced,
                "unconfirmed_strobes": self.clock.unconfirmed,
                "strobes": self.clock.strobes,
                "resets": self.clock.resets,
                "rejected_strobes": self.clock.rejected,
                "undated_pending": len(self._undated),
            },
            "merge": {"pending": len(self._heap)},
            "auth": None if self.auth is None else self.auth.stats(),
            "resilience": self.resilience.stats(),
            "filter": {
                "outcomes": {
                    k[len("outcome_") :]: v
                    for k, v in sorted(self.counters.items())
                    if k.startswith("outcome_")
                },
                "counters": self.filter.counters(),
                "status": None if est is None else est.status.name.lower(),
                "reasons": [] if est is None else list(est.reasons),
                "line_id": None if est is None else est.line_id,
            },
            "link": {
                "outputs": link.outputs,
                "superseded": link.superseded,
                "retransmits": link.retransmits,
                "acks": link.acks,
                "bogus_acks": link.bogus_acks,
                "bad_acks": link.bad_acks,
                "last_acked_seq": link.last_acked_seq,
                "state": link.state,
                "state_since": link.state_since,
                "transitions": [list(t) for t in self.link.transitions[-20:]],
                "withheld": self.link.withheld,
            },
            **({} if now is None else {"vital": self.vitality(now)}),
        }


_STATUS_NAMES = {0: "initialising", 1: "nominal", 2: "degraded", 3: "lost"}


def _stream_name(key: Any) -> str:
    """A stream key (an address, or (address, SENSOR_TYPE) with per-type sequences) for the logs."""
    if isinstance(key, tuple) and len(key) == 2 and isinstance(key[0], tuple):
        return f"{source_of(key[0])}/{_TYPE_NAMES.get(key[1], key[1])}"
    return source_of(key)


def _round(x: float | None) -> float | None:
    return None if x is None else round(x, 4)


def _outcome_name(outcome: Any) -> str:
    name = getattr(outcome, "name", None)
    return name.lower() if isinstance(name, str) else str(outcome)
