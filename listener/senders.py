"""Sender identity (sans-I/O): which source may send which SENSOR_TYPE (issue 20, part 1).

A *source* is the sender's socket as a string, ``"HOST:PORT"`` (``"[HOST]:PORT"`` for IPv6), or with
authenticated links (``auth.enabled``) the authenticated module id, ``"key:N"`` (the KEY_ID byte,
which only the holder of module N's key can sign for; the source address is then not trusted).

Three modes (``[senders] mode``):

- ``tofu`` (the default when no sender is configured): trust on first use. Each SENSOR_TYPE is bound
  to the first source that sends it; GROUND TRUTH and STOP are bound together to the source of the
  first GROUND TRUTH (the control module), so a STOP before any GROUND TRUTH is rejected. Each binding
  is logged (a warning event: it is a trust decision). The bindings can be persisted and restored
  (:meth:`SenderTable.snapshot` / :meth:`SenderTable.restore`, JSON-able) so a restarted listener
  keeps them.
- ``strict`` (the default when senders are configured): only the configured entries. Each entry is a
  source and the types it may send; GROUND TRUTH and STOP may be listed by one entry only (the control
  module's).
- ``permissive`` (lab): the rules of the table (or of TOFU when none is configured) are evaluated and
  every violation is counted (``would_reject``) and warned about, but the datagram is accepted. The
  listener logs a loud warning at start.

A rejected datagram is counted under its reason (``sender_unknown``: a source the table does not
know; ``sender_type``: a known source sending a type it may not send; ``sender_unbound``: TOFU, a STOP
before the control module is known) and produces a warning event, rate limited per reason
(:class:`listener.warnlimit.WarningLimiter`). The check comes before the sequence buffer, so a
rejected datagram never touches a stream's state.

TOML::

    [senders]
    mode = "strict"                  # tofu | strict | permissive (default: strict with entries, else tofu)
    warning_interval_s = 10.0        # at most one warning of a kind per interval [s]

    [senders.control]                # one table per sender; the name is for the logs
    source = "10.0.0.5:47001"        # or key_id = 0 with authenticated links
    types = ["ground_truth", "strobe", "stop"]

    [senders.gnss]
    source = "10.0.0.6:47003"
    types = ["gps"]
"""

from __future__ import annotations

import ipaddress
import math
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from listener.errors import ConfigError
from listener.warnlimit import DEFAULT_INTERVAL_S, WarningLimiter

__all__ = [
    "CONTROL_TYPES",
    "MODES",
    "SenderEntry",
    "SendersConfig",
    "SenderTable",
    "TYPE_CODES",
    "TYPE_NAMES",
    "parse_senders",
    "source_of",
]

TYPE_CODES = {"imu": 1, "odometer": 2, "gps": 3, "ground_truth": 8, "strobe": 9, "stop": 10}
TYPE_NAMES = {code: name for name, code in TYPE_CODES.items()}
GROUND_TRUTH = 8
STOP = 10
CONTROL_TYPES = frozenset((GROUND_TRUTH, STOP))  #: only from the control module
MODES = ("tofu", "strict", "permissive")
SNAPSHOT_VERSION = 1
_MAX_SOURCE_CHARS = 80

REJECT_UNKNOWN = "sender_unknown"  #: a source the table does not know
REJECT_TYPE = "sender_type"  #: a known source sending a type it may not send
REJECT_UNBOUND = "sender_unbound"  #: TOFU: a STOP before the control module is known


def source_of(addr: Any, key_id: int | None = None) -> str:
    """The source string of a datagram: ``"key:N"`` when authenticated, else ``"HOST:PORT"``."""
    if key_id is not None:
        return f"key:{int(key_id)}"
    if isinstance(addr, tuple) and len(addr) >= 2:
        host, port = addr[0], addr[1]
        host = str(host)
        return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
    return str(addr)


