"""Structured logs: one JSON object per line, with per-kind rate limiting of warnings.

``JsonLogger`` writes ``{"ts": ..., "level": ..., "event": ..., **fields}`` lines to a text stream
(stderr by default; journald stores them as they are). ``ts`` is wall-clock time for humans; the
cores never see it. Warnings of the same ``event`` kind are emitted at most once per
``warning_interval_s``; the suppressed count is carried by the next one that goes out (events that
must never be dropped, the vital supervision's status and link-state changes, pass ``limit=False``).

Under systemd, when the stream is the journal (``JOURNAL_STREAM`` names its device and inode, as
systemd.exec(5) documents), each line starts with the syslog priority ``<N>`` (debug 7, info 6,
warning 4, error 3), which journald strips and stores as PRIORITY, so ``journalctl -p warning``
filters. ``priority_prefix`` forces it on or off.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from typing import Any, TextIO

LEVELS = {"debug": 10, "info": 20, "warning": 30, "error": 40}
#: syslog priorities (sd-daemon(3) prefixes) of the levels
PRIORITIES = {"debug": 7, "info": 6, "warning": 4, "error": 3}


def stream_is_journal(stream: TextIO, environ: dict[str, str] | None = None) -> bool:
    """True when ``stream`` is the journal stream systemd connected (``JOURNAL_STREAM=dev:inode``)."""
    env = os.environ if environ is None else environ
    value = env.get("JOURNAL_STREAM", "")
    dev, sep, ino = value.partition(":")
    if not sep or not dev.isdigit() or not ino.isdigit():
        return False
    try:
        st = os.fstat(stream.fileno())
    except (AttributeError, OSError, ValueError):
        return False
    return st.st_dev == int(dev) and st.st_ino == int(ino)


def _clean(value: Any) -> Any:
    """JSON-safe copy: non-finite floats become strings, unknown objects their str()."""
    if isinstance(value, float):
        return value if math.isfinite(value) else str(value)
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_clean(v) for v in value]
    if value is None or isinstance(value, str | int | bool):
        return value
    return str(value)


class JsonLogger:
    """Minimal structured logger (the stdlib ``logging`` adds nothing here but indirection)."""

    def __init__(
        self,
        stream: TextIO | None = None,
        level: str = "info",
        warning_interval_s: float = 5.0,
        clock=time.monotonic,
        priority_prefix: str = "auto",
    ) -> None:
        self._stream = stream if stream is not None else sys.stderr
        if priority_prefix not in ("auto", "on", "off"):
            raise ValueError(f"priority_prefix {priority_prefix!r}: expected auto, on or off")
        self.prefix = priority_prefix == "on" or (
            priority_prefix == "auto" and stream_is_journal(self._stream)
        )
        self._level = LEVELS[level]
        self._interval = warning_interval_s
        self._clock = clock
        self._last_warning: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}

    def log(self, level: str, event: str, limit: bool = True, **fields: Any) -> bool:
        """Write one line; returns False when filtered by level or (``limit``) the warning rate limit."""
        if LEVELS[level] < self._level:
            return False
        if limit and level == "warning" and self._interval > 0:
            now = self._clock()
            last = self._last_warning.get(event)
            if last is not None and now - last < self._interval:
                self._suppressed[event] = self._suppressed.get(event, 0) + 1
                return False
            self._last_warning[event] = now
            dropped = self._suppressed.pop(event, 0)
            if dropped:
                fields["suppressed"] = dropped
        record = {"ts": round(time.time(), 6), "level": level, "event": event}
        record.update(_clean(fields))
        try:
            line = json.dumps(record, separators=(",", ":"))
            if self.prefix:
                line = f"<{PRIORITIES[level]}>{line}"
            self._stream.write(line + "\n")
            self._stream.flush()
        except (OSError, ValueError):
            return False  # a closed or broken log stream must not stop the service
        return True

    def debug(self, event: str, **fields: Any) -> bool:
        return self.log("debug", event, **fields)

    def info(self, event: str, **fields: Any) -> bool:
        return self.log("info", event, **fields)

    def warning(self, event: str, **fields: Any) -> bool:
        return self.log("warning", event, **fields)

    def error(self, event: str, **fields: Any) -> bool:
        return self.log("error", event, **fields)
