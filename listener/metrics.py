"""The operator's view: a Prometheus endpoint (``[metrics] port``, off by default), via prometheus_client.

prometheus_client serves ``/metrics`` from its own HTTP thread. The pipeline belongs to the event loop,
so a scrape never reads it from that thread: the collector asks the loop for a snapshot
(``loop.call_soon_threadsafe``) and waits for it at most ``SNAPSHOT_TIMEOUT_S``. A loop that does not
answer in time is itself the news: the scrape then carries ``sfa_up 0`` and nothing else of the
pipeline. The output latency histogram (from the loop callback that got the input to the datagram
handed to the socket) is observed on the loop thread; prometheus_client's metrics are thread-safe.

Names (all prefixed ``sfa_``) are listed in docs/listener.md, "Prometheus endpoint".
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import time
from typing import Any

from prometheus_client import CollectorRegistry, Histogram, start_http_server
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily

from listener.config import MetricsConfig, latency_buckets
from sfa.layout import REASON_NAMES

SNAPSHOT_TIMEOUT_S = 1.0
_STATUSES = ("initialising", "nominal", "degraded", "lost")
_LINK_STATES = ("idle", "up", "degraded", "down")
_SEQ_KINDS = ("in_order", "reordered", "duplicates", "lost", "late", "resyncs")


class _Collector:
    """Turns one service snapshot into metric families at each scrape."""

    def __init__(self, server: MetricsServer) -> None:
        self._server = server

    def collect(self):
        snap = self._server.snapshot()
        up = GaugeMetricFamily("sfa_up", "1 when the event loop answered the scrape in time")
        up.add_metric([], 0.0 if snap is None else 1.0)
        yield up
        if snap is None:
            return
        yield from _families(snap)


def _gauge(name: str, doc: str, value: float | None, labels: dict[str, str] | None = None):
    g = GaugeMetricFamily(name, doc, labels=list(labels or {}))
    g.add_metric(list((labels or {}).values()), float("nan") if value is None else float(value))
    return g


def _families(snap: dict[str, Any]):
    est = snap["estimate"]
    vital = snap["metrics"]["vital"]
    m = snap["metrics"]
    line = "" if est is None or est["line_id"] is None else str(est["line_id"])
    yield _gauge("sfa_position_arc_length_meters", "arc length of the last estimate on its line [m]",
                 None if est is None else est["arc_length_m"], {"line_id": line})
    yield _gauge("sfa_position_sigma_meters", "1-sigma of the arc length of the last estimate [m]",
                 None if est is None else est["sigma_s_m"])
    yield _gauge("sfa_position_epoch_seconds", "sensor time of the last estimate [s]",
                 None if est is None else est["epoch_s"])
    yield _gauge("sfa_speed_meters_per_second", "speed of the last estimate, > 0 forward [m/s]",
                 None if est is None else est["speed_mps"])
    status = vital["status"]
    g = GaugeMetricFamily("sfa_status", "1 for the filter status last observed (outputs and timer)",
                          labels=["status"])
    for name in _STATUSES:
        g.add_metric([name], 1.0 if status == name else 0.0)
    yield g
    g = GaugeMetricFamily("sfa_reason", "1 for each reason the filter reports with its status",
                          labels=["reason"])
    reasons = set(vital["reasons"])
    for name in REASON_NAMES.values():
        g.add_metric([name], 1.0 if name in reasons else 0.0)
    yield g
    decay = vital["decay"]
    yield _gauge("sfa_decay_latched", "1 while the latched decay state holds (no position sent as nominal)",
                 1.0 if decay["latched"] else 0.0)
    g = GaugeMetricFamily("sfa_decay_phase", "1 for the current decay phase", labels=["phase"])
    for ph in ("normal", "await_standstill", "await_ground_truth", "confirming"):
        g.add_metric([ph], 1.0 if decay["phase"] == ph else 0.0)
    yield g
    c = CounterMetricFamily("sfa_decay_entries", "times the decay state was entered")
    c.add_metric([], decay["entries"])
    yield c
    age = GaugeMetricFamily("sfa_module_last_heard_age_seconds", "time since the module was last heard [s]",
                            labels=["module"])
    rate = GaugeMetricFamily("sfa_module_rate_hertz", "datagrams per second over the rate window",
                             labels=["module"])
    nominal = GaugeMetricFamily("sfa_module_nominal_rate_hertz", "the module's configured nominal rate",
                                labels=["module"])
    heard = CounterMetricFamily("sfa_module_datagrams", "valid datagrams heard from the module",
                                labels=["module"])
    seq = CounterMetricFamily("sfa_module_sequence", "sequence accounting of the module's streams",
                              labels=["module", "kind"])
    for name, mod in vital["modules"].items():
        a = mod["last_heard_age_s"]
        age.add_metric([name], float("nan") if a is None else a)
        rate.add_metric([name], mod["rate_hz"])
        nominal.add_metric([name], mod["nominal_rate_hz"])
        heard.add_metric([name], mod["heard"])
        if mod["sequence"] is not None:
            for kind in _SEQ_KINDS:
                seq.add_metric([name, kind], mod["sequence"][kind])
    yield from (age, rate, nominal, heard, seq)
    inp = m["input"]
    c = CounterMetricFamily("sfa_input_datagrams", "input datagrams received")
    c.add_metric([], inp["received"])
    yield c
    c = CounterMetricFamily("sfa_input_rejected", "input datagrams rejected, by reason", labels=["reason"])
    for reason, n in inp["rejected_by_reason"].items():
        c.add_metric([reason], n)
    yield c
    sq = m["sequencing"]
    c = CounterMetricFamily("sfa_sequence", "sequence accounting over all streams", labels=["kind"])
    for kind in _SEQ_KINDS:
        c.add_metric([kind], sq[kind])
    yield c
    link = m["link"]
    g = GaugeMetricFamily("sfa_link_state", "1 for the OBCU link's current state", labels=["state"])
    for st in _LINK_STATES:
        g.add_metric([st], 1.0 if link["state"] == st else 0.0)
    yield g
    for key, doc in (("outputs", "new estimates sent to the OBCU"), ("retransmits", "resends"),
                     ("acks", "acks accepted"), ("withheld", "estimates withheld by the vital supervision")):
        c = CounterMetricFamily(f"sfa_link_{key}", doc)
        c.add_metric([], link[key])
        yield c
    res = m.get("resilience")
    if res is not None:  # issue 20: warnings of the resilience stage, by kind; STROBEs rejected
        c = CounterMetricFamily("sfa_warnings", "warning events raised (logged or rate-limited), by kind",
                                labels=["kind"])
        for kind, n in res["warnings"].items():
            c.add_metric([kind], n)
        yield c
        c = CounterMetricFamily("sfa_clock_rejected_strobes", "STROBEs not taken into the timebase")
        c.add_metric([], m["clock"]["rejected_strobes"])
        yield c


class MetricsServer:
    """The /metrics endpoint of one :class:`listener.service.ListenerService`."""

    def __init__(self, service, config: MetricsConfig) -> None:
        self._service = service
        self._cfg = config
        self.registry = CollectorRegistry(auto_describe=False)
        self.latency = Histogram(
            "sfa_output_latency_seconds",
            "from the loop callback that received the input to the output handed to the socket [s]",
            buckets=latency_buckets(config),
            registry=self.registry,
        )
        self.registry.register(_Collector(self))
        self._http = None
        self._thread = None
        self.port: int | None = None
        self.scrapes = 0
        self.timeouts = 0

    def start(self) -> None:
        self._http, self._thread = start_http_server(self._cfg.port, self._cfg.bind, registry=self.registry)
        self.port = self._http.server_port

    def stop(self) -> None:
        if self._http is not None:
            self._http.shutdown()
            self._http.server_close()
            self._http = None

    def outputs_sent(self, n: int, started: float) -> None:
        """``n`` datagrams handed to the socket in the callback that started at loop time ``started``."""
        loop = self._service._loop
        if loop is None:
            return
        lat = max(0.0, loop.time() - started)
        for _ in range(n):
            self.latency.observe(lat)

    def _take(self) -> dict[str, Any]:
        svc = self._service
        est = svc.pipeline.last_estimate
        return {
            "metrics": svc.metrics(),
            "estimate": None
            if est is None
            else {
                "arc_length_m": est.arc_length_m,
                "sigma_s_m": est.sigma_s_m,
                "epoch_s": est.epoch_s,
                "speed_mps": est.speed_mps,
                "line_id": est.line_id,
            },
            "taken": time.time(),
        }

    def snapshot(self) -> dict[str, Any] | None:
        """A snapshot taken on the event loop (None when it did not answer within the timeout)."""
        loop: asyncio.AbstractEventLoop | None = self._service._loop
        if loop is None or loop.is_closed():
            return None
        fut: concurrent.futures.Future = concurrent.futures.Future()

        def take() -> None:
            if fut.set_running_or_notify_cancel():
                try:
                    fut.set_result(self._take())
                except Exception as exc:  # pragma: no cover - reported to the scraper as sfa_up 0
                    fut.set_exception(exc)

        self.scrapes += 1
        try:
            loop.call_soon_threadsafe(take)
            return fut.result(timeout=SNAPSHOT_TIMEOUT_S)
        except (concurrent.futures.TimeoutError, RuntimeError, Exception):
            fut.cancel()
            self.timeouts += 1
            return None
