"""Compiled reader of captures in the forms tcpdump, dumpcap and the simulator write, read as dpkt reads them.

The file is memory-mapped and its records walked in one numba loop (``scan_records``, the walk the
fast replay's single pass :func:`tools.fast_ingest.ingest` shares); each UDP datagram to the listener
port is returned as (arrival time, IP header offset and version, payload offset and length) into the
mapped bytes, so no per-datagram Python object is ever built. Forms read, each exactly as the dpkt
reader of the exact replay (:mod:`tools.capture_reader`) interprets it:

- classic pcap, little- or big-endian, micro- or nanosecond timestamps; pcapng (its first section:
  Enhanced and obsolete Packet Blocks, other blocks skipped as dpkt skips them; the byte order,
  timestamp resolution and offset are the ones ``dpkt.pcapng.Reader`` takes from the section and its
  first interface, and it is run on the file to get them);
- Ethernet frames with up to two VLAN tags (802.1Q, 802.1ad, the legacy QinQ types, as
  ``dpkt.ethernet``), carrying IPv4 without options or IPv6 without extension headers (the numbers of
  ``dpkt.ip6.EXT_HDRS``), and UDP.

Anything else (the "modified" pcap forms, another link type, IPv4 options, IPv6 extension headers or
a jumbo payload, packet block options other than plain ones, a comment, a second pcapng section, a
record cut short by the snap length or a truncated tail) makes :func:`scan_capture` return a reason,
and the caller falls back to the exact dpkt reader, which handles every case.

Frames the dpkt reader would skip are counted under the same reasons (``other_port``, ``not_udp``,
``ip_fragment``, ``udp_length_mismatch``, and ``not_ip`` for an Ethernet type dpkt does not parse, or
ARP; :func:`tools.fast_ingest._ethernet_table`). Timestamps are dpkt's to the bit: ``sec + usec / 1e6`` in
floats for microsecond pcap; for nanosecond pcap dpkt computes ``sec + Decimal(nsec) / Decimal("1E9")``,
exact on these digits, and the walk computes the double nearest to that exact value in integer
arithmetic (:func:`tools.fast_ingest.nano_timestamp`); pcapng: ``tsoffset + float(ticks) / divisor``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tools.fast_ingest import (  # the compiled walk lives with the fast replay's single pass
    F_IP_FRAGMENT,
    F_NOT_IP,
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
    F_NOT_IP: "not_ip",
}


@dataclass(frozen=True)
class ScannedCapture:
    """UDP datagrams to the listener port, in file order, as arrays into the mapped file."""

    data: np.ndarray  #: the whole file (uint8, memory-mapped)
    time_s: np.ndarray  #: capture timestamp per datagram [s] (float64)
    ip_offset: np.ndarray  #: IP header start in ``data`` per datagram (int64)
    ip_version: np.ndarray  #: 4 or 6 per datagram (int8)
    src_port: np.ndarray  #: UDP source port per datagram (int64)
    offset: np.ndarray  #: payload start in ``data`` (int64)
    length: np.ndarray  #: payload length [bytes] (int64)
    frame_index: np.ndarray  #: 1-based record number of each datagram in the file (int64)
    frames: int  #: records in the file
    skipped_at: np.ndarray  #: (frame index, reason code) of every skipped frame (int64, (n, 2))


def scan_capture(path: str | Path, port: int) -> ScannedCapture | str:
    """Scan a capture in one of the forms of the module docstring.

    Returns the scanned datagrams, or a string saying why this file needs the exact reader.
    """
    mapped = map_capture(path)
    if isinstance(mapped, str):
        return mapped
    data = mapped.data
    cap = record_capacity(data)
    out_t = np.empty(cap, dtype=np.float64)
    out_ip = np.empty(cap, dtype=np.int64)
    out_ver = np.empty(cap, dtype=np.int8)
    out_off = np.empty(cap, dtype=np.int64)
    out_len = np.empty(cap, dtype=np.int64)
    out_frame = np.empty(cap, dtype=np.int64)
    skip = np.empty((cap, 2), dtype=np.int64)
    res = np.zeros(4, dtype=np.int64)
    scan_records(
        data, int(port), *mapped.args, out_t, out_ip, out_ver, out_off, out_len, out_frame, skip, res
    )
    status, frames, k, s = (int(x) for x in res)
    if status != U_OK:
        return f"record {frames}: {UNSUPPORTED_REASONS[int(status)]}"
    off = out_off[:k].copy()
    return ScannedCapture(
        data,
        out_t[:k].copy(),
        out_ip[:k].copy(),
        out_ver[:k].copy(),
        (data[off - 8].astype(np.int64) << 8) | data[off - 7].astype(np.int64),
        out_off[:k].copy(),
        out_len[:k].copy(),
        out_frame[:k].copy(),
        int(frames),
        skip[:s].copy(),
    )
