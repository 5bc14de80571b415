"""Typed configuration of the listener service, loaded from TOML and validated at start.

Every field carries its unit. ``load_config(path, overrides)`` reads a TOML file (see
``listener/config/listener.example.toml`` for the documented example), applies command-line
overrides written as dotted keys (``link.ack_timeout_s=3``) and raises :class:`ConfigError` naming the
offending key on anything unknown, mistyped or out of range.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from listener.defaults import DEFAULT_HOST, DEFAULT_LISTENER_PORT, DEFAULT_OBCU_PORT
from listener.errors import ConfigError
from listener.senders import SendersConfig, parse_senders
from sfa.layout import REASON_NAMES

_FILTER_REASONS = frozenset(REASON_NAMES.values())


@dataclass(frozen=True)
class InputConfig:
    """UDP input and per-sender sequencing."""

    bind: str = "0.0.0.0"  #: address the input socket binds to
    port: int = DEFAULT_LISTENER_PORT  #: UDP port of INPUT_PROTOCOL [1..65535]
    per_type_sequence: bool = False  #: scope sequence numbers per (sender, SENSOR_TYPE) instead of per sender
    hold_time_s: float = 0.03  #: how long an out-of-order datagram waits for a gap to fill [s]
    max_pending: int = 256  #: datagrams held per stream before the oldest gap is declared lost [count]
    max_streams: int = 64  #: distinct senders tracked at once; idle ones are evicted beyond this [count]
    #: hold a new sender's first datagrams hold_time_s to find its true first number. Off by default:
    #: with it, the first releases depend on exact arrival timing, so a replay could differ from the
    #: live run in its first estimates; without it a reordered very first pair loses one datagram (late)
    startup_hold: bool = False
    #: SO_RCVBUF requested for the input socket [bytes]; as root SO_RCVBUFFORCE lifts the kernel's
    #: net.core.rmem_max cap; the size the kernel granted is logged at READY
    receive_buffer_bytes: int = 4 * 1024 * 1024
    #: how the input socket is read: "batched" (a non-blocking socket drained by loop.add_reader, up to
    #: batch_datagrams per wake-up, cheap header checks before the decode) or "protocol" (an asyncio
    #: DatagramProtocol, one callback per datagram: the earlier reader, kept for comparison)
    reader: str = "batched"
    batch_datagrams: int = 256  #: datagrams read per wake-up at most before the loop runs timers [count]


@dataclass(frozen=True)
class ClockConfig:
    """Mapping of arrival times onto the sensor-set timebase carried by STROBE."""

    window_strobes: int = 120  #: STROBEs kept for the offset and skew estimate [count]
    max_pending_undated: int = 512  #: undated measurements held until the first STROBE [count]
    max_step_s: float = (
        1.0  #: an offset change larger than this (confirmed by a second STROBE) resets the model [s]
    )
    #: a measurement whose epoch is further ahead of the STROBE clock's sensor time is rejected [s]
    max_future_s: float = 2.0
    #: nominal rate of the sensor-set clock against the listener's: sensor seconds per listener second.
    #: 1 on a train (the skew estimate is then bounded to +-1000 ppm around it); the simulator's
    #: --speed for an accelerated live run, whose sensor clock runs that many times faster [-]
    rate: float = 1.0
    #: drift bound of the sensor-set clock against the listener's (SUBSET-041: 0.1 %): a STROBE that
    #: would move the timebase faster than this (beyond the jitter allowance) is not taken [-]
    max_drift: float = 1e-3
    #: how much earlier than the model a STROBE may arrive and still be taken (delay jitter) [s]
    max_jitter_s: float = 0.05
    #: a new offset (a step, or a drift beyond the bound) is adopted only after STROBEs agreeing with it,
    #: and none agreeing with the current model, for this long [s]
    confirm_s: float = 5.0
    #: the status stays DEGRADED (reason clock_untrusted) this long after a STROBE was rejected or a
    #: measurement's epoch disagreed with the timebase [s]
    trouble_hold_s: float = 10.0


@dataclass(frozen=True)
class MergeConfig:
    """Time-ordered merge of the streams before the filter."""

    hold_s: float = 0.0  #: extra wait before a measurement is released to the filter, in sensor time [s]
    max_pending: int = 4096  #: measurements held in the merge at most [count]


@dataclass(frozen=True)
class LinkConfig:
    """OUTPUT_PROTOCOL link to the OBCU, acks and retransmission."""

    obcu_host: str = DEFAULT_HOST  #: OBCU address
    obcu_port: int = DEFAULT_OBCU_PORT  #: OBCU UDP port [1..65535]
    max_rate_hz: float = 0.0  #: cap on new outputs per second; 0 means one per filter update [Hz]
    start_seq: int = 0  #: SEQ of the first output [0..65535]
    degraded_after_s: float = 2.5  #: no ack for this long -> link DEGRADED [s]
    down_after_s: float = 5.0  #: no ack for this long -> link DOWN [s]
    #: resend the freshest estimate when nothing newer was sent for this long [s]
    retransmit_interval_s: float = 0.5
    max_retransmits: int = 10  #: resends of one estimate at most [count]
    max_output_age_s: float = 1.0  #: an estimate older than this (sensor time) is never resent [s]
    extended: bool = False  #: send the extended output form (protocol extension, off by default)


@dataclass(frozen=True)
class LogConfig:
    """Structured logging and metrics."""

    level: str = "info"  #: debug, info, warning or error
    metrics_interval_s: float = 10.0  #: period of the metrics snapshot in the log [s]
    warning_interval_s: float = 5.0  #: at most one warning of each kind per interval [s]
    #: "<N>" syslog priority prefix on each line: "auto" (when stderr is the journal, JOURNAL_STREAM),
    #: "on" or "off"
    priority_prefix: str = "auto"


@dataclass(frozen=True)
class FilterSelection:
    """Which filter preset the listener runs (see ``sfa.presets``)."""

    #: preset family: "datasheet" (sensor classes from datasheets, a digitised map's errors, the adaptive
    #: GNSS model; docs/filter.md) or "model-matched" (the simulator's own sensor settings: a result with
    #: it on the simulator's data proves nothing, docs/filter.md "Presets")
    presets: str = "datasheet"
    imu: str = "mems-train"  #: IMU preset name
    odometer: str = "wheel-odometer"  #: odometer preset name
    gps: str = "standalone"  #: GNSS preset name
    #: ``[filter.set]``: FilterConfig fields set on top of the preset (``sfa.config.FilterConfig``, units
    #: in the field names), as sorted (name, value) pairs, e.g. ``separation_window_s = 60.0``
    set: tuple[tuple[str, float | int | bool], ...] = ()

    def filter_config(self, **extra: object):
        """The ``sfa.config.FilterConfig`` this selection names: the preset family's configuration of
        the three sensors, the ``set`` fields, then ``extra`` (a replay's sweep) on top."""
        from sfa.presets import config_for

        return config_for(self.presets, imu=self.imu, odometer=self.odometer, gps=self.gps,
                          **{**dict(self.set), **extra})


@dataclass(frozen=True)
class AuthSettings:
    """Authenticated links (EN 50159 category 3 extension; off by default, see docs/protocol.md)."""

    enabled: bool = False  #: wrap/verify every datagram on both links with a truncated HMAC-SHA256
    key_file: str = ""  #: file with the master key as hex (at least 32 hex digits = 16 bytes)
    tag_bytes: int = 16  #: tag length [bytes], 16..32 (16 = 128 bits)
    window: int = 1024  #: anti-replay window per sender [extended sequence numbers]


@dataclass(frozen=True)
class VitalConfig:
    """Vital supervision (after the Vital Control seed): time-outs on a timer, module vitality, the
    latched decay state and what the OBCU sees in each state (docs/listener.md, docs/protocol.md)."""

    #: false: no time-out timer, no decay state, nothing withheld (the listener before issue 19: status
    #: events are still logged as measurements show them). For comparisons of the filter alone
    enabled: bool = True
    #: the worst filter status the 18-byte standard output (which has no status field) still carries:
    #: "degraded" (default: DEGRADED positions go out, LOST and decay stop the output) or "nominal"
    #: (only NOMINAL positions go out; anything else stops the output so the OBCU's age check trips)
    standard_output: str = "degraded"
    decay_on_lost: bool = True  #: LOST latches the decay state
    #: a declared sensor fault in ``decay_reasons`` present for longer than this latches decay [s]
    fault_budget_s: float = 10.0
    #: the filter reasons counted as declared sensor faults for the budget (comma-separated)
    decay_reasons: str = "imu_timeout,odometer_timeout,imu_stuck,imu_fault,odometer_slip"
    #: consistent updates (odometer or GNSS accepted while NOMINAL) after the GROUND TRUTH
    #: re-initialisation that release the decay state [count]
    recovery_updates: int = 20
    #: lateness of the timer that evaluates a silent sensor's time-out past its deadline [s]
    timeout_margin_s: float = 0.001
    rate_window_s: float = 5.0  #: window of the per-module rate estimate [s]
    imu_rate_hz: float = 100.0  #: nominal IMU rate [Hz]
    odometer_rate_hz: float = 20.0  #: nominal odometer rate [Hz]
    gnss_rate_hz: float = 1.0  #: nominal GNSS fix rate [Hz]
    #: a module whose rate over the window is below this fraction of its nominal rate is reported slow [-]
    min_rate_fraction: float = 0.8


@dataclass(frozen=True)
class PlausibilityConfig:
    """Plausibility of GROUND TRUTH and of the published arc length (docs/listener.md, "Plausibility")."""

    enabled: bool = True  #: false: GROUND TRUTH always applied, outputs never vetted (the listener before)
    #: the line's maximum speed where the track database's line has no ``maxspeed`` tag [m/s]
    #: (44.5 = 160 km/h, the fastest train preset on the bundled lines)
    max_speed_mps: float = 44.5
    speed_margin: float = 1.2  #: the change of the arc length may exceed the limit x time by this factor [-]
    #: the change between outputs may exceed the speed bound by this plus 3 sigma of the last output
    #: (filter corrections: a GNSS fix after a gap) [m]
    step_allowance_m: float = 25.0
    arc_margin_m: float = 50.0  #: the published arc length stays within [-margin, length + margin] [m]
    #: a GROUND TRUTH disagreeing with a NOMINAL filter is confirmed by a second one within this [s]
    gt_confirm_window_s: float = 30.0
    #: ... that agrees with it (after carrying the first forward at its speed) to within this [m]
    gt_confirm_tolerance_m: float = 10.0


@dataclass(frozen=True)
class CheckpointConfig:
    """State checkpoint for a restart without GROUND TRUTH (docs/listener.md, "Checkpoint and restart")."""

    enabled: bool = True  #: write and resume checkpoints (``sfa listen`` only; a replay never does)
    #: checkpoint file; "" = $STATE_DIRECTORY/listener-checkpoint.json when STATE_DIRECTORY is set
    #: (systemd's StateDirectory=), else no checkpoint
    path: str = ""
    interval_s: float = 1.0  #: period of the checkpoint [s]
    max_age_s: float = 10.0  #: an older checkpoint is refused at start [s]
    #: output SEQ of the first output after a resume: the checkpointed next SEQ plus this (more than the
    #: outputs sent between the last checkpoint and the exit; less than 32768) [count]
    seq_skip: int = 4096
    max_accel_mps2: float = 3.0  #: speed sigma widening per second of gap (emergency braking) [m/s^2]
    #: the first sensor time after the restart must match the checkpoint's plus the elapsed time to
    #: within this, else the checkpoint is refused (sensor-set clock reset) [s]
    clock_tolerance_s: float = 2.0
    #: a seed whose widened arc-length sigma exceeds this is refused (wait for GROUND TRUTH); above the
    #: filter's LOST bound (lost_sigma_m) the resumed estimates are not sent until GNSS narrows them [m]
    max_sigma_m: float = 500.0
    reanchor_gnss: int = 1  #: accepted GNSS fixes needed before the resumed status may be NOMINAL [count]
    reanchor_odometer: int = 5  #: accepted odometer samples needed too [count]


@dataclass(frozen=True)
class MetricsConfig:
    """Prometheus endpoint (off by default)."""

    port: int = 0  #: HTTP port of the /metrics endpoint; 0 = off [0..65535]
    bind: str = "127.0.0.1"  #: address the endpoint binds to
    #: upper bounds of the output latency histogram (datagram arrival -> output sent) [s], comma-separated
    latency_buckets_s: str = "0.0005,0.001,0.002,0.005,0.01,0.02,0.05,0.1,0.25,0.5,1"


@dataclass(frozen=True)
class ListenerConfig:
    """The whole listener configuration."""

    track: str = ""  #: path of the SQLite track database ("" = bundled default)
    input: InputConfig = field(default_factory=InputConfig)
    clock: ClockConfig = field(default_factory=ClockConfig)
    merge: MergeConfig = field(default_factory=MergeConfig)
    link: LinkConfig = field(default_factory=LinkConfig)
    log: LogConfig = field(default_factory=LogConfig)
    filter: FilterSelection = field(default_factory=FilterSelection)
    auth: AuthSettings = field(default_factory=AuthSettings)
    vital: VitalConfig = field(default_factory=VitalConfig)
    metrics: MetricsConfig = field(default_factory=MetricsConfig)
    #: which source may send which SENSOR_TYPE (listener.senders; default: trust on first use)
    senders: SendersConfig = field(default_factory=SendersConfig)
    plausibility: PlausibilityConfig = field(default_factory=PlausibilityConfig)
    checkpoint: CheckpointConfig = field(default_factory=CheckpointConfig)
    watchdog_max_lag_s: float = 0.5  #: event-loop lag beyond which WATCHDOG=1 is withheld [s]
    #: exit status of ``sfa listen`` after a STOP datagram (0 by default, as docs/interfaces say; the
    #: shipped systemd unit sets 10 with Restart=always and RestartPreventExitStatus=10) [0..255]
    stop_exit_status: int = 0


_SECTIONS = {
    "input": InputConfig,
    "clock": ClockConfig,
    "merge": MergeConfig,
    "link": LinkConfig,
    "log": LogConfig,
    "filter": FilterSelection,
    "auth": AuthSettings,
    "vital": VitalConfig,
    "metrics": MetricsConfig,
    "plausibility": PlausibilityConfig,
    "checkpoint": CheckpointConfig,
}


def _coerce(key: str, value: Any, typ: Any) -> Any:
    """Check ``value`` against the annotated type name ``typ`` and return it converted."""
    if typ in ("float", float):
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{key}: expected a number, got {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise ConfigError(f"{key}: must be finite, got {value!r}")
        return value
    if typ in ("int", int):
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{key}: expected an integer, got {value!r}")
        return value
    if typ in ("bool", bool):
        if not isinstance(value, bool):
            raise ConfigError(f"{key}: expected true or false, got {value!r}")
        return value
    if typ in ("str", str):
        if not isinstance(value, str):
            raise ConfigError(f"{key}: expected a string, got {value!r}")
        return value
    raise ConfigError(f"{key}: unsupported type {typ!r}")  # pragma: no cover - programming error


def _build(cls: type, data: dict[str, Any], prefix: str) -> Any:
    fields = {f.name: f for f in dataclasses.fields(cls)}
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        name = f"{prefix}{key}"
        if key not in fields:
            raise ConfigError(f"{name}: unknown key (known: {', '.join(sorted(fields))})")
        raw = cls is FilterSelection and key == "set"  # (already checked by _filter_set)
        kwargs[key] = value if raw else _coerce(name, value, fields[key].type)
    return cls(**kwargs)


def _filter_set(table: Any) -> tuple[tuple[str, float | int | bool], ...]:
    """``[filter.set]`` as sorted (name, value) pairs: numbers and booleans only (the names and ranges
    are checked against FilterConfig in :func:`_validate`)."""
    if not isinstance(table, dict):
        raise ConfigError("filter.set: expected a table of FilterConfig fields")
    out = []
    for name, value in sorted(table.items()):
        finite = isinstance(value, bool) or (isinstance(value, int | float) and math.isfinite(value))
        if not finite:
            raise ConfigError(f"filter.set.{name}: expected a finite number or true/false, got {value!r}")
        out.append((name, value))
    return tuple(out)


def _validate(cfg: ListenerConfig) -> None:
    def need(cond: bool, key: str, why: str) -> None:
        if not cond:
            raise ConfigError(f"{key}: {why}")

    need(1 <= cfg.input.port <= 65535, "input.port", "must be in 1..65535")
    need(cfg.input.hold_time_s >= 0.0, "input.hold_time_s", "must be >= 0")
    need(cfg.input.hold_time_s <= 5.0, "input.hold_time_s", "must be <= 5 s")
    need(cfg.input.max_pending >= 1, "input.max_pending", "must be >= 1")
    need(cfg.input.max_streams >= 1, "input.max_streams", "must be >= 1")
    need(cfg.input.receive_buffer_bytes >= 65536, "input.receive_buffer_bytes", "must be >= 65536")
    need(cfg.input.reader in ("batched", "protocol"), "input.reader", "must be batched or protocol")
    need(1 <= cfg.input.batch_datagrams <= 65536, "input.batch_datagrams", "must be in 1..65536")
    need(cfg.clock.window_strobes >= 1, "clock.window_strobes", "must be >= 1")
    need(cfg.clock.max_pending_undated >= 0, "clock.max_pending_undated", "must be >= 0")
    need(cfg.clock.max_step_s > 0.0, "clock.max_step_s", "must be > 0")
    need(cfg.clock.max_future_s > 0.0, "clock.max_future_s", "must be > 0")
    need(0.01 <= cfg.clock.rate <= 1000.0, "clock.rate", "must be in 0.01..1000")
    need(0.0 < cfg.clock.max_drift <= 0.1, "clock.max_drift", "must be in (0, 0.1]")
    need(cfg.clock.max_jitter_s >= 0.0, "clock.max_jitter_s", "must be >= 0")
    need(cfg.clock.confirm_s >= 0.0, "clock.confirm_s", "must be >= 0")
    need(cfg.clock.trouble_hold_s >= 0.0, "clock.trouble_hold_s", "must be >= 0")
    pl = cfg.plausibility
    need(pl.max_speed_mps > 0.0, "plausibility.max_speed_mps", "must be > 0")
    need(pl.speed_margin >= 1.0, "plausibility.speed_margin", "must be >= 1")
    need(pl.step_allowance_m >= 0.0, "plausibility.step_allowance_m", "must be >= 0")
    need(pl.arc_margin_m >= 0.0, "plausibility.arc_margin_m", "must be >= 0")
    need(pl.gt_confirm_window_s > 0.0, "plausibility.gt_confirm_window_s", "must be > 0")
    need(pl.gt_confirm_tolerance_m > 0.0, "plausibility.gt_confirm_tolerance_m", "must be > 0")
    if cfg.filter.set:  # every field and value as FilterConfig checks them (a clear error, at load)
        from sfa.errors import SfaError

        try:
            cfg.filter.filter_config()
        except (SfaError, KeyError, TypeError) as exc:
            raise ConfigError(f"filter.set: {exc}") from exc
    ck = cfg.checkpoint
    need(ck.interval_s > 0.0, "checkpoint.interval_s", "must be > 0")
    need(ck.max_age_s > 0.0, "checkpoint.max_age_s", "must be > 0")
    need(0 <= ck.seq_skip <= 32767, "checkpoint.seq_skip", "must be in 0..32767")
    need(ck.max_accel_mps2 > 0.0, "checkpoint.max_accel_mps2", "must be > 0")
    need(ck.clock_tolerance_s > 0.0, "checkpoint.clock_tolerance_s", "must be > 0")
    need(ck.max_sigma_m > 0.0, "checkpoint.max_sigma_m", "must be > 0")
    need(ck.reanchor_gnss >= 0, "checkpoint.reanchor_gnss", "must be >= 0")
    need(ck.reanchor_odometer >= 0, "checkpoint.reanchor_odometer", "must be >= 0")
    need(0 <= cfg.stop_exit_status <= 255, "stop_exit_status", "must be in 0..255")
    need(cfg.merge.hold_s >= 0.0, "merge.hold_s", "must be >= 0")
    need(cfg.merge.max_pending >= 1, "merge.max_pending", "must be >= 1")
    need(1 <= cfg.link.obcu_port <= 65535, "link.obcu_port", "must be in 1..65535")
    need(cfg.link.max_rate_hz >= 0.0, "link.max_rate_hz", "must be >= 0")
    need(0 <= cfg.link.start_seq <= 65535, "link.start_seq", "must be in 0..65535")
    need(cfg.link.degraded_after_s > 0.0, "link.degraded_after_s", "must be > 0")
    need(
        cfg.link.down_after_s > cfg.link.degraded_after_s,
        "link.down_after_s",
        "must be greater than link.degraded_after_s",
    )
    need(cfg.link.retransmit_interval_s > 0.0, "link.retransmit_interval_s", "must be > 0")
    need(cfg.link.max_retransmits >= 0, "link.max_retransmits", "must be >= 0")
    need(cfg.link.max_output_age_s > 0.0, "link.max_output_age_s", "must be > 0")
    need(
        cfg.log.level in ("debug", "info", "warning", "error"),
        "log.level",
        "must be one of debug, info, warning, error",
    )
    need(cfg.log.metrics_interval_s > 0.0, "log.metrics_interval_s", "must be > 0")
    need(cfg.log.warning_interval_s >= 0.0, "log.warning_interval_s", "must be >= 0")
    need(cfg.log.priority_prefix in ("auto", "on", "off"), "log.priority_prefix", "must be auto, on or off")
    need(cfg.watchdog_max_lag_s > 0.0, "watchdog_max_lag_s", "must be > 0")
    from sfa.presets import PRESET_FAMILIES

    need(cfg.filter.presets in PRESET_FAMILIES, "filter.presets",
         f"must be {' or '.join(PRESET_FAMILIES)}, got {cfg.filter.presets!r}")
    need(16 <= cfg.auth.tag_bytes <= 32, "auth.tag_bytes", "must be in 16..32")
    need(cfg.auth.window >= 1, "auth.window", "must be >= 1")
    need(not cfg.auth.enabled or bool(cfg.auth.key_file), "auth.key_file", "required when auth.enabled")
    v = cfg.vital
    need(v.standard_output in ("degraded", "nominal"), "vital.standard_output", "must be degraded or nominal")
    need(v.fault_budget_s >= 0.0, "vital.fault_budget_s", "must be >= 0")
    unknown = [r for r in decay_reasons(v) if r not in _FILTER_REASONS]
    known = ", ".join(sorted(_FILTER_REASONS))
    need(not unknown, "vital.decay_reasons", f"unknown reason(s) {unknown} (known: {known})")
    need(v.recovery_updates >= 1, "vital.recovery_updates", "must be >= 1")
    need(0.0 < v.timeout_margin_s <= 0.05, "vital.timeout_margin_s", "must be in (0, 0.05]")
    need(v.rate_window_s > 0.0, "vital.rate_window_s", "must be > 0")
    for key in ("imu_rate_hz", "odometer_rate_hz", "gnss_rate_hz"):
        need(getattr(v, key) > 0.0, f"vital.{key}", "must be > 0")
    need(0.0 <= v.min_rate_fraction <= 1.0, "vital.min_rate_fraction", "must be in 0..1")
    need(0 <= cfg.metrics.port <= 65535, "metrics.port", "must be in 0..65535 (0 = off)")
    try:
        buckets = latency_buckets(cfg.metrics)
    except ValueError:
        buckets = []
    need(
        bool(buckets) and all(b > 0 for b in buckets) and buckets == sorted(set(buckets)),
        "metrics.latency_buckets_s",
        f"must be increasing positive numbers, got {cfg.metrics.latency_buckets_s!r}",
    )


def decay_reasons(v: VitalConfig) -> tuple[str, ...]:
    """The configured decay reasons as a tuple of filter reason names."""
    return tuple(r.strip() for r in v.decay_reasons.split(",") if r.strip())


def latency_buckets(m: MetricsConfig) -> list[float]:
    """The configured histogram bounds [s]; ValueError when one is not a number."""
    return [float(b) for b in m.latency_buckets_s.split(",") if b.strip()]


def _set_dotted(tree: dict[str, Any], dotted: str, raw: str) -> None:
    """Apply one ``section.key=value`` override; the value is parsed as a TOML value, else a string."""
    parts = dotted.split(".")
    if not all(parts):
        raise ConfigError(f"override {dotted!r}: empty key component")
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw
    node = tree
    for part in parts[:-1]:
        child = node.setdefault(part, {})
        if not isinstance(child, dict):
            raise ConfigError(f"override {dotted!r}: {part} is not a section")
        node = child
    node[parts[-1]] = value


def config_from_dict(data: dict[str, Any]) -> ListenerConfig:
    """Build and validate a :class:`ListenerConfig` from a parsed TOML tree."""
    kwargs: dict[str, Any] = {}
    top = {f.name: f for f in dataclasses.fields(ListenerConfig)}
    for key, value in data.items():
        if key == "senders":  # nested tables, parsed once auth.enabled is known (below)
            continue
        if key in _SECTIONS:
            if not isinstance(value, dict):
                raise ConfigError(f"{key}: expected a table")
            if key == "filter" and "set" in value:
                value = {**value, "set": _filter_set(value["set"])}
            kwargs[key] = _build(_SECTIONS[key], value, f"{key}.")
        elif key in top:
            kwargs[key] = _coerce(key, value, top[key].type)
        else:
            raise ConfigError(f"{key}: unknown key (known: {', '.join(sorted(top))})")
    if "senders" in data:
        auth = kwargs.get("auth")
        kwargs["senders"] = parse_senders(data["senders"], authenticated=bool(auth and auth.enabled))
    cfg = ListenerConfig(**kwargs)
    _validate(cfg)
    return cfg


def load_config(path: str | Path | None = None, overrides: list[str] | None = None) -> ListenerConfig:
    """Read the TOML file at ``path`` (optional), apply ``key=value`` overrides, validate."""
    tree: dict[str, Any] = {}
    if path is not None:
        try:
            with open(path, "rb") as fh:
                tree = tomllib.load(fh)
        except FileNotFoundError as exc:
            raise ConfigError(f"{path}: no such configuration file") from exc
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{path}: not valid TOML: {exc}") from exc
    for item in overrides or []:
        if "=" not in item:
            raise ConfigError(f"override {item!r}: expected KEY=VALUE")
        key, raw = item.split("=", 1)
        _set_dotted(tree, key.strip(), raw.strip())
    return config_from_dict(tree)


def read_master_key(path: str) -> bytes:
    """The master key from a file holding it as hex (whitespace ignored); at least 16 bytes."""
    try:
        text = Path(path).read_text()
    except OSError as exc:
        raise ConfigError(f"auth.key_file {path}: cannot read: {exc.strerror or exc}") from exc
    try:
        key = bytes.fromhex("".join(text.split()))
    except ValueError:
        raise ConfigError(f"auth.key_file {path}: not a hex string") from None
    if len(key) < 16:
        raise ConfigError(f"auth.key_file {path}: {len(key)} bytes, at least 16 required")
    return key
