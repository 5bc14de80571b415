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


def udp_frames(packets, src_ip: bytes, dst_ip: bytes, dst_port: int) -> list[bytes]:
    """Ethernet II / IPv4 / UDP frames of ``packets`` (vectorised; byte-identical to dpkt's construction).

    IPv4: version 4, IHL 5, TOS 0, DF clear, TTL 64, protocol 17, identification counting per source
    port; header checksum and UDP checksum (over the pseudo-header) computed as RFC 768/791 say
    (a computed UDP checksum of 0 is sent as 0xFFFF). tests/test_sim_capture.py compares these
    frames with frames built field by field with dpkt.
    """
    n = len(packets)
    ports = np.fromiter((p.src_port for p in packets), dtype=np.int64, count=n)
    lengths = np.fromiter((len(p.payload) for p in packets), dtype=np.int64, count=n)
    ident = np.zeros(n, dtype=np.int64)
    for port in np.unique(ports):
        idx = np.flatnonzero(ports == port)
        ident[idx] = np.arange(idx.size) & 0xFFFF
    src_w = np.frombuffer(src_ip, dtype=">u2").astype(np.int64)
    dst_w = np.frombuffer(dst_ip, dtype=">u2").astype(np.int64)
    frames: list[bytes | None] = [None] * n
    for length in np.unique(lengths):
        idx = np.flatnonzero(lengths == length)
        m, L = idx.size, int(length)
        body = np.frombuffer(b"".join(packets[i].payload for i in idx.tolist()), dtype=np.uint8).reshape(m, L)
        padded = np.zeros((m, L + (L & 1)), dtype=np.int64)
        padded[:, :L] = body
        words = (padded[:, 0::2] << 8) | padded[:, 1::2]
        ulen = 8 + L
        total = 20 + ulen
        sport = ports[idx]
        # UDP checksum: pseudo-header (src, dst, proto, UDP length) + UDP header (checksum 0) + data
        s = words.sum(axis=1) + src_w.sum() + dst_w.sum() + 17 + ulen + sport + dst_port + ulen
        udp_sum = _fold(s) ^ 0xFFFF
        udp_sum[udp_sum == 0] = 0xFFFF
        ip_sum = (
            _fold(0x4500 + total + ident[idx] + 0 + ((64 << 8) | 17) + src_w.sum() + dst_w.sum()) ^ 0xFFFF
        )
        rec = np.empty(
            m,
            dtype=np.dtype(
                [
                    ("dst", "V6"),
                    ("src", "V6"),
                    ("etype", ">u2"),
                    ("vhl", "u1"),
                    ("tos", "u1"),
                    ("len", ">u2"),
                    ("id", ">u2"),
                    ("off", ">u2"),
                    ("ttl", "u1"),
                    ("p", "u1"),
                    ("sum", ">u2"),
                    ("ip_src", "V4"),
                    ("ip_dst", "V4"),
                    ("sport", ">u2"),
                    ("dport", ">u2"),
                    ("ulen", ">u2"),
                    ("usum", ">u2"),
                    ("data", "u1", (L,)),
                ]
            ),
        )
        rec["dst"] = np.void(DST_MAC)
        rec["src"] = np.void(SRC_MAC)
        rec["etype"] = 0x0800
        rec["vhl"], rec["tos"], rec["len"], rec["id"], rec["off"] = 0x45, 0, total, ident[idx], 0
        rec["ttl"], rec["p"], rec["sum"] = 64, 17, ip_sum
        rec["ip_src"], rec["ip_dst"] = np.void(src_ip), np.void(dst_ip)
        rec["sport"], rec["dport"], rec["ulen"], rec["usum"] = sport, dst_port, ulen, udp_sum
        rec["data"] = body
        size = rec.dtype.itemsize
        buf = rec.tobytes()
        for j, i in enumerate(idx.tolist()):
            frames[i] = buf[j * size : (j + 1) * size]
    return frames


