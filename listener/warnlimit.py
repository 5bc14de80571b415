"""Rate limit of the pipeline's warning events (sans-I/O: ``now`` is an argument).

The trust checks (:mod:`listener.senders`, the sequence buffers' jump handling) and the resilience
stage (:mod:`listener.resilience`: plausibility, clock, checkpoint) can fire once per datagram under
attack. Each kind of warning goes out at most once per ``interval_s``; the ones held back are counted
and the next one that goes out carries ``suppressed`` (how many were held back since the previous
one). The counters beside them (metrics) are never rate limited.
"""

from __future__ import annotations

import math
from typing import Any

from listener.errors import ConfigError

DEFAULT_INTERVAL_S = 10.0  #: at most one warning of a kind per this many seconds [s]


class WarningLimiter:
    """At most one event per kind per ``interval_s``; the rest counted and reported with the next one."""

    __slots__ = ("interval_s", "_last", "_suppressed", "emitted", "suppressed_total", "total")

    def __init__(self, interval_s: float = DEFAULT_INTERVAL_S) -> None:
        if isinstance(interval_s, bool) or not isinstance(interval_s, int | float) or not (
            math.isfinite(interval_s) and interval_s >= 0
        ):
            raise ConfigError(f"warning interval must be a finite number >= 0 [s], got {interval_s!r}")
        self.interval_s = float(interval_s)
        self._last: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}
        self.emitted = 0
        self.suppressed_total = 0
        self.total: dict[str, int] = {}  #: occurrences per kind, let through or not

    def event(
        self, kind: str, now: float, limit_key: str | None = None, **fields: Any
    ) -> dict[str, Any] | None:
        """The event ``{"event": kind, "at": now, "level": "warning", **fields}`` if one of this kind
        (or of ``limit_key``, a finer kind: e.g. the reason) may go out at ``now`` (with ``suppressed``
        when some were held back), else None (counted)."""
        key = kind if limit_key is None else limit_key
        self.total[kind] = self.total.get(kind, 0) + 1
        last = self._last.get(key)
        if last is not None and now - last < self.interval_s:
            self._suppressed[key] = self._suppressed.get(key, 0) + 1
            self.suppressed_total += 1
            return None
        self._last[key] = now
        self.emitted += 1
        # suppressed: how many of this kind were held back since the previous one went out (0: none)
        held = self._suppressed.pop(key, 0)
        return {"event": kind, "at": now, "level": "warning", **fields, "suppressed": held}