def _normalise_source(text: str, where: str) -> str:
    """``HOST:PORT`` with a literal IP address and a port in 1..65535, in :func:`source_of`'s form."""
    if not isinstance(text, str) or not text:
        raise ConfigError(f"{where}: expected \"HOST:PORT\", got {text!r}")
    host, sep, port = text.rpartition(":")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    try:
        ip = ipaddress.ip_address(host)
    except ValueError:
        raise ConfigError(f"{where}: {text!r}: the host must be a literal IP address") from None
    if not sep or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ConfigError(f"{where}: {text!r}: the port must be in 1..65535")
    return source_of((str(ip), int(port)))


@dataclass(frozen=True)
class SenderEntry:
    """One configured sender: its source and the SENSOR_TYPEs it may send."""

    name: str
    source: str  #: "HOST:PORT" or "key:N"
    types: frozenset[int]


@dataclass(frozen=True)
class SendersConfig:
    """The ``[senders]`` section."""

    mode: str = "tofu"  #: tofu, strict or permissive (the parser's default: strict with entries)
    warning_interval_s: float = DEFAULT_INTERVAL_S  #: at most one warning of a kind per interval [s]
    entries: tuple[SenderEntry, ...] = field(default_factory=tuple)


def parse_senders(data: Mapping[str, Any], authenticated: bool = False) -> SendersConfig:
    """The :class:`SendersConfig` of a parsed ``[senders]`` TOML table; ConfigError naming the key."""
    if not isinstance(data, Mapping):
        raise ConfigError("senders: expected a table")
    mode = None
    interval = DEFAULT_INTERVAL_S
    entries: list[SenderEntry] = []
    for key, value in data.items():
        where = f"senders.{key}"
        if key == "mode":
            if value not in MODES:
                raise ConfigError(f"{where}: must be one of {', '.join(MODES)}, got {value!r}")
            mode = value
        elif key == "warning_interval_s":
            ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
            if not ok or value < 0:
                raise ConfigError(f"{where}: must be a finite number >= 0 [s], got {value!r}")
            interval = float(value)
        elif isinstance(value, Mapping):
            entries.append(_entry(key, value, authenticated))
        else:
            raise ConfigError(
                f"{where}: unknown key (known: mode, warning_interval_s, or a [senders.NAME] table)"
            )
    if mode is None:
        mode = "strict" if entries else "tofu"
    if mode == "tofu" and entries:
        raise ConfigError("senders.mode: tofu learns the senders; remove it or the [senders.NAME] tables")
    if mode == "strict" and not entries:
        raise ConfigError("senders.mode: strict needs at least one [senders.NAME] table")
    seen: dict[str, str] = {}
    control = [e.name for e in entries if e.types & CONTROL_TYPES]
    if len(control) > 1:
        raise ConfigError(
            f"senders: ground_truth and stop come from the control module only, but {control} list them"
        )
    for e in entries:
        if e.source in seen:
            raise ConfigError(f"senders.{e.name}: source {e.source} is also senders.{seen[e.source]}")
        seen[e.source] = e.name
    return SendersConfig(mode, interval, tuple(entries))


def _entry(name: str, data: Mapping[str, Any], authenticated: bool) -> SenderEntry:
    where = f"senders.{name}"
    unknown = set(data) - {"source", "key_id", "types"}
    if unknown:
        raise ConfigError(f"{where}.{sorted(unknown)[0]}: unknown key (known: source, key_id, types)")
    if ("source" in data) == ("key_id" in data):
        raise ConfigError(f"{where}: give exactly one of source = \"HOST:PORT\" or key_id = N")
    if "key_id" in data:
        kid = data["key_id"]
        if isinstance(kid, bool) or not isinstance(kid, int) or not 0 <= kid <= 255:
            raise ConfigError(f"{where}.key_id: an integer in 0..255, got {kid!r}")
        if not authenticated:
            raise ConfigError(f"{where}.key_id: only with authenticated links (auth.enabled = true)")
        source = f"key:{kid}"
    else:
        if authenticated:
            raise ConfigError(
                f"{where}.source: with authenticated links a sender is its KEY_ID (key_id = N); "
                "the source address is not authenticated"
            )
        source = _normalise_source(data["source"], f"{where}.source")
    types = data.get("types")
    if not isinstance(types, list) or not types:
        raise ConfigError(f"{where}.types: a non-empty list of {', '.join(TYPE_CODES)}")
    codes = set()
    for t in types:
        if t not in TYPE_CODES:
            raise ConfigError(f"{where}.types: unknown type {t!r} (known: {', '.join(TYPE_CODES)})")
        codes.add(TYPE_CODES[t])
    return SenderEntry(name, source, frozenset(codes))


