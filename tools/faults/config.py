"""The impairment profile of one direction of a fault proxy: a frozen, validated dataclass.

Every probability is per datagram in 0..1; every time is in seconds. Blackout windows and the
injection window are measured from the proxy's start (its first ``now``, or the ``start`` given to
the core). A profile is read from a TOML table whose keys are the field names (``from_dict``); the
same names, with ``-`` for ``_``, are the options of ``sfa faults proxy``.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tools.faults.errors import FaultConfigError

FORGE_KINDS = ("random", "ground_truth", "stop", "seq_jump", "strobe_shift")
#: SENSOR_TYPE names a forgery may pose as (Impairments.forge_as), with their SENSOR_TYPE byte
SENSOR_NAMES = {"imu": 1, "odometer": 2, "gps": 3, "ground_truth": 8, "strobe": 9}


@dataclass(frozen=True)
class Impairments:
    """What the proxy does to the datagrams of one direction (client -> upstream)."""

    loss: float = 0.0  #: Bernoulli loss probability [0..1]
    #: Gilbert-Elliott burst loss: probability of moving GOOD -> BAD per datagram [0..1] (0: off)
    ge_p_good_bad: float = 0.0
    ge_p_bad_good: float = 0.3  #: probability of moving BAD -> GOOD per datagram [0..1]
    ge_loss_good: float = 0.0  #: loss probability in the GOOD state [0..1]
    ge_loss_bad: float = 1.0  #: loss probability in the BAD state [0..1]
    duplicate: float = 0.0  #: probability a forwarded datagram is sent twice [0..1]
    duplicate_gap_s: float = 0.0005  #: delay of the copy after the original [s]
    #: probability a datagram is held and sent right after the next datagram of the same sender [0..1]
    reorder: float = 0.0
    reorder_max_s: float = 0.02  #: a held datagram goes out at the latest this long after it arrived [s]
    delay_s: float = 0.0  #: fixed delay added to every datagram [s]
    jitter_s: float = 0.0  #: uniform extra delay in [0, jitter_s], kept in order per sender [s]
    bitflip: float = 0.0  #: probability a datagram gets bit flips [0..1]
    bitflip_bits: int = 1  #: bits flipped in a corrupted datagram [count >= 1]
    truncate: float = 0.0  #: probability a datagram is cut to a random shorter length [0..1]
    #: blackout windows (start_s, duration_s) from the proxy start: nothing passes, either way [s]
    blackouts: tuple[tuple[float, float], ...] = ()
    replay: float = 0.0  #: probability an earlier datagram of the same sender is re-sent [0..1]
    replay_window: int = 512  #: earlier datagrams kept per sender for replays [count]
    forge_rate_hz: float = 0.0  #: forged INPUT datagrams injected per second [1/s]
    forge_count: int = 0  #: most forged datagrams injected (0: no limit) [count]
    #: fraction of forged datagrams that are fully valid (in range); the rest break a range or form [0..1]
    forge_valid_fraction: float = 0.0
    forge_on_stream: bool = False  #: send forged datagrams as if from a real sender (else their own source)
    #: what a *valid* forgery is (issue 20's trust attacks): "random" (any sensor, random content),
    #: "ground_truth" (a GROUND TRUTH at a random arc length), "stop" (a STOP), "seq_jump" (a copy of the
    #: real sender's last datagram with SEQ + forge_seq_offset; needs forge_on_stream), "strobe_shift"
    #: (a STROBE forge_shift_s off the stream's clock; made by the proxy live, which sees the stream)
    forge_kind: str = "random"
    forge_seq_offset: int = 100  #: seq_jump: how far ahead of the sender's last SEQ [sequence numbers]
    #: strobe_shift: a STROBE dated the stream's sensor time now (the newest real STROBE's timestamp plus
    #: the time since it passed) shifted by +- this, the sign drawn per forgery [s]
    forge_shift_s: float = 100.0
    #: forge_on_stream: pose as the real sender of this SENSOR_TYPE ("ground_truth": the control module,
    #: "gps", ...; "" any real sender). A GROUND TRUTH or STOP forged on a stream takes the next SEQ of
    #: that stream (the in-sequence masquerade); on an authenticated stream it is signed with that
    #: sender's key and epoch (a compromised module key: needs the core's ``sign``)
    forge_as: str = ""
    #: a STOP is forwarded with SEQ + this (the control stream's numbers in between never sent: a STOP
    #: after a gap) [sequence numbers]
    stop_seq_gap: int = 0
    #: replay burst: at this time from the start (< 0: none) every sender's first ``replay_burst``
    #: datagrams (recorded as they passed) are re-sent from that sender's socket [s]
    replay_burst_at_s: float = -1.0
    replay_burst: int = 0  #: datagrams recorded per sender for the replay burst [count]
    garbage_rate_hz: float = 0.0  #: random-byte datagrams injected per second (a flood) [1/s]
    garbage_max_bytes: int = 64  #: longest garbage datagram [bytes]
    inject_start_s: float = 0.0  #: injections start this long after the proxy start [s]
    inject_end_s: float = math.inf  #: injections end this long after the proxy start [s]
    impair_replies: bool = False  #: apply loss/duplication/corruption to replies too (blackouts always apply)
    max_batch: int = 10000  #: injections emitted per timer call at most (bounds one call's work) [count]
    max_senders: int = 256  #: distinct senders tracked; the least recent is forgotten beyond [count]

    def validate(self) -> Impairments:
        """Return self if consistent, else raise :class:`FaultConfigError` naming the field."""
        for name in (
            "loss", "ge_p_good_bad", "ge_p_bad_good", "ge_loss_good", "ge_loss_bad", "duplicate",
            "reorder", "bitflip", "truncate", "replay", "forge_valid_fraction",
        ):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and 0.0 <= value <= 1.0):
                raise FaultConfigError(f"{name}: a probability in 0..1, got {value!r}")
        for name in ("duplicate_gap_s", "reorder_max_s", "delay_s", "jitter_s", "forge_rate_hz",
                     "forge_shift_s",
                     "garbage_rate_hz", "inject_start_s"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0.0):
                raise FaultConfigError(f"{name}: must be finite and >= 0, got {value!r}")
        if not self.inject_end_s > self.inject_start_s:
            raise FaultConfigError("inject_end_s: must be greater than inject_start_s")
        for name, low in (("bitflip_bits", 1), ("replay_window", 1), ("forge_count", 0),
                          ("garbage_max_bytes", 1), ("max_batch", 1), ("max_senders", 1)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise FaultConfigError(f"{name}: an integer >= {low}, got {value!r}")
        if self.forge_as and self.forge_as not in SENSOR_NAMES:
            names = ", ".join(SENSOR_NAMES)
            raise FaultConfigError(f"forge_as: one of {names} (or \"\"), got {self.forge_as!r}")
        if self.forge_as and not self.forge_on_stream:
            raise FaultConfigError("forge_as: poses as a real sender: set forge_on_stream")
        for name in ("stop_seq_gap", "replay_burst"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 32767:
                raise FaultConfigError(f"{name}: an integer in 0..32767, got {value!r}")
        if not (isinstance(self.replay_burst_at_s, int | float) and math.isfinite(self.replay_burst_at_s)):
            raise FaultConfigError(f"replay_burst_at_s: a finite number, got {self.replay_burst_at_s!r}")
        if self.forge_kind not in FORGE_KINDS:
            raise FaultConfigError(f"forge_kind: one of {', '.join(FORGE_KINDS)}, got {self.forge_kind!r}")
        if self.forge_kind == "seq_jump" and not self.forge_on_stream:
            raise FaultConfigError("forge_kind: seq_jump forges a real sender's stream: set forge_on_stream")
        off = self.forge_seq_offset
        if isinstance(off, bool) or not isinstance(off, int) or not 1 <= off <= 32767:
            raise FaultConfigError(f"forge_seq_offset: an integer in 1..32767, got {off!r}")
        for i, window in enumerate(self.blackouts):
            ok = len(window) == 2 and all(math.isfinite(x) for x in window)
            if not ok or window[0] < 0 or window[1] <= 0:
                raise FaultConfigError(f"blackouts[{i}]: need start_s >= 0, duration_s > 0, not {window!r}")
        return self

    @property
    def injects(self) -> bool:
        """Whether the profile injects datagrams of its own (forged or garbage)."""
        return self.forge_rate_hz > 0.0 or self.garbage_rate_hz > 0.0

    @property
    def bursts(self) -> bool:
        """Whether the profile re-sends recorded datagrams in a replay burst."""
        return self.replay_burst > 0 and self.replay_burst_at_s >= 0.0

    def as_dict(self) -> dict[str, Any]:
        out = dataclasses.asdict(self)
        out["blackouts"] = [list(w) for w in self.blackouts]
        if math.isinf(self.inject_end_s):
            del out["inject_end_s"]
        return out


_FIELDS = {f.name: f for f in dataclasses.fields(Impairments)}


def impairments_from_dict(data: dict[str, Any], where: str = "profile") -> Impairments:
    """Build and validate a profile from a parsed TOML table (unknown keys are errors)."""
    if not isinstance(data, dict):
        raise FaultConfigError(f"{where}: expected a table")
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        if key not in _FIELDS:
            raise FaultConfigError(f"{where}.{key}: unknown key (known: {', '.join(sorted(_FIELDS))})")
        typ = str(_FIELDS[key].type)
        if key == "blackouts":
            if not isinstance(value, list) or not all(
                isinstance(w, list) and len(w) == 2 and all(_is_number(x) for x in w) for w in value
            ):
                raise FaultConfigError(f"{where}.blackouts: expected [[start_s, duration_s], ...]")
            value = tuple((float(a), float(b)) for a, b in value)
        elif typ == "float":
            if not _is_number(value):
                raise FaultConfigError(f"{where}.{key}: expected a number, got {value!r}")
            value = float(value)
        elif typ == "int":
            if isinstance(value, bool) or not isinstance(value, int):
                raise FaultConfigError(f"{where}.{key}: expected an integer, got {value!r}")
        elif typ == "bool" and not isinstance(value, bool):
            raise FaultConfigError(f"{where}.{key}: expected true or false, got {value!r}")
        elif typ == "str" and not isinstance(value, str):
            raise FaultConfigError(f"{where}.{key}: expected a string, got {value!r}")
        kwargs[key] = value
    try:
        return Impairments(**kwargs).validate()
    except FaultConfigError as exc:
        raise FaultConfigError(f"{where}.{exc}") from None


def load_profile(path: str | Path, table: str | None = None) -> Impairments:
    """Read a profile from a TOML file (the whole file, or one of its tables)."""
    try:
        data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise FaultConfigError(f"{path}: cannot read: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise FaultConfigError(f"{path}: not valid TOML: {exc}") from exc
    if table is not None:
        if table not in data:
            raise FaultConfigError(f"{path}: no table [{table}]")
        data = data[table]
    return impairments_from_dict(data, where=str(table or Path(path).name))


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(float(value))
