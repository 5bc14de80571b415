"""Compiled reader of the common capture case: classic pcap, Ethernet, IPv4, UDP at fixed offsets.

The file is memory-mapped and its record headers walked in one numba loop; each UDP datagram to the
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
from numba import njit

PCAP_MAGIC_US_LE = 0xA1B2C3D4  #: classic pcap, microsecond timestamps, as read little-endian
GLOBAL_HEADER_BYTES = 24
RECORD_HEADER_BYTES = 16
ETH_HEADER_BYTES = 14
DLT_EN10MB = 1

# per-frame codes written by the scanner
F_DATAGRAM = 0
F_OTHER_PORT = 1
F_NOT_UDP = 2
F_IP_FRAGMENT = 3
F_UDP_LENGTH_MISMATCH = 4
SKIP_REASONS = {
    F_OTHER_PORT: "other_port",
    F_NOT_UDP: "not_udp",
    F_IP_FRAGMENT: "ip_fragment",
    F_UDP_LENGTH_MISMATCH: "udp_length_mismatch",
}

# why the scanner gave up (the exact reader takes over)
U_OK = 0
U_TRUNCATED = 1
U_NOT_ETHERNET_IPV4 = 2
U_IP_HEADER = 3
U_IP_LENGTH = 4
U_UDP_HEADER = 5
UNSUPPORTED_REASONS = {
    U_TRUNCATED: "truncated record",
    U_NOT_ETHERNET_IPV4: "frame not Ethernet/IPv4",
    U_IP_HEADER: "IPv4 header not plain",
    U_IP_LENGTH: "IPv4 length disagrees with the frame",
    U_UDP_HEADER: "UDP header cut short",
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


@njit(cache=True)
def _u16be(d, i):
    return (np.int64(d[i]) << 8) | np.int64(d[i + 1])


@njit(cache=True)
def _u32le(d, i):
    return (
        np.int64(d[i]) | (np.int64(d[i + 1]) << 8) | (np.int64(d[i + 2]) << 16) | (np.int64(d[i + 3]) << 24)
    )


@njit(cache=True)
def _scan(d, port, out_t, out_ip, out_port, out_off, out_len, out_frame, skip):
    """Walk the records. Returns (status, frames, datagrams, skipped)."""
    n = d.shape[0]
    pos = GLOBAL_HEADER_BYTES
    frames = 0
    k = 0
    s = 0
    while pos < n:
        if pos + RECORD_HEADER_BYTES > n:
            return U_TRUNCATED, frames, k, s
        sec = _u32le(d, pos)
        usec = _u32le(d, pos + 4)
        incl = _u32le(d, pos + 8)
        orig = _u32le(d, pos + 12)
        body = pos + RECORD_HEADER_BYTES
        if body + incl > n or incl != orig:
            return U_TRUNCATED, frames, k, s
        pos = body + incl
        frames += 1
        if incl < ETH_HEADER_BYTES + 20 or _u16be(d, body + 12) != 0x0800:
            return U_NOT_ETHERNET_IPV4, frames, k, s
        ip = body + ETH_HEADER_BYTES
        vhl = d[ip]
        if (vhl >> 4) != 4 or (vhl & 0xF) != 5:
            return U_IP_HEADER, frames, k, s
        ip_len = _u16be(d, ip + 2)
        if ip_len < 20 or ip_len > incl - ETH_HEADER_BYTES:
            return U_IP_LENGTH, frames, k, s
        flags_off = _u16be(d, ip + 6)
        if (flags_off & 0x2000) != 0 or (flags_off & 0x1FFF) != 0:
            skip[s, 0] = frames
            skip[s, 1] = F_IP_FRAGMENT
            s += 1
            continue
        if d[ip + 9] != 17:
            skip[s, 0] = frames
            skip[s, 1] = F_NOT_UDP
            s += 1
            continue
        udp = ip + 20
        udp_bytes = ip_len - 20
        if udp_bytes < 8:
            return U_UDP_HEADER, frames, k, s
        if _u16be(d, udp + 2) != port:
            skip[s, 0] = frames
            skip[s, 1] = F_OTHER_PORT
            s += 1
            continue
        ulen = _u16be(d, udp + 4)
        plen = udp_bytes - 8
        if ulen != 0 and ulen - 8 != plen:
            skip[s, 0] = frames
            skip[s, 1] = F_UDP_LENGTH_MISMATCH
            s += 1
            continue
        out_t[k] = np.float64(sec) + np.float64(usec) / 1e6  # as dpkt: tv_sec + tv_usec / 1E6
        out_ip[k] = (
            (np.uint32(d[ip + 12]) << 24)
            | (np.uint32(d[ip + 13]) << 16)
            | (np.uint32(d[ip + 14]) << 8)
            | np.uint32(d[ip + 15])
        )
        out_port[k] = _u16be(d, udp)
        out_off[k] = udp + 8
        out_len[k] = plen
        out_frame[k] = frames
        k += 1
    return U_OK, frames, k, s


def scan_capture(path: str | Path, port: int) -> ScannedCapture | str:
    """Scan a classic little-endian microsecond pcap of Ethernet/IPv4 frames.

    Returns the scanned datagrams, or a string saying why this file needs the exact reader.
    """
    p = Path(path)
    try:
        size = p.stat().st_size
    except OSError as exc:
        return f"cannot stat: {exc.strerror or exc}"
    if size < GLOBAL_HEADER_BYTES:
        return "not a classic pcap"
    try:
        data = np.memmap(p, dtype=np.uint8, mode="r")
    except (OSError, ValueError) as exc:
        return f"cannot map: {exc}"
    magic = int(data[0]) | int(data[1]) << 8 | int(data[2]) << 16 | int(data[3]) << 24
    if magic != PCAP_MAGIC_US_LE:
        return "not a little-endian microsecond classic pcap (pcapng, nanosecond or big-endian)"
    linktype = int(data[20]) | int(data[21]) << 8 | int(data[22]) << 16 | int(data[23]) << 24
    if linktype != DLT_EN10MB:
        return f"link type {linktype} (only Ethernet is read by the fast path)"
    # upper bound of the number of records: every record is at least 16 + 34 bytes
    cap = max(1, (size - GLOBAL_HEADER_BYTES) // (RECORD_HEADER_BYTES + ETH_HEADER_BYTES + 20) + 1)
    out_t = np.empty(cap, dtype=np.float64)
    out_ip = np.empty(cap, dtype=np.uint32)
    out_port = np.empty(cap, dtype=np.int64)
    out_off = np.empty(cap, dtype=np.int64)
    out_len = np.empty(cap, dtype=np.int64)
    out_frame = np.empty(cap, dtype=np.int64)
    skip = np.empty((cap, 2), dtype=np.int64)
    status, frames, k, s = _scan(data, int(port), out_t, out_ip, out_port, out_off, out_len, out_frame, skip)
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


def ipv4_text(addr: int) -> str:
    """Dotted-quad text of an IPv4 address held as an integer (as socket.inet_ntop writes it)."""
    a = int(addr)
    return f"{a >> 24 & 255}.{a >> 16 & 255}.{a >> 8 & 255}.{a & 255}"
