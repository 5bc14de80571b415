"""Test helpers: write (time, (host, port), payload) datagrams as pcap/pcapng with dpkt.

Besides the form ``sfa sim`` writes (classic little-endian microsecond pcap, Ethernet, IPv4), the
forms other capture tools write: pcapng, nanosecond and big-endian pcap, 802.1Q/802.1ad VLAN tags and
IPv6 (each IPv4 source address mapped to an IPv6 one, ``fd00::`` plus the IPv4 address).
"""

from __future__ import annotations

import ipaddress
import socket
import struct

import dpkt


def ipv6_of(host: str) -> str:
    """The IPv6 source address the helpers use for an IPv4 one (as socket.inet_ntop writes it)."""
    return str(ipaddress.IPv6Address(int(ipaddress.IPv6Address("fd00::")) + int(ipaddress.IPv4Address(host))))


def frame_ethernet(src, dst_port: int, payload: bytes, ip_id: int = 0, vlan=(), ipv6: bool = False) -> bytes:
    """An Ethernet frame of one UDP datagram; ``vlan``: (TPID, VLAN id) of each tag, outermost first."""
    udp = dpkt.udp.UDP(sport=src[1], dport=dst_port, data=payload)
    udp.ulen = 8 + len(payload)
    if ipv6:
        ip = dpkt.ip6.IP6(
            src=socket.inet_pton(socket.AF_INET6, ipv6_of(src[0])),
            dst=socket.inet_pton(socket.AF_INET6, "::1"),
            nxt=dpkt.ip.IP_PROTO_UDP,
            hlim=64,
            plen=udp.ulen,
            data=udp,
        )
        eth_type = dpkt.ethernet.ETH_TYPE_IP6
    else:
        ip = dpkt.ip.IP(
            src=socket.inet_aton(src[0]),
            dst=socket.inet_aton("127.0.0.1"),
            p=dpkt.ip.IP_PROTO_UDP,
            id=ip_id & 0xFFFF,
            data=udp,
        )
        ip.len = 20 + udp.ulen
        eth_type = dpkt.ethernet.ETH_TYPE_IP
    tags = b"".join(struct.pack(">HH", tpid, vid & 0x0FFF) for tpid, vid in vlan)
    if tags:  # the first tag's TPID where the type was; the inner type after the last tag
        return b"\x00" * 12 + tags + struct.pack(">H", eth_type) + bytes(ip)
    eth = dpkt.ethernet.Ethernet(src=b"\x00" * 6, dst=b"\x00" * 6, type=eth_type, data=ip)
    return bytes(eth)


def write_capture(
    path, datagrams, dst_port: int = 48000, pcapng: bool = False, extra=(), nano: bool = False,
    big_endian: bool = False, vlan=(), ipv6: bool = False,
) -> None:  # fmt: skip
    """Write datagrams; ``extra`` are raw (time, frame) records interleaved by time (other traffic).

    ``nano``: nanosecond timestamps; ``big_endian``: a classic pcap written in big-endian byte order
    (as on a big-endian host); ``vlan``, ``ipv6``: as :func:`frame_ethernet`."""
    records = [(t, frame_ethernet(a, dst_port, p, i, vlan, ipv6)) for i, (t, a, p) in enumerate(datagrams)]
    records += list(extra)
    records.sort(key=lambda r: r[0])
    with open(path, "wb") as fh:
        if big_endian:
            magic = dpkt.pcap.TCPDUMP_MAGIC_NANO if nano else dpkt.pcap.TCPDUMP_MAGIC
            fh.write(struct.pack(">IHHiIII", magic, 2, 4, 0, 0, 65535, dpkt.pcap.DLT_EN10MB))
            scale = 10**9 if nano else 10**6
            for t, frame in records:
                sec = int(t)
                frac = round(t % 1 * scale)
                fh.write(struct.pack(">IIII", sec, frac, len(frame), len(frame)) + frame)
            return
        writer = dpkt.pcapng.Writer(fh) if pcapng else dpkt.pcap.Writer(fh, nano=nano)
        for t, frame in records:
            writer.writepkt(frame, ts=t)
