"""Rate limit of warning events (sans-I/O): at most one event of a kind per interval, driven by ``now``.

A suppressed event is counted; the next one let through carries ``suppressed`` (how many of its kind
were dropped since the last one logged), so the log shows a flood without being one. Counters in the
metrics count every occurrence regardless.
"""

from __future__ import annotations

from typing import Any


class EventRateLimiter:
    def __init__(self, interval_s: float) -> None:
        self.interval_s = interval_s
        self._last: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}
        self.total: dict[str, int] = {}  #: occurrences per kind, logged or not

    def offer(self, kind: str, now: float, fields: dict[str, Any]) -> dict[str, Any] | None:
        """The event to queue for ``kind`` at ``now``, or None when it is suppressed."""
        self.total[kind] = self.total.get(kind, 0) + 1
        last = self._last.get(kind)
        if last is not None and now - last < self.interval_s:
            self._suppressed[kind] = self._suppressed.get(kind, 0) + 1
            return None
        self._last[kind] = now
        return {"event": kind, **fields, "suppressed": self._suppressed.pop(kind, 0)}
