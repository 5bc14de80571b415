"""Test helpers: write (time, (host, port), payload) datagrams as pcap/pcapng with dpkt."""

from __future__ import annotations

import socket

import dpkt


def frame_ethernet(src, dst_port: int, payload: bytes, ip_id: int = 0) -> bytes:
    udp = dpkt.udp.UDP(sport=src[1], dport=dst_port, data=payload)
    udp.ulen = 8 + len(payload)
    ip = dpkt.ip.IP(
        src=socket.inet_aton(src[0]),
        dst=socket.inet_aton("127.0.0.1"),
        p=dpkt.ip.IP_PROTO_UDP,
        id=ip_id & 0xFFFF,
        data=udp,
    )
    ip.len = 20 + udp.ulen
    eth = dpkt.ethernet.Ethernet(src=b"\x00" * 6, dst=b"\x00" * 6, type=dpkt.ethernet.ETH_TYPE_IP, data=ip)
    return bytes(eth)


def write_capture(path, datagrams, dst_port: int = 48000, pcapng: bool = False, extra=()) -> None:
    """Write datagrams; ``extra`` are raw (time, frame) records interleaved by time (other traffic)."""
    records = [(t, frame_ethernet(addr, dst_port, data, i)) for i, (t, addr, data) in enumerate(datagrams)]
    records += list(extra)
    records.sort(key=lambda r: r[0])
    with open(path, "wb") as fh:
        writer = dpkt.pcapng.Writer(fh) if pcapng else dpkt.pcap.Writer(fh, nano=False)
        for t, frame in records:
            writer.writepkt(frame, ts=t)
