"""Sample streams -> INPUT_PROTOCOL datagrams per module, with sequence numbers and send/arrival times.

Each module is one sender with its own socket (source port) and sequence counter: the counter
starts at the module's ``seq_start``, increases by one per datagram actually sent and wraps at
65535; a ``restart`` fault puts it back to ``seq_start``. A ``silent`` fault suppresses sending.

Timing model (documented in docs/simulator.md): a sample taken at ``t`` is sent at
``t + send_delay_s + LN(send_jitter_s, jitter_sigma)`` and arrives at the listener's host
``delay_s + LN(jitter_s, jitter_sigma)`` later, where ``LN(m, sigma)`` is a lognormal with median
``m`` (``m = 0`` means no jitter). A sender is sequential and the path is FIFO, so send and
arrival times of one module never decrease (each at least 1 us after the previous one).

The control module sends GROUND TRUTH 0.1 s before the first sample (it carries the state at
``t = 0``), STROBE at ``t = 0, 1/rate, 2/rate ...`` with the sensor-set time of sending, and STOP
0.5 s after the last truth sample.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .faults import Fault
from .scenario import ModuleConfig, NetworkConfig
from .sensors.stream import SampleStream

GROUND_TRUTH_LEAD_S = 0.1  #: GROUND TRUTH is sent this long before t = 0 [s]
STOP_LAG_S = 0.5  #: STOP is sent this long after the last truth sample [s]
MIN_SPACING_S = 1e-6  #: minimum spacing of one sender's packets [s]


class Packet(NamedTuple):
    """One datagram as captured on the listener's host."""

    arrival_s: float  #: capture timestamp (host clock = sensor-set time + host_clock_offset_s) [s]
    src_port: int  #: UDP source port of the sending module
    payload: bytes  #: INPUT_PROTOCOL datagram
    send_s: float = 0.0  #: time the module sent it, sensor-set timebase [s]
    module: str = ""  #: imu, odometer, gps or control


def lognormal(rng: np.random.Generator, median: float, sigma: float, n: int) -> np.ndarray:
    """Lognormal samples with the given median (zeros when median is 0)."""
    if median <= 0 or n == 0:
        return np.zeros(n)
    return median * np.exp(sigma * rng.normal(0.0, 1.0, n))


def send_times(
    sample_t: np.ndarray, module: ModuleConfig, net: NetworkConfig, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """(send, arrival) times for samples taken at ``sample_t`` (see module doc), same timebase."""
    n = sample_t.size
    send = sample_t + module.send_delay_s + lognormal(rng, module.send_jitter_s, net.jitter_sigma, n)
    send = _monotone(send)
    arrival = _monotone(send + net.delay_s + lognormal(rng, net.jitter_s, net.jitter_sigma, n))
    return send, arrival


def _monotone(t: np.ndarray) -> np.ndarray:
    if t.size == 0:
        return t
    k = np.arange(t.size) * MIN_SPACING_S
    return np.maximum.accumulate(t - k) + k


def sequence_numbers(sent_t: np.ndarray, seq_start: int, faults: list[Fault]) -> np.ndarray:
    """Sequence number of each sent datagram (times ascending), with restarts."""
    n = sent_t.size
    counter = np.arange(n, dtype=np.int64)
    restarts = sorted(f.start_s for f in faults if f.kind == "restart")
    base = np.zeros(n, dtype=np.int64)
    for r in restarts:
        first = int(np.searchsorted(sent_t, r, side="left"))
        base[first:] = first
    return (seq_start + counter - base) % 65536


def silent_mask(t: np.ndarray, faults: list[Fault]) -> np.ndarray:
    """Samples suppressed by ``silent`` faults."""
    mask = np.zeros(t.size, dtype=bool)
    for f in faults:
        if f.kind == "silent":
            mask |= f.active(t)
    return mask


def sensor_payloads(stream: SampleStream, module: ModuleConfig, start_epoch_s: float, faults: list[Fault]):
    """(sample times, datagrams) one sensor module sends (bulk-packed, see ``wirepack``)."""
    from .wirepack import pack_stream

    send = stream.send & ~silent_mask(stream.t_s, faults)
    idx = np.flatnonzero(send)
    t = stream.t_s[idx]
    seq = sequence_numbers(t, module.seq_start, faults)
    epochs = start_epoch_s + t if module.send_epoch else None
    values = {k: arr[idx] for k, arr in stream.values.items()}
    return t, pack_stream(stream.module, seq, values, epochs)


def control_schedule(end_s: float, rate_hz: float, faults: list[Fault]) -> tuple[np.ndarray, list[str]]:
    """(scheduled times, kinds) of the control module's datagrams: GROUND TRUTH, STROBEs, STOP."""
    n_strobe = int(np.floor(end_s * rate_hz + 1e-9)) + 1
    t_all = np.concatenate(([-GROUND_TRUTH_LEAD_S], np.arange(n_strobe) / rate_hz, [end_s + STOP_LAG_S]))
    kinds = ["ground_truth"] + ["strobe"] * n_strobe + ["stop"]
    keep = ~silent_mask(t_all, faults)
    keep[-1] = True  # STOP always goes out at the end
    return t_all[keep], [k for k, kept in zip(kinds, keep, strict=True) if kept]


def control_messages(
    kinds: list[str],
    t: np.ndarray,
    send_t: np.ndarray,
    module: ModuleConfig,
    start_epoch_s: float,
    init_speed_mps: float,
    init_arc_m: float,
    line_id: int | None,
    faults: list[Fault],
) -> list:
    """InputMessages of the control module; a STROBE carries the sensor-set time it is sent at."""
    from listener.codec import GroundTruth, Stop, Strobe

    seq = sequence_numbers(t, module.seq_start, faults).tolist()
    msgs = []
    for i, kind in enumerate(kinds):
        if kind == "ground_truth":
            epoch = start_epoch_s if module.send_epoch else None
            msgs.append(GroundTruth(seq[i], init_speed_mps, 0.0, 0.0, init_arc_m, line_id, epoch))
        elif kind == "stop":
            msgs.append(Stop(seq[i]))
        else:
            msgs.append(Strobe(seq[i], start_epoch_s + float(send_t[i])))
    return msgs
