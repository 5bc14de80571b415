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
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

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
from listener.seqbuf import SeqBufferConfig, StreamTable, stream_key

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


@dataclass(frozen=True, slots=True)
class _Arrived:
    """A decoded message and the listener time it arrived."""

    msg: Any
    arrival: float


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
            from sfa.presets import config_for

            sel = self.cfg.filter
            cfg = config_for(sel.presets, imu=sel.imu, odometer=sel.odometer, gps=sel.gps)
            filt = TrackFilter(track, cfg)
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

    # ------------------------------------------------------------------ inputs
    def receive(self, data: bytes, addr: Any, now: float) -> list[bytes]:
        """One INPUT_PROTOCOL datagram from ``addr`` arrived at ``now``."""
        self.counters["received"] += 1
        if self.stopped:
            self.counters["after_stop"] += 1
            return []
        if self.auth is not None:
            try:
                data = self.auth.open_input(data, addr)
            except AuthError as exc:
                self.counters["rejected"] += 1
                self.rejected[str(exc.reason)] += 1
                return self._drain(now)
        try:
            msg = self._decode(data)
        except DecodeError as exc:
            self.counters["rejected"] += 1
            self.rejected[str(exc.reason)] += 1
            return self._drain(now)
        stype = int(sensor_type_of(msg))
        self.by_type[_TYPE_NAMES.get(stype, str(stype))] += 1
        key = stream_key(addr, stype, self.cfg.input.per_type_sequence)
        released = self.streams.push(key, msg.seq, _Arrived(msg, now), now)
        return self._dispatch(released, now)

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
        times = [t for t in (self.streams.next_deadline(), self.link.next_timer()) if t is not None]
        return min(times) if times else None

    def handle_timer(self, now: float) -> list[bytes]:
        """Release sequence-buffer holds and run the OBCU link's timers due at ``now``."""
        out = self._dispatch(self.streams.poll(now), now)
        out.extend(self.link.handle_timer(now))
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
                self.counters["strobes"] += 1
                self.clock.on_strobe(msg.timestamp, item.arrival)
                self._date_undated()
            elif isinstance(msg, Stop):
                self.counters["stops"] += 1
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
            self.counters["dated_by_strobe"] += 1
        else:
            ref = self.clock.to_sensor_time(item.arrival)
            if ref is not None and epoch > ref + self.cfg.clock.max_future_s:
                # e.g. a flipped exponent bit: one such epoch would drag the filter far into the future
                self.counters["rejected"] += 1
                self.rejected["epoch_future"] += 1
                return
            self.counters["dated_by_epoch"] += 1
        self._newest_epoch = max(self._newest_epoch, epoch)
        self._order += 1
        heapq.heappush(self._heap, (epoch, self._order, item.msg))
        if len(self._heap) > self.cfg.merge.max_pending:
            self.counters["merge_overflow"] += 1  # released early rather than lost

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
            if self.on_measurement is not None:
                self.on_measurement(meas)
            update = filt.process(meas)
            if self.on_update is not None:
                self.on_update(update)
            self.counters["processed"] += 1
            self.counters[f"outcome_{update.kind}_{_outcome_name(update.outcome)}"] += 1
            out.extend(self._maybe_output(now))
        return out

    def _maybe_output(self, now: float) -> list[bytes]:
        est = self.filter.estimate()
        if not math.isfinite(est.epoch_s) or not math.isfinite(est.arc_length_m):
            return []
        sensor_now = self.clock.to_sensor_time(now)
        stale_before = self.cfg.link.max_output_age_s + self.cfg.merge.hold_s  # the hold is intended
        if sensor_now is not None and est.epoch_s < sensor_now - stale_before:
            # behind by more than the freshness bound (a backlog): never sent as a fresh estimate
            self.counters["stale_not_sent"] += 1
            return []
        if est.epoch_s < self._last_output_epoch:
            return []
        if (
            est.epoch_s == self._last_output_epoch
            and self.last_estimate is not None
            and (est.arc_length_m == self.last_estimate.arc_length_m)
        ):
            return []
        self._last_output_epoch = est.epoch_s
        self.last_estimate = est
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
                    int(est.status),
                    est.line_id,
                )
            )
        return encode_output(OutputMessage(seq, est.epoch_s, est.arc_length_m))

    # ------------------------------------------------------------------ metrics
    def metrics(self) -> dict[str, Any]:
        """A snapshot of every stage's counters (JSON-serialisable)."""
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
                    )
                },
            },
            "clock": {
                "synced": self.clock.synced,
                "unconfirmed_strobes": self.clock.unconfirmed,
                "strobes": self.clock.strobes,
                "resets": self.clock.resets,
                "undated_pending": len(self._undated),
            },
            "merge": {"pending": len(self._heap)},
            "auth": None if self.auth is None else self.auth.stats(),
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
            },
        }


def _outcome_name(outcome: Any) -> str:
    name = getattr(outcome, "name", None)
    return name.lower() if isinstance(name, str) else str(outcome)
