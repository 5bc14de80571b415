"""Write ``sample.pcap``: every SFA message kind, for the Wireshark dissector (``tools/wireshark/sfa.lua``).

    python -m tools.wireshark.make_sample [OUT.pcap]      (default: tools/wireshark/sample.pcap)

Contents, Ethernet/IPv4/UDP on 127.0.0.1 with the default ports (listener/defaults.py):

* 2 s of the simulator's ``tram-urban`` scenario (seed 1): the INPUT datagrams every interface module
  sends (GROUND TRUTH, STROBE, IMU, ODOMETER, GPS), from their source ports 47000-47003 to 48000;
* OUTPUT datagrams to the OBCU port 48001 from the listener's output socket (port 50000), 10 per
  second: standard 18-byte ones in the first second, the 47-byte extended form after; their values
  are taken from the simulator's truth (a filter would add its error: this file shows the format,
  not the filter);
* an ACK per second from 48001 back to port 50000;
* the authenticated envelope (listener/auth.py) around an INPUT (16- and 32-byte tags), an OUTPUT and
  an ACK, under the throwaway key :data:`SAMPLE_KEY` (not a secret: it only makes the tags real);
* a STOP to the non-default port 49000 (the heuristic dissector finds it), and seven datagrams the
  codec rejects, so the dissector's expert info can be seen: a length that disagrees with the header,
  an unknown SENSOR_TYPE, a 20-byte OUTPUT; and, well-formed but out of range, a latitude of 95 deg,
  a fix quality of 9, a NaN acceleration, an extended OUTPUT whose interval misses its arc length.

Deterministic: the simulator is seeded and nothing reads a clock.
"""

from __future__ import annotations

import math
import socket
import struct
import sys
from pathlib import Path

SAMPLE_KEY = bytes(range(32))  #: throwaway key of the sample's authenticated datagrams
LISTENER_OUT_PORT = 50000  #: source port of the listener's outputs in the sample
OTHER_PORT = 49000  #: a non-default listener port (heuristic dissection)
HERE = Path(__file__).resolve().parent


def frame(src_port: int, dst_port: int, payload: bytes, ident: int) -> bytes:
    """An Ethernet II / IPv4 / UDP frame on 127.0.0.1 (lengths and checksums by dpkt)."""
    import dpkt

    lo = socket.inet_aton("127.0.0.1")
    udp = dpkt.udp.UDP(sport=src_port, dport=dst_port, data=payload)
    udp.ulen = 8 + len(payload)
    ip = dpkt.ip.IP(src=lo, dst=lo, p=dpkt.ip.IP_PROTO_UDP, id=ident & 0xFFFF, ttl=64, data=udp)
    ip.len = 20 + udp.ulen
    eth = dpkt.ethernet.Ethernet(
        src=b"\x02\x00\x00\x00\x00\x01",
        dst=b"\x02\x00\x00\x00\x00\x02",
        type=dpkt.ethernet.ETH_TYPE_IP,
        data=ip,
    )
    return bytes(eth)


