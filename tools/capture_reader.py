"""Reading captures (pcap and pcapng, as tcpdump or Wireshark write them) into UDP datagrams.

dpkt parses the file formats and the headers. Link types handled: Ethernet (tcpdump on ``lo`` or a
NIC), Linux cooked v1/v2 (``tcpdump -i any``), raw IP, BSD loopback (NULL/LOOP). IPv4 and IPv6.
Only UDP datagrams whose destination port is the listener port are returned; every other frame is
counted by the reason it was skipped. A truncated last record (tcpdump killed mid-write) ends the
read with a counted ``truncated_tail`` instead of an error; a file that is not a capture at all
raises :class:`~tools.errors.CaptureError` naming the file.
"""

from __future__ import annotations

import os
import struct
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from tools.errors import CaptureError

DLT_NULL = 0
DLT_EN10MB = 1
DLT_RAW_BSD = 12
DLT_RAW = 101
DLT_LOOP = 108
DLT_LINUX_SLL = 113
DLT_LINUX_SLL2 = 276


@dataclass(frozen=True, slots=True)
class CapturedDatagram:
    """One UDP datagram of the capture."""

    time_s: float  #: capture timestamp (arrival at the listener's host) [s]
    src: tuple[str, int]  #: source address and port
    dst_port: int  #: destination port
    payload: bytes


@dataclass
class CaptureStats:
    frames: int = 0  #: records in the file
    datagrams: int = 0  #: UDP datagrams to the listener port returned
    skipped: Counter = field(default_factory=Counter)  #: frames skipped, by reason
    truncated_bytes: int = 0  #: bytes of an incomplete last record, not read (file cut mid-record)
    truncated_records: int = 0  #: incomplete records at the end of the file (0 or 1)

    def truncation_warning(self, path: str | Path) -> str | None:
        """A one-line warning when the file ended inside a record, else None."""
        if not self.truncated_records:
            return None
        return (
            f"{path}: capture truncated mid-record: skipped the last {self.truncated_bytes} bytes "
            f"({self.truncated_records} incomplete record) after {self.frames} complete records"
        )


_PCAP_MAGIC_ORDER = {b"\xd4\xc3\xb2\xa1": "<", b"\x4d\x3c\xb2\xa1": "<", b"\xa1\xb2\xc3\xd4": ">",
                     b"\xa1\xb2\x3c\x4d": ">"}  # fmt: skip
_PCAP_RECORD_HEADER = 16  #: ts_sec, ts_frac, incl_len, orig_len


def _classic_record_complete(fh, start: int, end: int) -> bool:
    """Whether the classic-pcap record at ``start`` is whole (dpkt returns a short body silently)."""
    head = os.pread(fh.fileno(), _PCAP_RECORD_HEADER, start)
    order = _PCAP_MAGIC_ORDER.get(os.pread(fh.fileno(), 4, 0))
    if order is None or len(head) < _PCAP_RECORD_HEADER:
        return False
    (incl_len,) = struct.unpack_from(f"{order}I", head, 8)
    return end - start >= _PCAP_RECORD_HEADER + incl_len


def _ip_of(dlt: int, buf: bytes):
    """The IP packet inside a link-layer frame, or None."""
    import dpkt

    if dlt == DLT_EN10MB:
        eth = dpkt.ethernet.Ethernet(buf)
        return eth.data if isinstance(eth.data, dpkt.ip.IP | dpkt.ip6.IP6) else None
    if dlt == DLT_LINUX_SLL:
        sll = dpkt.sll.SLL(buf)
        return sll.data if isinstance(sll.data, dpkt.ip.IP | dpkt.ip6.IP6) else None
    if dlt == DLT_LINUX_SLL2:
        sll2 = dpkt.sll2.SLL2(buf)
        return sll2.data if isinstance(sll2.data, dpkt.ip.IP | dpkt.ip6.IP6) else None
    if dlt in (DLT_RAW, DLT_RAW_BSD):
        version = buf[0] >> 4 if buf else 0
        if version == 4:
            return dpkt.ip.IP(buf)
        if version == 6:
            return dpkt.ip6.IP6(buf)
        return None
    if dlt in (DLT_NULL, DLT_LOOP):
        lo = dpkt.loopback.Loopback(buf)
        return lo.data if isinstance(lo.data, dpkt.ip.IP | dpkt.ip6.IP6) else None
    raise CaptureError(f"unsupported link type {dlt}")


def _addr(ip) -> str:
    import socket

    import dpkt

    if isinstance(ip, dpkt.ip6.IP6):
        return socket.inet_ntop(socket.AF_INET6, ip.src)
    return socket.inet_ntop(socket.AF_INET, ip.src)


def read_capture(
    path: str | Path, port: int, stats: CaptureStats | None = None
) -> Iterator[CapturedDatagram]:
    """Yield the UDP datagrams to ``port`` in file order (the capture order is the arrival order)."""
    import dpkt

    stats = stats if stats is not None else CaptureStats()
    p = Path(path)
    try:
        fh = open(p, "rb")  # noqa: SIM115 - closed in finally
    except OSError as exc:
        raise CaptureError(f"{p}: cannot open: {exc.strerror or exc}") from exc
    try:
        try:
            reader = dpkt.pcap.UniversalReader(fh)
        except (ValueError, dpkt.dpkt.NeedData, dpkt.dpkt.UnpackError) as exc:
            raise CaptureError(f"{p}: not a pcap or pcapng capture ({exc})") from exc
        dlt = reader.datalink()
        if dlt not in (DLT_NULL, DLT_EN10MB, DLT_RAW_BSD, DLT_RAW, DLT_LOOP, DLT_LINUX_SLL, DLT_LINUX_SLL2):
            raise CaptureError(f"{p}: unsupported link type {dlt}")
        records = iter(reader)
        size = os.fstat(fh.fileno()).st_size
        classic = isinstance(reader, dpkt.pcap.Reader)
        index = 0
        while True:
            start = fh.tell()
            try:
                ts, buf = next(records)
            except StopIteration:
                break
            except (dpkt.dpkt.NeedData, dpkt.dpkt.UnpackError, ValueError, struct.error):
                _truncated(stats, size - start)
                break
            # the file can only end inside its last record: check that one (dpkt hands back a short body)
            end = fh.tell()
            if classic and end >= size and not _classic_record_complete(fh, start, end):
                _truncated(stats, size - start)
                break
            index += 1
            stats.frames += 1
            try:
                ip = _ip_of(dlt, buf)
            except (dpkt.dpkt.NeedData, dpkt.dpkt.UnpackError, IndexError, ValueError):
                stats.skipped["bad_frame"] += 1
                continue
            if ip is None:
                stats.skipped["not_ip"] += 1
                continue
            if isinstance(ip, dpkt.ip.IP) and (ip.mf or ip.offset):
                stats.skipped["ip_fragment"] += 1
                continue
            udp = ip.data
            if not isinstance(udp, dpkt.udp.UDP):
                stats.skipped["not_udp"] += 1
                continue
            if udp.dport != port:
                stats.skipped["other_port"] += 1
                continue
            payload = bytes(udp.data)
            if udp.ulen and udp.ulen - 8 != len(payload):
                stats.skipped["udp_length_mismatch"] += 1
                continue
            stats.datagrams += 1
            yield CapturedDatagram(float(ts), (_addr(ip), int(udp.sport)), int(udp.dport), payload)
    finally:
        fh.close()


def _truncated(stats: CaptureStats, nbytes: int) -> None:
    stats.skipped["truncated_tail"] += 1
    stats.truncated_records += 1
    stats.truncated_bytes += nbytes
