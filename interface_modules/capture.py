"""Writers for the offline outputs: a classic pcap as captured on the listener's host, and truth.csv.

The pcap holds Ethernet II / IPv4 / UDP frames built with dpkt (correct lengths and checksums),
source ``network.host:module port``, destination ``network.listener_host:listener_port``, one frame
per datagram, timestamped with its arrival time (microsecond resolution, the classic format).
The IPv4 identification field counts per source module, like a host's per-socket counter would.
"""

from __future__ import annotations

import csv
import socket
from pathlib import Path

import numpy as np

from .errors import SimError

TRUTH_COLUMNS = ("epoch", "arc_length", "speed", "accel", "lat", "lon", "line_id", "direction", "event")
SRC_MAC = b"\x02\x00\x00\x00\x00\x01"  #: locally administered MAC of the sensor set
DST_MAC = b"\x02\x00\x00\x00\x00\x02"  #: locally administered MAC of the listener's host


def write_pcap(run, path: str | Path) -> int:
    """Write the run's packets as a classic pcap; return the number of frames."""
    import dpkt

    net = run.scenario.network
    try:
        src_ip = socket.inet_aton(net.host)
        dst_ip = socket.inet_aton(net.listener_host)
    except OSError as exc:
        raise SimError(f"network.host / listener_host must be IPv4 addresses: {exc}") from exc
    ip_ids: dict[int, int] = {}
    try:
        with open(path, "wb") as fh:
            writer = dpkt.pcap.Writer(fh, linktype=dpkt.pcap.DLT_EN10MB)
            for p in run.packets:
                udp = dpkt.udp.UDP(sport=p.src_port, dport=net.listener_port, data=p.payload)
                udp.ulen = len(udp)
                ident = ip_ids.get(p.src_port, 0)
                ip_ids[p.src_port] = (ident + 1) & 0xFFFF
                ip = dpkt.ip.IP(src=src_ip, dst=dst_ip, p=dpkt.ip.IP_PROTO_UDP, ttl=64, id=ident, data=udp)
                ip.len = len(ip)
                frame = dpkt.ethernet.Ethernet(
                    src=SRC_MAC, dst=DST_MAC, type=dpkt.ethernet.ETH_TYPE_IP, data=ip
                )
                writer.writepkt(bytes(frame), ts=p.arrival_s)
    except OSError as exc:
        raise SimError(f"cannot write capture {str(path)!r}: {exc}") from exc
    return len(run.packets)


def event_column(run) -> list[str]:
    """Per truth row, the events at that row's time (';'-joined, 'kind:detail')."""
    epoch = run.truth["epoch"]
    col = [""] * epoch.size
    if epoch.size == 0:
        return col
    for t, kind, detail in run.events:
        i = int(np.clip(np.searchsorted(epoch, t - 1e-9, side="left"), 0, epoch.size - 1))
        text = kind if not detail else f"{kind}:{detail}"
        col[i] = text if not col[i] else f"{col[i]};{text}"
    return col


def write_truth_csv(run, path: str | Path) -> int:
    """Write truth.csv (docs/simulator.md); return the number of rows."""
    tr = run.truth
    events = event_column(run)
    fmt = {
        "epoch": "{:.3f}".format,
        "arc_length": "{:.4f}".format,
        "speed": "{:.5f}".format,
        "accel": "{:.5f}".format,
        "lat": "{:.9f}".format,
        "lon": "{:.9f}".format,
        "line_id": lambda x: str(int(x)),
        "direction": lambda x: str(int(x)),
    }
    cols = [[fmt[name](x) for x in tr[name].tolist()] for name in TRUTH_COLUMNS[:-1]]
    try:
        with open(path, "w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(TRUTH_COLUMNS)
            w.writerows(zip(*cols, events, strict=True))
    except OSError as exc:
        raise SimError(f"cannot write truth {str(path)!r}: {exc}") from exc
    return len(events)


def write_events_csv(run, path: str | Path) -> int:
    """Write the run's events (epoch, kind, detail); return the number of rows."""
    try:
        with open(path, "w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(("epoch", "kind", "detail"))
            w.writerows((f"{t:.3f}", kind, detail) for t, kind, detail in run.events)
    except OSError as exc:
        raise SimError(f"cannot write events {str(path)!r}: {exc}") from exc
    return len(run.events)