class SenderTable:
    """The sender check. ``check(source, sensor_type, now)``: None to accept, else the reject reason.

    Events (bindings, rejections: dicts with ``event``, ``at``, ``level``) queue in :attr:`events`;
    the pipeline moves them to its own event queue.
    """

    def __init__(self, config: SendersConfig | None = None) -> None:
        self.cfg = config or SendersConfig()
        self.mode = self.cfg.mode
        self.configured = bool(self.cfg.entries)
        #: SENSOR_TYPE -> the sources allowed (configured), or the one bound (TOFU)
        self._allowed: dict[int, frozenset[str]] = {}
        self._known: set[str] = set()
        for e in self.cfg.entries:
            self._known.add(e.source)
            for t in e.types:
                self._allowed[t] = self._allowed.get(t, frozenset()) | {e.source}
        self._bound: dict[int, str] = {}  # TOFU bindings (SENSOR_TYPE -> source)
        self._bound_at: dict[int, float] = {}
        self.rejected: Counter[str] = Counter()
        self.would_reject: Counter[str] = Counter()
        self.limiter = WarningLimiter(self.cfg.warning_interval_s)
        self.events: list[dict[str, Any]] = []

    # ------------------------------------------------------------------ the check
    def check(self, source: str, sensor_type: int, now: float) -> str | None:
        """None if ``source`` may send ``sensor_type`` (binding it on first use in TOFU), else why not."""
        if self.configured:
            allowed = self._allowed.get(sensor_type)
            if allowed is not None and source in allowed:
                return None
            why = REJECT_TYPE if source in self._known else REJECT_UNKNOWN
        else:
            why = self._tofu(source, sensor_type, now)
            if why is None:
                return None
        return self._violation(why, source, sensor_type, now)

    def _tofu(self, source: str, sensor_type: int, now: float) -> str | None:
        bound = self._bound.get(sensor_type)
        if bound == source:
            return None
        if bound is None:
            if sensor_type == STOP:  # the control module is the first GROUND TRUTH's source
                return REJECT_UNBOUND
            self._bind(sensor_type, source, now)
            return None
        return REJECT_TYPE if source in self._bound.values() else REJECT_UNKNOWN

    def _bind(self, sensor_type: int, source: str, now: float) -> None:
        types = (GROUND_TRUTH, STOP) if sensor_type == GROUND_TRUTH else (sensor_type,)
        for t in types:
            self._bound[t] = source
            self._bound_at[t] = now
        self.events.append(
            {
                "event": "sender_bound",
                "at": now,
                "level": "warning",
                "source": source,
                "types": [TYPE_NAMES[t] for t in types],
                "rule": "trust on first use ([senders] not configured)",
            }
        )

    def _violation(self, why: str, source: str, sensor_type: int, now: float) -> str | None:
        name = TYPE_NAMES.get(sensor_type, str(sensor_type))
        permissive = self.mode == "permissive"
        (self.would_reject if permissive else self.rejected)[why] += 1
        expected = self.allowed_sources(sensor_type)
        ev = self.limiter.event(
            "sender_would_reject" if permissive else "sender_rejected",
            now,
            limit_key=f"{'would_reject' if permissive else 'rejected'}:{why}",
            reason=why,
            source=source,
            type=name,
            allowed=sorted(expected),
        )
        if ev is not None:
            self.events.append(ev)
        return None if permissive else why

    # ------------------------------------------------------------------ views
    def allowed_sources(self, sensor_type: int) -> frozenset[str]:
        """The sources that may send ``sensor_type`` now (configured, or bound by TOFU)."""
        if self.configured:
            return self._allowed.get(sensor_type, frozenset())
        bound = self._bound.get(sensor_type)
        return frozenset() if bound is None else frozenset((bound,))

    def start_events(self, now: float) -> list[dict[str, Any]]:
        """The event to log at start: the mode, loud when permissive (never rate limited)."""
        ev: dict[str, Any] = {
            "event": "senders_mode",
            "at": now,
            "level": "warning" if self.mode != "strict" else "info",
            "mode": self.mode,
            "senders": {e.name: {"source": e.source, "types": sorted(TYPE_NAMES[t] for t in e.types)}
                        for e in self.cfg.entries},
        }
        if self.mode == "permissive":
            ev["warning"] = (
                "PERMISSIVE: datagrams from any source are accepted whatever their type; violations are "
                "only counted (senders.would_reject). Lab use only, never on a train."
            )
        elif self.mode == "tofu":
            ev["warning"] = (
                "no [senders] table: each SENSOR_TYPE is bound to the first source that sends it, "
                "GROUND TRUTH and STOP to the first GROUND TRUTH's"
            )
        return [ev]

    def stats(self) -> dict[str, Any]:
        """JSON-able counters and bindings (the metrics' ``senders`` section)."""
        return {
            "mode": self.mode,
            "configured": self.configured,
            "bindings": {TYPE_NAMES[t]: s for t, s in sorted(self._bound.items())},
            "rejected": dict(sorted(self.rejected.items())),
            "would_reject": dict(sorted(self.would_reject.items())),
            "warnings_suppressed": self.limiter.suppressed_total,
        }

    # ------------------------------------------------------------------ persistence (checkpoint)
    def snapshot(self) -> dict[str, Any]:
        """The learned bindings, JSON-able, for the checkpoint (a configured table learns nothing)."""
        return {
            "version": SNAPSHOT_VERSION,
            "mode": self.mode,
            "bindings": {TYPE_NAMES[t]: s for t, s in sorted(self._bound.items())},
        }

    def restore(self, snap: Mapping[str, Any], now: float = 0.0) -> int:
        """Take back the bindings of :meth:`snapshot` (a restarted listener); returns how many.

        A configured table has nothing to restore (0). Raises ConfigError naming the field on a
        malformed snapshot (the table is then unchanged)."""
        if not isinstance(snap, Mapping) or snap.get("version") != SNAPSHOT_VERSION:
            raise ConfigError(f"senders snapshot: expected version {SNAPSHOT_VERSION}, got {snap!r:.80}")
        bindings = snap.get("bindings")
        if not isinstance(bindings, Mapping):
            raise ConfigError("senders snapshot: bindings must be a table")
        parsed: dict[int, str] = {}
        for name, source in bindings.items():
            if name not in TYPE_CODES:
                raise ConfigError(f"senders snapshot: unknown type {name!r}")
            if not isinstance(source, str) or not source or len(source) > _MAX_SOURCE_CHARS:
                raise ConfigError(f"senders snapshot: {name}: bad source {source!r:.80}")
            parsed[TYPE_CODES[name]] = source
        if (GROUND_TRUTH in parsed) != (STOP in parsed) or parsed.get(GROUND_TRUTH) != parsed.get(STOP):
            raise ConfigError("senders snapshot: ground_truth and stop must be bound to the same source")
        if self.configured:
            return 0
        self._bound = parsed
        self._bound_at = dict.fromkeys(parsed, now)
        if parsed:
            self.events.append(
                {
                    "event": "sender_bindings_restored",
                    "at": now,
                    "level": "warning",
                    "bindings": {TYPE_NAMES[t]: s for t, s in sorted(parsed.items())},
                }
            )
        return len(parsed)