def _fold(s: np.ndarray) -> np.ndarray:
    """One's-complement fold of 16-bit word sums."""
    s = np.asarray(s, dtype=np.int64)
    while np.any(s >> 16):
        s = (s & 0xFFFF) + (s >> 16)
    return s


def write_pcap(run, path: str | Path) -> int:
    """Write the run's packets as a classic pcap (dpkt.pcap.Writer); return the number of frames."""
    return write_packets_pcap(run.packets, run.scenario.network, path)


def write_packets_pcap(packets, network, path: str | Path) -> int:
    """Write ``packets`` (``.arrival_s``, ``.src_port``, ``.payload``) as a classic pcap from
    ``network.host`` to ``network.listener_host:listener_port``; return the number of frames."""
    import dpkt

    try:
        src_ip = socket.inet_aton(network.host)
        dst_ip = socket.inet_aton(network.listener_host)
    except OSError as exc:
        raise SimError(f"network.host / listener_host must be IPv4 addresses: {exc}") from exc
    frames = udp_frames(packets, src_ip, dst_ip, network.listener_port)
    try:
        with open(path, "wb") as fh:
            writer = dpkt.pcap.Writer(fh, snaplen=65535, linktype=dpkt.pcap.DLT_EN10MB)
            writer.writepkts(zip((p.arrival_s for p in packets), frames, strict=True))
    except OSError as exc:
        raise SimError(f"cannot write capture {str(path)!r}: {exc}") from exc
    return len(frames)


def strobe_dated(scenario):
    """The scenario with no epoch in any IMU, odometer or GNSS datagram (``send_epoch = false``): the
    thesis's sensors' form, every measurement dated by the listener's STROBE clock at its arrival."""
    import dataclasses

    return scenario.with_overrides(
        **{m: dataclasses.replace(getattr(scenario, m), send_epoch=False) for m in ("imu", "odometer", "gps")}
    )


def datagrams_of(run) -> list[tuple[float, tuple[str, int], bytes]]:
    """The run's packets as ``(arrival time, (source host, source port), payload)``."""
    host = "127.0.0.1"
    return [(float(p.arrival_s), (host, int(p.src_port)), bytes(p.payload)) for p in run.packets]


def lossy(datagrams, seed: int = 17) -> list:
    """``datagrams`` ``(time, source, payload)`` with 1 % of them lost, 1 % duplicated and 1 % overtaken by
    their successor (one seeded draw per datagram); the arrival times stay those of the original stream,
    in ascending order. The lossy form of the golden captures
    (tests/test_golden_replay.py), the fast replay's tests and ``sfa bench``'s replay capture."""
    rng = np.random.default_rng(seed)
    out: list = []
    for d in datagrams:
        u = rng.random()
        if u < 0.01:
            continue  # lost
        out.append(d)
        if u < 0.02:
            out.append(d)  # duplicated
        elif u < 0.03 and len(out) >= 2:
            out[-1], out[-2] = out[-2], out[-1]  # overtaken by its successor
    return [(t, src, pl) for (_, src, pl), t in zip(out, sorted(d[0] for d in out), strict=True)]


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


def _csv_field(text: str) -> str:
    """A CSV field: double quotes become single quotes; quoted if it holds a comma."""
    text = text.replace('"', "'").replace("\n", " ")
    return f'"{text}"' if "," in text else text


def write_truth_csv(run, path: str | Path) -> int:
    """Write truth.csv (docs/simulator.md); return the number of rows."""
    tr = run.truth
    events = [
        f'"{e}"' if ("," in e or '"' in e) and '"' not in e else e.replace('"', "'")
        for e in event_column(run)
    ]
    row = "%.3f,%.4f,%.5f,%.5f,%.9f,%.9f,%d,%d,%s"
    cols = [tr[name].tolist() for name in TRUTH_COLUMNS[:-1]]
    try:
        with open(path, "w", encoding="utf-8", newline="") as fh:
            fh.write(",".join(TRUTH_COLUMNS) + "\n")
            rows = zip(*cols, events, strict=True)
            fh.write("\n".join(map(row.__mod__, rows)))
            fh.write("\n")
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
