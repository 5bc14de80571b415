"""Compiled reader of the common capture case: classic pcap, Ethernet, IPv4, UDP at fixed offsets.

The file is memory-mapped and its record headers walked in one numba loop (``scan_records``, the walk
the fast replay's single pass :func:`tools.fast_ingest.ingest` shares); each UDP datagram to the
listener port is returned as (arrival time, source address and port, payload offset and length) into
the mapped bytes, so no per-datagram Python object is ever built. Only the layout ``sfa sim`` and
``tcpdump -i lo`` write is handled here; anything else (pcapng, nanosecond timestamps, another link
type, VLAN tags, IPv6, options the reader would have to interpret, a truncated tail) makes
:func:`scan_capture` return None, and the caller falls back to the exact dpkt reader
(:mod:`tools.capture_reader`), which handles every case.

Frames the dpkt reader would skip are counted under the same reasons (``other_port``, ``not_udp``,
``ip_fragment``, ``udp_length_mismatch``); timestamps are computed with the same float operations
as dpkt (``sec + usec / 1e6``), so they are bit-identical.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tools.fast_ingest import (  # the compiled walk lives with the fast replay's single pass
    F_IP_FRAGMENT,
    F_NOT_UDP,
    F_OTHER_PORT,
    F_UDP_LENGTH_MISMATCH,
    U_OK,
    UNSUPPORTED_REASONS,
    map_capture,
    record_capacity,
    scan_records,
)

SKIP_REASONS = {
    F_OTHER_PORT: "other_port",
    F_NOT_UDP: "not_udp",
    F_IP_FRAGMENT: "ip_fragment",
    F_UDP_LENGTH_MISMATCH: "udp_length_mismatch",
}


@dataclass(frozen=True)
class ScannedCapture:
    """UDP datagrams to the listener port, in file order, as arrays into the mapped file."""

    data: np.ndarray  #: the whole file (uint8, memory-mapped)
    time_s: np.ndarray  #: capture timestamp per datagram [s] (float64)
    src_ip: np.ndarray  #: IPv4 source address per datagram (uint32, network byte order as an integer)
    src_port: np.ndarray  #: UDP source port per datagram (int64)
    offset: np.ndarray  #: payload start in ``data`` (int64)
    length: np.ndarray  #: payload length [bytes] (int64)
    frame_index: np.ndarray  #: 1-based record number of each datagram in the file (int64)
    frames: int  #: records in the file
    skipped_at: np.ndarray  #: (frame index, reason code) of every skipped frame (int64, (n, 2))


def scan_capture(path: str | Path, port: int) -> ScannedCapture | str:
    """Scan a classic little-endian microsecond pcap of Ethernet/IPv4 frames.

    Returns the scanned datagrams, or a string saying why this file needs the exact reader.
    """
    data = map_capture(path)
    if isinstance(data, str):
        return data
    cap = record_capacity(data)
    out_t = np.empty(cap, dtype=np.float64)
    out_ip = np.empty(cap, dtype=np.uint32)
    out_port = np.empty(cap, dtype=np.int64)
    out_off = np.empty(cap, dtype=np.int64)
    out_len = np.empty(cap, dtype=np.int64)
    out_frame = np.empty(cap, dtype=np.int64)
    skip = np.empty((cap, 2), dtype=np.int64)
    res = np.zeros(4, dtype=np.int64)
    scan_records(data, int(port), out_t, out_ip, out_port, out_off, out_len, out_frame, skip, res)
    status, frames, k, s = (int(x) for x in res)
    if status != U_OK:
        return f"record {frames}: {UNSUPPORTED_REASONS[int(status)]}"
    return ScannedCapture(
        data,
        out_t[:k].copy(),
        out_ip[:k].copy(),
        out_port[:k].copy(),
        out_off[:k].copy(),
        out_len[:k].copy(),
        out_frame[:k].copy(),
        int(frames),
        skip[:s].copy(),
    )