def sample_records(duration_s: float = 2.0) -> list[tuple[float, int, int, bytes]]:
    """``(time [s], source port, destination port, payload)`` of the sample, in capture order."""
    import numpy as np

    from interface_modules.offline import generate
    from listener.auth import wrap
    from listener.codec import (
        GpsFix,
        ImuSample,
        OutputExtended,
        OutputMessage,
        Stop,
        Strobe,
        encode_ack,
        encode_input,
        encode_output,
        encode_output_extended,
    )
    from listener.defaults import DEFAULT_LISTENER_PORT, DEFAULT_OBCU_PORT

    run = generate("tram-urban", seed=1, max_duration_s=duration_s)
    recs = [(p.arrival_s, p.src_port, DEFAULT_LISTENER_PORT, p.payload) for p in run.packets]
    t0 = run.packets[0].arrival_s
    tr = run.truth
    offset = t0 - float(tr["epoch"][0])  # capture clock - sensor-set clock
    for k in range(1, int(duration_s * 10)):
        e = float(tr["epoch"][0]) + 0.1 * k
        s = float(np.interp(e, tr["epoch"], tr["arc_length"]))
        v = float(np.interp(e, tr["epoch"], tr["speed"]))
        line = int(tr["line_id"][0])
        if e - float(tr["epoch"][0]) < 1.0:
            payload = encode_output(OutputMessage(k, e, s))
        else:
            payload = encode_output_extended(OutputExtended(k, e, s, v, s - 2.5, s + 2.5, 1, line))
        recs.append((e + offset + 0.004, LISTENER_OUT_PORT, DEFAULT_OBCU_PORT, payload))
        if k % 10 == 9:
            recs.append((e + offset + 0.005, DEFAULT_OBCU_PORT, LISTENER_OUT_PORT, encode_ack(k)))
    t_end = max(r[0] for r in recs)
    strobe = encode_input(Strobe(200, float(tr["epoch"][-1])))
    imu = encode_input(ImuSample(201, 0.1, -0.05, -9.81, 0.001, -0.002, 0.0125, float(tr["epoch"][-1])))
    extra = [
        (47000, DEFAULT_LISTENER_PORT, wrap(strobe, SAMPLE_KEY, 7, key_id=0)),
        (47001, DEFAULT_LISTENER_PORT, wrap(imu, SAMPLE_KEY, 7, key_id=1, tag_bytes=32)),
        (
            LISTENER_OUT_PORT,
            DEFAULT_OBCU_PORT,
            wrap(encode_output(OutputMessage(300, 1.7e9, 42.0)), SAMPLE_KEY, 3),
        ),
        (DEFAULT_OBCU_PORT, LISTENER_OUT_PORT, wrap(encode_ack(300), SAMPLE_KEY, 3)),
        (40000, OTHER_PORT, encode_input(Stop(5))),
        (47001, DEFAULT_LISTENER_PORT, imu[:-8]),  # header says 7 doubles, 6 follow
        (47000, DEFAULT_LISTENER_PORT, b"\x07\x01\x00\x00\x00"),  # SENSOR_TYPE 7 does not exist
        # well-formed but rejected by the codec's value checks (encoded without them, as the fault tools do)
        (47003, DEFAULT_LISTENER_PORT, encode_input(GpsFix(9, 95.0, 11.6, 160.0, 1, 8, 2.5), validate=False)),
        (47003, DEFAULT_LISTENER_PORT, encode_input(GpsFix(10, 50.9, 11.6, 160.0, 9, 8), validate=False)),
        (
            47001,
            DEFAULT_LISTENER_PORT,
            encode_input(ImuSample(202, math.nan, 0, -9.81, 0, 0, 0), validate=False),
        ),
        (
            LISTENER_OUT_PORT,
            DEFAULT_OBCU_PORT,
            struct.pack("<HdddddBi", 302, 1.7e9, 50.0, 1.0, 51.0, 52.0, 1, 2),
        ),
        (LISTENER_OUT_PORT, DEFAULT_OBCU_PORT, encode_output(OutputMessage(301, 1.7e9, 43.0)) + b"\x00\x00"),
    ]
    recs += [(t_end + 0.01 * (i + 1), sp, dp, data) for i, (sp, dp, data) in enumerate(extra)]
    recs.sort(key=lambda r: r[0])
    return recs


def write_sample(path: str | Path) -> int:
    """Write the sample capture (classic pcap, microseconds); return the number of frames."""
    import dpkt

    recs = sample_records()
    with open(path, "wb") as fh:
        writer = dpkt.pcap.Writer(fh, snaplen=65535, linktype=dpkt.pcap.DLT_EN10MB)
        for i, (t, sp, dp, data) in enumerate(recs):
            writer.writepkt(frame(sp, dp, data, i), ts=t)
    return len(recs)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    out = Path(args[0]) if args else HERE / "sample.pcap"
    n = write_sample(out)
    print(f"{out}: {n} frames")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
