"""The compiled front end of the fast replay: capture records, INPUT decoding and packing in one pass.

:func:`scan_records` walks the records of a memory-mapped capture as the dpkt reader of the exact
replay (:mod:`tools.capture_reader`) interprets them, for the forms described in
:mod:`tools.fast_pcap` (classic pcap in either byte order with micro- or nanosecond timestamps,
pcapng, Ethernet with up to two VLAN tags, IPv4 and IPv6, UDP); :func:`decode_many` decodes
INPUT_PROTOCOL payloads against listener.codec's tables (:mod:`tools.fast_decode` builds them). Both are
wrapped by those two modules for their callers and tests. :func:`ingest` is the fast replay's single
pass over the file: the same record walk and the same per-datagram decoding (one function,
``_decode_one``, shared with :func:`decode_many`), and in the same loop everything the replay needs
from each datagram, written straight into its final arrays:

- per datagram (up to and including the first valid STOP, where the replay ends): the payload offset
  and length, the IP header offset and version, the arrival time, and the SENSOR_TYPE of a valid
  datagram (-1 when the codec would reject it),
- the stream table (first datagram of every sender/type, a SEQ that does not continue its stream, more
  streams than the listener tracks), and the measurements without an epoch, per type,
- the measurements (IMU, odometer, GPS, GROUND TRUTH) in ``sfa.batch.Packed`` layout (kind, epoch,
  7 values, as :func:`tools.fast_pack.pack_rows` packs them) with their datagram index and arrival,
- the GNSS rows (datagram, measurement index, arrival, lat, lon, fix quality) and the STROBEs
  (datagram, timestamp, arrival),
- valid datagrams per SENSOR_TYPE.

The file is read once (76 MB for the one-hour regional capture), float64 fields with one unaligned
load each (the fast replay runs only on little-endian hosts), and nothing is allocated in the loop.

Everything here is self-contained (no compiled function of another module is called and no other
module's constants are read at compile time): numba's disk cache is invalidated by this file alone.
"""

from __future__ import annotations

import math
import socket
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from llvmlite import ir
from numba import njit
from numba.core import types
from numba.extending import intrinsic

GLOBAL_HEADER_BYTES = 24  #: classic pcap file header
RECORD_HEADER_BYTES = 16  #: classic pcap record header
EPB_HEADER_BYTES = 28  #: pcapng Enhanced (and obsolete) Packet Block, up to the packet data
ETH_HEADER_BYTES = 14
DLT_EN10MB = 1
#: classic pcap magic bytes as the file holds them -> (big-endian, nanosecond) as dpkt.pcap.Reader reads them
#: (the "modified" pcap forms with a longer record header are left to the exact reader)
CLASSIC_MAGICS = {
    b"\xd4\xc3\xb2\xa1": (False, False),
    b"\x4d\x3c\xb2\xa1": (False, True),
    b"\xa1\xb2\xc3\xd4": (True, False),
    b"\xa1\xb2\x3c\x4d": (True, True),
}
PCAPNG_SHB = 0x0A0D0D0A
PCAPNG_EPB = 6
PCAPNG_PB = 2  #: the obsolete Packet Block (dpkt reads it like an EPB)
PCAPNG_OPT_COMMENT = 1
ETH_TYPE_IP = 0x0800
ETH_TYPE_IP6 = 0x86DD
ETH_TYPE_8021Q = 0x8100
#: dpkt.ethernet's _ETH_TYPES_QINQ: a first VLAN tag (802.1Q, 802.1ad, legacy QinQ); a second follows 802.1Q
ETH_TYPES_VLAN = (0x8100, 0x88A8, 0x9100, 0x9200)

# slots of the format descriptor (``fmt``, int64) and its float part (``ffmt``)
FMT_PCAPNG = 0  #: 1: pcapng blocks, 0: classic pcap records
FMT_BIG = 1  #: 1: the file's headers are big-endian
FMT_NANO = 2  #: classic pcap with nanosecond timestamps (dpkt: sec + Decimal(nsec) / Decimal("1E9"))
FMT_START = 3  #: file offset of the first record (block)
NFMT = 4
FF_DIVISOR = 0  #: pcapng: the first interface's timestamp resolution, as dpkt's float divisor
FF_OFFSET = 1  #: pcapng: its timestamp offset [s] (float of dpkt's int if_tsoffset)
NFFMT = 2

# per-frame codes of the record walk
F_DATAGRAM = 0
F_OTHER_PORT = 1
F_NOT_UDP = 2
F_IP_FRAGMENT = 3
F_UDP_LENGTH_MISMATCH = 4
F_NO_FRAME = 5  #: a pcapng block that is not a packet (skipped by dpkt, not a frame)
F_NOT_IP = 6  #: an Ethernet frame dpkt reads as carrying no IP packet (ARP, LLDP, ...)

# the Ethernet type table (``ethk``, uint8 (2, 65536): row 0 the frame's own type, row 1 the type after
# its VLAN tags) as dpkt.ethernet reads them
E_REFUSE = 0  #: a form whose dpkt reading the walk does not follow (802.3/LLC, MPLS, a parsed non-IP type)
E_NOT_IP = 1  #: no IP packet: dpkt keeps the payload as bytes (a type it does not parse) or ARP
E_IP4 = 2
E_IP6 = 3
E_VLAN = 4  #: a VLAN tag follows (row 0 only)

# why the walk gave up (the exact reader takes over)
U_OK = 0
U_TRUNCATED = 1
U_NOT_ETHERNET_IPV4 = 2
U_IP_HEADER = 3
U_IP_LENGTH = 4
U_UDP_HEADER = 5
U_BLOCK = 6
U_TIMESTAMP = 7
UNSUPPORTED_REASONS = {
    U_TRUNCATED: "truncated record",
    U_NOT_ETHERNET_IPV4: "Ethernet frame the fast path does not read (802.3/LLC, MPLS, cut short)",
    U_IP_HEADER: "IP header not plain (IPv4 options or IPv6 extension headers)",
    U_IP_LENGTH: "IP length disagrees with the frame",
    U_UDP_HEADER: "UDP header cut short",
    U_BLOCK: "pcapng block the fast path does not read (a second section, packet options, a comment)",
    U_TIMESTAMP: "timestamp out of the fast path's range",
}

MAX_FIELDS = 9  #: most payload fields of any form (GPS: 2 ints + 5 doubles; IMU: 7 doubles)
NV = 7  #: values per packed measurement (sfa.batch.NV; checked by tests/test_fast_replay.py)

# slots of ingest's scalar results (``res``)
R_STATUS = 0  #: U_* of the record walk
R_FRAMES = 1  #: records walked
R_DATAGRAMS = 2  #: UDP datagrams to the port in the whole file
R_ROWS = 3  #: datagrams the replay reads: up to and including the first valid STOP (else all)
R_STOPPED = 4  #: 1 when a valid STOP ended the rows
R_STOP_FRAME = 5  #: record number of that STOP
R_SKIPPED = 6  #: skipped frames (all of the file), in ``skip``
R_MEAS = 7  #: measurements packed
R_GPS = 8  #: GNSS rows
R_STROBES = 9  #: STROBE rows
R_STREAMS = 10  #: streams seen (-1: more than the listener tracks)
R_LAST_FIRST = 11  #: datagram index of the last stream's first datagram (-1: none)
R_LAST_BREAK = 12  #: last datagram whose SEQ does not continue its stream by one (-1: none)
R_BAD = 13  #: datagrams the codec rejects
R_TYPES = 16  #: 16 slots: valid datagrams per SENSOR_TYPE
NRES = 32


@intrinsic
def _load_f64(typingctx, arr, pos):
    """The float64 stored little-endian at byte ``pos`` of a uint8 array (one unaligned load, no bounds
    check: callers read inside a payload whose length they have checked)."""
    sig = types.float64(arr, types.intp)

    def codegen(context, builder, signature, args):
        ary = context.make_array(signature.args[0])(context, builder, args[0])
        ptr = builder.gep(ary.data, [args[1]])
        return builder.load(builder.bitcast(ptr, ir.DoubleType().as_pointer()), align=1)

    return sig, codegen


@njit(cache=True, _nrt=False)
def _u16be(d, i):
    return (np.int64(d[i]) << 8) | np.int64(d[i + 1])


@njit(cache=True, _nrt=False)
def _u32le(d, i):
    return (
        np.int64(d[i]) | (np.int64(d[i + 1]) << 8) | (np.int64(d[i + 2]) << 16) | (np.int64(d[i + 3]) << 24)
    )


@njit(cache=True, _nrt=False)
def _u32be(d, i):
    return (
        (np.int64(d[i]) << 24) | (np.int64(d[i + 1]) << 16) | (np.int64(d[i + 2]) << 8) | np.int64(d[i + 3])
    )


@njit(cache=True, _nrt=False)
def _u32(d, i, big):
    return _u32be(d, i) if big else _u32le(d, i)


@njit(cache=True, _nrt=False)
def _u16(d, i, big):
    if big:
        return _u16be(d, i)
    return np.int64(d[i]) | (np.int64(d[i + 1]) << 8)


@njit(cache=True, _nrt=False)
def _u64be(d, i):
    """The 8 bytes at i as one int64 (big-endian, wrapping): a key, not a number."""
    return (_u32be(d, i) << 32) | _u32be(d, i + 4)


@njit(cache=True, _nrt=False)
def _i32le(d, i):
    u = _u32le(d, i)
    if u >= 2147483648:
        u -= 4294967296
    return u


_E9 = 1_000_000_000


@njit(cache=True, _nrt=False)
def nano_timestamp(sec, nsec):
    """dpkt's nanosecond timestamp as the exact replay takes it, ``float(sec + Decimal(nsec) /
    Decimal("1E9"))``: the double nearest to the exact decimal sec.nnnnnnnnn (28-digit Decimal
    arithmetic is exact on these 10 + 10 digits), ties to even. With q, r = divmod(sec * 1e9 + nsec,
    1e9), q in [2^k, 2^(k+1)): the double is q + j * 2^-s (s = 52 - k), j = r * 2^s / 1e9 rounded to even
    in integer arithmetic. NaN for q = 0 (the caller refuses it)."""
    total = sec * _E9 + nsec  # < 2^63 (sec, nsec < 2^32)
    q = total // _E9
    r = total - q * _E9
    if q == 0:
        return np.nan
    k = 0
    while (q >> (k + 1)) != 0:
        k += 1
    s = 52 - k
    j = np.int64(0)
    rem = r
    left = s
    while left > 0:  # long division of r * 2^s by 1e9, 32 bits at a time (rem < 2^30: no overflow)
        t = 32 if left > 32 else left
        rem = rem << t
        j = (j << t) + rem // _E9
        rem = rem % _E9
        left -= t
    if 2 * rem > _E9 or (2 * rem == _E9 and (j & 1) == 1):
        j += 1
    return np.float64(q) + math.ldexp(np.float64(j), -s)


@njit(cache=True, _nrt=False)
def _frame(d, body, flen, port, ethk, ext6):
    """The Ethernet frame d[body:body + flen] as dpkt reads it: (status U_*, frame code F_*, payload offset,
    payload length, IP header offset, IP version). ``ethk``: the Ethernet type table (E_*),
    ``ext6``: dpkt.ip6's extension header numbers."""
    if flen < ETH_HEADER_BYTES:
        return U_NOT_ETHERNET_IPV4, 0, 0, 0, 0, 0
    et = _u16be(d, body + 12)
    off = ETH_HEADER_BYTES
    kind = ethk[0, et]
    if et == 0:  # dpkt: "unknown type, assume Ethernet" (no IP packet) unless Cisco ISL or Novell raw 802.3
        isl = (d[body] == 0x01 or d[body] == 0x03) and d[body + 1] == 0 and d[body + 2] == 0x0C
        isl = isl and d[body + 3] == 0 and d[body + 4] == 0
        ipx = flen >= ETH_HEADER_BYTES + 2 and d[body + 14] == 0xFF and d[body + 15] == 0xFF
        kind = E_REFUSE if isl or ipx else E_NOT_IP
    if kind == E_VLAN:  # dpkt: up to two tags (a second one after 802.1Q)
        if flen < off + 4:
            return U_NOT_ETHERNET_IPV4, 0, 0, 0, 0, 0
        et = _u16be(d, body + off + 2)
        off += 4
        if et == ETH_TYPE_8021Q:
            if flen < off + 4:
                return U_NOT_ETHERNET_IPV4, 0, 0, 0, 0, 0
            et = _u16be(d, body + off + 2)
            off += 4
        kind = ethk[1, et]
    if kind == E_NOT_IP:
        return U_OK, F_NOT_IP, 0, 0, 0, 0
    ip = body + off
    avail = flen - off
    if kind == E_IP4:
        if avail < 20:
            return U_NOT_ETHERNET_IPV4, 0, 0, 0, 0, 0
        vhl = d[ip]
        if (vhl >> 4) != 4 or (vhl & 0xF) != 5:
            return U_IP_HEADER, 0, 0, 0, 0, 0
        ip_len = _u16be(d, ip + 2)
        if ip_len < 20 or ip_len > avail:
            return U_IP_LENGTH, 0, 0, 0, 0, 0
        flags_off = _u16be(d, ip + 6)
        if (flags_off & 0x2000) != 0 or (flags_off & 0x1FFF) != 0:
            return U_OK, F_IP_FRAGMENT, 0, 0, 0, 0
        if d[ip + 9] != 17:
            return U_OK, F_NOT_UDP, 0, 0, 0, 0
        udp = ip + 20
        udp_bytes = ip_len - 20
        version = 4
    elif kind == E_IP6:
        if avail < 40:
            return U_NOT_ETHERNET_IPV4, 0, 0, 0, 0, 0
        plen6 = _u16be(d, ip + 4)
        if plen6 == 0 or plen6 > avail - 40:  # (0: a jumbo payload; dpkt would take the whole frame)
            return U_IP_LENGTH, 0, 0, 0, 0, 0
        nxt = d[ip + 6]
        if ext6[nxt]:
            return U_IP_HEADER, 0, 0, 0, 0, 0
        if nxt != 17:
            return U_OK, F_NOT_UDP, 0, 0, 0, 0
        udp = ip + 40
        udp_bytes = plen6
        version = 6
    else:
        return U_NOT_ETHERNET_IPV4, 0, 0, 0, 0, 0
    if udp_bytes < 8:
        return U_UDP_HEADER, 0, 0, 0, 0, 0
    if _u16be(d, udp + 2) != port:
        return U_OK, F_OTHER_PORT, 0, 0, 0, 0
    ulen = _u16be(d, udp + 4)
    plen = udp_bytes - 8
    if ulen != 0 and ulen - 8 != plen:
        return U_OK, F_UDP_LENGTH_MISMATCH, 0, 0, 0, 0
    return U_OK, F_DATAGRAM, udp + 8, plen, ip, version


@njit(cache=True, _nrt=False)
def _record(d, pos, port, fmt, ffmt, ethk, ext6):
    """One record (classic pcap) or block (pcapng) at ``pos``: (status U_*, next pos, frame code F_*,
    payload offset, payload length, IP header offset, IP version, arrival).

    The checks and their order are those of the dpkt-compatible walk described in tools.fast_pcap;
    anything dpkt would read otherwise than plainly (a record or block cut short, packet options, a
    second pcapng section) stops the walk with its status."""
    n = d.shape[0]
    big = fmt[FMT_BIG] != 0
    if fmt[FMT_PCAPNG] == 0:
        if pos + RECORD_HEADER_BYTES > n:
            return U_TRUNCATED, pos, 0, 0, 0, 0, 0, 0.0
        incl = _u32(d, pos + 8, big)
        orig = _u32(d, pos + 12, big)
        body = pos + RECORD_HEADER_BYTES
        if body + incl > n or incl != orig:
            return U_TRUNCATED, pos, 0, 0, 0, 0, 0, 0.0
        nxt = body + incl
        sec = _u32(d, pos, big)
        frac = _u32(d, pos + 4, big)
        if fmt[FMT_NANO] != 0:
            arrival = nano_timestamp(sec, frac)
            if not (arrival == arrival):
                return U_TIMESTAMP, pos, 0, 0, 0, 0, 0, 0.0
        else:
            arrival = np.float64(sec) + np.float64(frac) / 1e6  # as dpkt: sec + usec / 1E6
    else:
        if pos + 8 > n:
            return U_TRUNCATED, pos, 0, 0, 0, 0, 0, 0.0
        btype = _u32(d, pos, big)
        blen = _u32(d, pos + 4, big)
        if blen < 12 or (blen & 3) != 0 or pos + blen > n:
            return U_TRUNCATED, pos, 0, 0, 0, 0, 0, 0.0
        if _u32(d, pos + blen - 4, big) != blen or btype == PCAPNG_SHB:
            return U_BLOCK, pos, 0, 0, 0, 0, 0, 0.0
        nxt = pos + blen
        if btype != PCAPNG_EPB and btype != PCAPNG_PB:
            return U_OK, nxt, F_NO_FRAME, 0, 0, 0, 0, 0.0
        if blen < EPB_HEADER_BYTES + 4:
            return U_BLOCK, pos, 0, 0, 0, 0, 0, 0.0
        incl = _u32(d, pos + 20, big)
        orig = _u32(d, pos + 24, big)
        padded = (incl + 3) & ~3
        if EPB_HEADER_BYTES + padded + 4 > blen or incl != orig:
            return U_TRUNCATED, pos, 0, 0, 0, 0, 0, 0.0
        o = pos + EPB_HEADER_BYTES + padded  # options: read as dpkt does, only plain ones accepted
        end = nxt - 4
        while o < end:
            if o + 4 > end:
                return U_BLOCK, pos, 0, 0, 0, 0, 0, 0.0
            code = _u16(d, o, big)
            size = 4 + ((_u16(d, o + 2, big) + 3) & ~3)
            if code == PCAPNG_OPT_COMMENT or o + size > end:
                return U_BLOCK, pos, 0, 0, 0, 0, 0, 0.0
            o += size
            if code == 0:
                break
        hi = _u32(d, pos + 12, big)
        if hi >= 2147483648:
            return U_TIMESTAMP, pos, 0, 0, 0, 0, 0, 0.0
        # as dpkt: tsoffset + (((ts_high << 32) | ts_low) / divisor), the int converted to float first
        arrival = ffmt[FF_OFFSET] + np.float64((hi << 32) | _u32(d, pos + 16, big)) / ffmt[FF_DIVISOR]
        body = pos + EPB_HEADER_BYTES
    status, code, o, plen, ip, version = _frame(d, body, incl, port, ethk, ext6)
    return status, nxt, code, o, plen, ip, version, arrival


@njit(cache=True, _nrt=False)
def _next_datagram(d, pos, port, fmt, ffmt, ethk, ext6, skip, frames, s):
    """Walk the records from ``pos`` to the next datagram to ``port``, noting the skipped frames in
    ``skip`` (record number, F_*). ``frames``: records walked so far, ``s``: skipped frames so far.

    Returns (status U_*, position after the datagram's record, frames, s, payload offset, payload
    length, IP header offset, IP version, arrival); the payload offset is -1 when the walk ends: at the
    end of the file (status U_OK) or at a record the fast path does not read (its status)."""
    n = d.shape[0]
    while pos < n:
        status, nxt, code, o, plen, ip, version, arrival = _record(d, pos, port, fmt, ffmt, ethk, ext6)
        if status != U_OK and nxt == pos:  # the record itself is not read
            return status, pos, frames, s, -1, 0, 0, 0, 0.0
        pos = nxt
        if code == F_NO_FRAME:
            continue
        frames += 1
        if status != U_OK:
            return status, pos, frames, s, -1, 0, 0, 0, 0.0
        if code != F_DATAGRAM:
            skip[s, 0] = frames
            skip[s, 1] = code
            s += 1
            continue
        return U_OK, pos, frames, s, o, plen, ip, version, arrival
    return U_OK, pos, frames, s, -1, 0, 0, 0, 0.0


@njit(cache=True, _nrt=False)
def scan_records(
    d, port, fmt, ffmt, ethk, ext6, out_t, out_ip, out_ver, out_off, out_len, out_frame, skip, res
):  # fmt: skip
    """Every record: datagrams to ``port`` into out_* (arrival, IP header offset and version, payload
    offset and length, 1-based record number), skipped frames into ``skip`` (record number, F_*).
    ``res``: (status U_*, records, datagrams, skipped)."""
    pos = fmt[FMT_START]
    frames = 0
    k = 0
    s = 0
    while True:
        status, pos, frames, s, o, plen, ip, version, arrival = _next_datagram(
            d, pos, port, fmt, ffmt, ethk, ext6, skip, frames, s
        )
        if o < 0:
            break
        out_t[k] = arrival
        out_ip[k] = ip
        out_ver[k] = version
        out_off[k] = o
        out_len[k] = plen
        out_frame[k] = frames
        k += 1
    res[0] = status
    res[1] = frames
    res[2] = k
    res[3] = s


@njit(cache=True, _nrt=False)
def _decode_one(d, o, n, form_size, lo, hi, w):
    """Decode the payload d[o:o+n] into ``w`` (ints then doubles in wire order, NaN beyond the form).

    Returns (valid, SENSOR_TYPE, SEQ, N_INT, N_DOUBLE); -1 for the header fields of a payload shorter than
    the header. Valid: a known form of exactly this length with every field inside its range
    lo <= x <= hi (lo inclusive: tools.fast_decode moves open bounds up one double; NaN and infinities
    fail the comparison, as in the codec's chained comparisons)."""
    for j in range(MAX_FIELDS):
        w[j] = np.nan
    if n < 5:
        return False, -1, -1, -1, -1
    t = np.int64(d[o])
    ni = np.int64(d[o + 3])
    nd = np.int64(d[o + 4])
    seq = np.int64(d[o + 1]) | (np.int64(d[o + 2]) << 8)
    if t >= 16 or ni >= 8 or nd >= 8:
        return False, t, seq, ni, nd
    idx = t * 64 + ni * 8 + nd
    if form_size[idx] == 0 or form_size[idx] != n:
        return False, t, seq, ni, nd
    p = o + 5
    for j in range(ni + nd):
        if j < ni:
            x = np.float64(_i32le(d, p))
            p += 4
        else:
            x = _load_f64(d, p)
            p += 8
        w[j] = x
        if not (lo[idx, j] <= x and x <= hi[idx, j]):
            return False, t, seq, ni, nd
    return True, t, seq, ni, nd


@njit(cache=True, _nrt=False)
def decode_many(d, offset, length, form_size, lo, hi, ok, stype, seq, n_int, n_double, values):
    """Decode every datagram d[offset[k]:offset[k]+length[k]] (little-endian, the protocol's order)."""
    for k in range(offset.shape[0]):
        good, t, sq, ni, nd = _decode_one(d, offset[k], length[k], form_size, lo, hi, values[k])
        ok[k] = good
        stype[k] = t
        seq[k] = sq
        n_int[k] = ni
        n_double[k] = nd


@njit(cache=True, _nrt=False)
def ingest(
    d,
    port,
    fmt,
    ffmt,
    ethk,
    ext6,
    per_type,
    max_streams,
    form_size,
    lo,
    hi,
    row_off,
    row_len,
    row_ip,
    row_ver,
    row_t,
    row_code,
    m_row,
    m_time,
    kind,
    t_s,
    vals,
    g_row,
    g_meas,
    g_time,
    g_lat,
    g_lon,
    g_fq,
    s_row,
    s_ts,
    s_time,
    skip,
    st_key,
    st_last,
    w,
    res,
):
    """The fast replay's pass over the mapped capture ``d`` (see the module docstring; ``fmt``, ``ffmt``,
    ``ext6`` as :func:`scan_records`).

    Output arrays are sized by the caller for the most records the file can hold; ``st_key`` (3 keys
    per stream) / ``st_last`` hold ``max_streams`` streams, ``w`` is a MAX_FIELDS scratch row; ``res``
    (NRES int64) receives the counts and flags (slots R_*)."""
    for q in range(NRES):
        res[q] = 0
    res[R_LAST_FIRST] = -1
    res[R_LAST_BREAK] = -1
    pos = fmt[FMT_START]
    frames = 0
    k = 0  # datagrams to the port
    s = 0  # skipped frames
    r = 0  # rows (datagrams up to the first valid STOP)
    nm = 0
    ng = 0
    ns = 0
    m = 0  # streams
    overflow = False
    q_hint = 0
    stopped = False
    while True:
        status, pos, frames, s, o, plen, ip, version, arrival = _next_datagram(
            d, pos, port, fmt, ffmt, ethk, ext6, skip, frames, s
        )
        if o < 0:
            break
        k += 1
        if stopped:  # the replay ended at the STOP; the rest of the file is only walked (for errors)
            continue
        good, t, sq, ni, nd = _decode_one(d, o, plen, form_size, lo, hi, w)
        row_off[r] = o
        row_len[r] = plen
        row_ip[r] = ip
        row_ver[r] = version
        row_t[r] = arrival
        if not good:
            row_code[r] = -1
            res[R_BAD] += 1
            r += 1
            continue
        row_code[r] = t
        res[R_TYPES + t] += 1
        # the stream table (listener.seqbuf's key: sender address and port, and the type if per type)
        if not overflow:
            if version == 4:
                k0 = np.int64(0)
                k1 = _u32be(d, ip + 12)
            else:
                k0 = _u64be(d, ip + 8)
                k1 = _u64be(d, ip + 16)
            k2 = (np.int64(version) << 32) | (_u16be(d, o - 8) << 8) | ((t & 0xFF) if per_type else 0)
            q = -1
            if q_hint < m and st_key[q_hint, 2] == k2 and st_key[q_hint, 1] == k1 and st_key[q_hint, 0] == k0:
                q = q_hint
            else:
                for p in range(m):
                    if st_key[p, 2] == k2 and st_key[p, 1] == k1 and st_key[p, 0] == k0:
                        q = p
                        break
            if q < 0:
                if m == max_streams:
                    overflow = True
                else:
                    st_key[m, 0] = k0
                    st_key[m, 1] = k1
                    st_key[m, 2] = k2
                    st_last[m] = sq
                    res[R_LAST_FIRST] = r
                    q_hint = m
                    m += 1
            else:
                if sq != (st_last[q] + 1) & 0xFFFF:
                    res[R_LAST_BREAK] = r
                st_last[q] = sq
                q_hint = q
        if t == 1 or t == 2 or t == 3 or t == 8:
            j = nm
            m_row[j] = r
            m_time[j] = arrival
            kind[j] = t
            v = vals[j]
            for q in range(NV):
                v[q] = np.nan
            # as tools.fast_pack._pack (values beyond the form are NaN in w: t_s is NaN without epoch)
            if t == 1:
                for q in range(6):
                    v[q] = w[q]
                t_s[j] = w[6]
            elif t == 2:
                v[0] = w[0]
                v[1] = w[1]
                t_s[j] = w[2]
            elif t == 3:
                b = 2 if ni == 2 else 0
                t_s[j] = w[b + 4]
                v[0] = 0.0
                v[1] = 0.0
                v[2] = w[b + 3]
                v[3] = w[0] if b == 2 else -1.0
                g_row[ng] = r
                g_meas[ng] = j
                g_time[ng] = arrival
                g_lat[ng] = w[b]
                g_lon[ng] = w[b + 1]
                g_fq[ng] = v[3]
                ng += 1
            else:  # GROUND TRUTH: the epoch only (initialisations go through TrackFilter)
                t_s[j] = w[ni + 4]
            nm += 1
        elif t == 9:
            s_row[ns] = r
            s_ts[ns] = w[0]
            s_time[ns] = arrival
            ns += 1
        r += 1
        if t == 10:
            stopped = True
            res[R_STOPPED] = 1
            res[R_STOP_FRAME] = frames
    res[R_STATUS] = status
    res[R_FRAMES] = frames
    res[R_DATAGRAMS] = k
    res[R_ROWS] = r
    res[R_SKIPPED] = s
    res[R_MEAS] = nm
    res[R_GPS] = ng
    res[R_STROBES] = ns
    res[R_STREAMS] = -1 if overflow else m


# ---------------------------------------------------------------------------------------- Python side
@dataclass(frozen=True)
class MappedCapture:
    """A capture file memory-mapped, with how dpkt reads it (the walk's format descriptor)."""

    data: np.ndarray  #: the whole file (uint8)
    fmt: np.ndarray  #: int64 slots FMT_*
    ffmt: np.ndarray  #: float64 slots FF_*
    ethk: np.ndarray  #: uint8 (2, 65536): the Ethernet type table (E_*)
    ext6: np.ndarray  #: bool (256,): dpkt.ip6's extension header numbers

    @property
    def args(self) -> tuple:
        return self.fmt, self.ffmt, self.ethk, self.ext6


def _ethernet_table() -> np.ndarray:
    """How dpkt.ethernet reads each Ethernet type (E_*): row 0 a frame's own type, row 1 the type after
    its VLAN tags. A type above 1500 that dpkt does not parse leaves the payload as bytes (no IP
    packet: skipped as not_ip by the exact reader); ARP is parsed into an ARP packet or, cut short, left
    as bytes, never an error; the other types dpkt parses, 802.3 lengths (1500 and below: LLC, ISL,
    raw 802.3) and MPLS label stacks are left to the exact reader."""
    import dpkt

    eth = dpkt.ethernet
    parsed = set(eth.Ethernet._typesw)
    inner = np.full(65536, E_NOT_IP, dtype=np.uint8)
    inner[sorted(parsed)] = E_REFUSE
    inner[eth.ETH_TYPE_ARP] = E_NOT_IP
    inner[0] = E_REFUSE  # (dpkt then falls back to the outer type)
    inner[eth.ETH_TYPE_IP] = E_IP4
    inner[eth.ETH_TYPE_IP6] = E_IP6
    outer = inner.copy()
    outer[: 1500 + 1] = E_REFUSE
    outer[[eth.ETH_TYPE_MPLS, eth.ETH_TYPE_MPLS_MCAST]] = E_REFUSE
    outer[sorted(eth._ETH_TYPES_QINQ)] = E_VLAN
    return np.stack((outer, inner))


def _ext6_table() -> np.ndarray:
    import dpkt

    table = np.zeros(256, dtype=np.bool_)
    table[list(dpkt.ip6.EXT_HDRS)] = True
    return table


def _pcapng_format(path: Path):
    """(big-endian, divisor, tsoffset, link type, offset of the first block after the first IDB) as
    dpkt.pcapng.Reader sets them up (it is run on the file for that), or a reason string."""
    import dpkt

    try:
        with open(path, "rb") as fh:
            reader = dpkt.pcapng.Reader(fh)
            start = fh.tell()
    except (ValueError, OSError, dpkt.dpkt.NeedData, dpkt.dpkt.UnpackError) as exc:
        return f"pcapng header not read: {exc}"
    # dpkt's reader attributes for what it applies to every packet (no public accessor in dpkt)
    big = not reader._Reader__le
    return big, float(reader._divisor), int(reader._tsoffset), int(reader.datalink()), start


def map_capture(path):
    """The file memory-mapped (uint8) with its format, as dpkt reads it: a :class:`MappedCapture`, or why
    the fast path cannot read it (the reasons of :func:`tools.fast_pcap.scan_capture`)."""
    p = Path(path)
    try:
        size = p.stat().st_size
    except OSError as exc:
        return f"cannot stat: {exc.strerror or exc}"
    try:
        with open(p, "rb") as fh:
            head = fh.read(GLOBAL_HEADER_BYTES)
    except OSError as exc:
        return f"cannot map: {exc.strerror or exc}"
    fmt = np.zeros(NFMT, dtype=np.int64)
    ffmt = np.zeros(NFFMT)
    form = CLASSIC_MAGICS.get(head[:4])
    if form is not None and len(head) == GLOBAL_HEADER_BYTES:
        big, nano = form
        linktype = int.from_bytes(head[20:24], "big" if big else "little")
        fmt[FMT_BIG], fmt[FMT_NANO], fmt[FMT_START] = big, nano, GLOBAL_HEADER_BYTES
    elif int.from_bytes(head[:4], "little") == PCAPNG_SHB:
        got = _pcapng_format(p)
        if isinstance(got, str):
            return got
        big, divisor, tsoffset, linktype, start = got
        if not (0.0 < divisor < float("inf")) or abs(tsoffset) >= 2**53:
            return f"pcapng timestamp resolution {divisor} or offset {tsoffset} (not read by the fast path)"
        fmt[FMT_PCAPNG], fmt[FMT_BIG], fmt[FMT_START] = 1, big, start
        ffmt[FF_DIVISOR], ffmt[FF_OFFSET] = divisor, float(tsoffset)
    else:
        return "not a classic pcap or pcapng file the fast path reads (modified pcap, or not a capture)"
    if linktype != DLT_EN10MB:
        return f"link type {linktype} (only Ethernet is read by the fast path)"
    try:
        data = np.memmap(p, dtype=np.uint8, mode="r") if size else np.zeros(0, dtype=np.uint8)
    except (OSError, ValueError) as exc:
        return f"cannot map: {exc}"
    return MappedCapture(data, fmt, ffmt, _ethernet_table(), _ext6_table())


def record_capacity(data) -> int:
    """Most records the mapped file can hold (every record is at least 16 + 34 bytes; a pcapng packet
    block 32 + 34)."""
    size = data.shape[0]
    return max(1, size // (RECORD_HEADER_BYTES + ETH_HEADER_BYTES + 20) + 1)


def unique_few(key: np.ndarray, most: int = 32):
    """``np.unique(key, return_index=True, return_inverse=True)`` of an int64 ``key`` with few distinct
    values (a capture's senders): one pass over ``key`` per value instead of a sort; np.unique itself
    beyond ``most`` values."""
    n = key.shape[0]
    inv = np.full(n, -1, dtype=np.int64)
    vals: list[int] = []
    firsts: list[int] = []
    i = 0
    while i < n:
        if len(vals) == most:
            return np.unique(key, return_index=True, return_inverse=True)
        v = key[i]
        inv[i:][key[i:] == v] = len(vals)  # (every earlier row has its value already)
        vals.append(int(v))
        firsts.append(i)
        left = inv[i:] < 0
        j = int(np.argmax(left))
        i = i + j if left[j] else n
    order = np.argsort(np.asarray(vals, dtype=np.int64), kind="stable")
    rank = np.empty(order.size, dtype=np.int64)
    rank[order] = np.arange(order.size)
    return np.asarray(vals, dtype=np.int64)[order], np.asarray(firsts, dtype=np.int64)[order], rank[inv]


def _be_int(d, at: np.ndarray, nbytes: int) -> np.ndarray:
    """The ``nbytes`` bytes at each offset ``at`` of ``d`` as one big-endian int64 (wrapping: a key)."""
    k = np.zeros(at.shape[0], dtype=np.int64)
    for b in range(nbytes):
        k = (k << 8) | d[at + b].astype(np.int64)
    return k


@dataclass(frozen=True)
class Ingested:
    """What :func:`ingest_capture` read: views of length ``rows`` / ``meas`` / ... into its arrays."""

    data: np.ndarray  #: the mapped file (uint8)
    res: np.ndarray  #: scalar results (slots R_*)
    row_off: np.ndarray  #: payload offset per row (rows: datagrams up to the first valid STOP)
    row_len: np.ndarray  #: payload length [bytes]
    row_ip: np.ndarray  #: IP header offset
    row_ver: np.ndarray  #: IP version (4 or 6; int8)
    row_t: np.ndarray  #: arrival [s] (as dpkt computes the record's timestamp)
    row_code: np.ndarray  #: SENSOR_TYPE of a valid row, -1 for one the codec rejects (int8)
    m_row: np.ndarray  #: measurements: row index (int64)
    m_time: np.ndarray  #: arrival [s]
    kind: np.ndarray  #: SENSOR_TYPE (int64; sfa.layout.M_* codes)
    t_s: np.ndarray  #: epoch [s] (NaN when the datagram has none)
    vals: np.ndarray  #: (meas, NV) values as tools.fast_pack.pack_rows (GNSS east/north still (0, 0))
    g_row: np.ndarray  #: GNSS rows: row index
    g_meas: np.ndarray  #: measurement index
    g_time: np.ndarray  #: arrival [s]
    g_lat: np.ndarray
    g_lon: np.ndarray
    g_fq: np.ndarray  #: fix quality, -1.0 without (float64)
    s_row: np.ndarray  #: STROBEs: row index
    s_ts: np.ndarray  #: sensor-set timestamp [s]
    s_time: np.ndarray  #: arrival [s]
    skipped_at: np.ndarray  #: (record number, F_*) of every skipped frame of the file
    #: the last (rows, _pair_keys(rows)): the sender table and the sequence buffers ask for the same rows
    _keys_memo: list = field(default_factory=list, compare=False, repr=False)

    @property
    def rows(self) -> int:
        return int(self.res[R_ROWS])

    def source(self, r: int) -> tuple[str, int]:
        """(host, port) of row r as the exact reader writes it (socket.inet_ntop of the source address)."""
        ip = int(self.row_ip[r])
        if self.row_ver[r] == 4:
            host = socket.inet_ntop(socket.AF_INET, bytes(self.data[ip + 12 : ip + 16]))
        else:
            host = socket.inet_ntop(socket.AF_INET6, bytes(self.data[ip + 8 : ip + 24]))
        o = int(self.row_off[r])
        return host, int(self.data[o - 8]) << 8 | int(self.data[o - 7])

    def source_ids(self, rows: np.ndarray):
        """(index per row into the list, [((host, port), SENSOR_TYPE)] of the distinct pairs) for valid
        ``rows``, vectorised as :meth:`first_sources`."""
        if rows.size == 0:
            return np.zeros(0, dtype=np.int64), []
        _, first, inv = self._pair_keys(rows)
        return inv, [(self.source(int(r)), int(self.row_code[r])) for r in rows[first].tolist()]

    def _pair_keys(self, rows: np.ndarray):
        memo = self._keys_memo
        if memo and memo[0].shape == rows.shape and np.array_equal(memo[0], rows):
            return memo[1]
        got = self._distinct_pairs(rows)
        memo[:] = [rows.copy(), got]
        return got

    def _distinct_pairs(self, rows: np.ndarray):
        """np.unique's (values, first indices, inverse) of the (address, port, SENSOR_TYPE) keys of rows."""
        d = self.data
        ip = self.row_ip[rows]
        v6 = self.row_ver[rows] == 6
        o = self.row_off[rows]
        port_type = (_be_int(d, o - 8, 2) << 8) | self.row_code[rows]
        if not v6.any():  # one int64 key: address, port, type (np.unique on rows is much slower)
            key1 = (_be_int(d, ip + 12, 4) << 24) | port_type
            return unique_few(key1)
        key = np.empty((rows.size, 3), dtype=np.int64)  # the walk's stream key, with the type
        key[:, 0] = np.where(v6, _be_int(d, ip + 8, 8), 0)
        key[:, 1] = np.where(v6, _be_int(d, ip + 16, 8), _be_int(d, ip + 12, 4))
        key[:, 2] = (self.row_ver[rows].astype(np.int64) << 32) | port_type
        u, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
        return u, first, inv.reshape(-1)

    def first_sources(self, start: int) -> list[tuple[int, tuple[str, int], int]]:
        """(row, (host, port), SENSOR_TYPE) of the first valid row of each (source, type) pair from row
        ``start`` on, in row order (for the sender table: listener.senders), vectorised."""
        rows = np.flatnonzero(self.row_code[start:] >= 0) + start
        if rows.size == 0:
            return []
        _, first, _ = self._pair_keys(rows)
        firsts = rows[np.sort(first)].tolist()
        return [(r, self.source(r), int(self.row_code[r])) for r in firsts]

    def datagram(self, r: int):
        """(arrival, (host, port), payload) of row r."""
        o = int(self.row_off[r])
        return float(self.row_t[r]), self.source(r), bytes(self.data[o : o + int(self.row_len[r])])


def ingest_capture(path, port: int, per_type: bool, max_streams: int, tables):
    """Run :func:`ingest` over the capture at ``path``: an :class:`Ingested`, or a reason string when the
    file is not one the fast path reads (as :func:`tools.fast_pcap.scan_capture` words it).

    ``tables``: (form_size, lo, hi) of :mod:`tools.fast_decode`."""
    mapped = map_capture(path)
    if isinstance(mapped, str):
        return mapped
    data = mapped.data
    cap = record_capacity(data)
    # sized for the most records the file can hold; untouched pages of np.empty are never mapped
    row_off = np.empty(cap, dtype=np.int64)
    row_len = np.empty(cap, dtype=np.int64)
    row_ip = np.empty(cap, dtype=np.int64)
    row_ver = np.empty(cap, dtype=np.int8)
    row_t = np.empty(cap)
    row_code = np.empty(cap, dtype=np.int8)
    m_row = np.empty(cap, dtype=np.int64)
    m_time = np.empty(cap)
    kind = np.empty(cap, dtype=np.int64)
    t_s = np.empty(cap)
    vals = np.empty((cap, NV))
    g_row = np.empty(cap, dtype=np.int64)
    g_meas = np.empty(cap, dtype=np.int64)
    g_time = np.empty(cap)
    g_lat = np.empty(cap)
    g_lon = np.empty(cap)
    g_fq = np.empty(cap)
    s_row = np.empty(cap, dtype=np.int64)
    s_ts = np.empty(cap)
    s_time = np.empty(cap)
    skip = np.empty((cap, 2), dtype=np.int64)
    streams = max(int(max_streams), 0)
    st_key = np.empty((max(streams, 1), 3), dtype=np.int64)
    st_last = np.empty(max(streams, 1), dtype=np.int64)
    w = np.empty(MAX_FIELDS)
    res = np.zeros(NRES, dtype=np.int64)
    form_size, lo, hi = tables
    ingest(
        data, int(port), *mapped.args, bool(per_type), streams, form_size, lo, hi,
        row_off, row_len, row_ip, row_ver, row_t, row_code, m_row, m_time, kind, t_s, vals,
        g_row, g_meas, g_time, g_lat, g_lon, g_fq, s_row, s_ts, s_time, skip, st_key, st_last, w, res,
    )  # fmt: skip
    if res[R_STATUS] != U_OK:
        return f"record {int(res[R_FRAMES])}: {UNSUPPORTED_REASONS[int(res[R_STATUS])]}"
    r, nm, ng, ns = (int(res[x]) for x in (R_ROWS, R_MEAS, R_GPS, R_STROBES))
    return Ingested(
        data, res, row_off[:r], row_len[:r], row_ip[:r], row_ver[:r], row_t[:r], row_code[:r],
        m_row[:nm], m_time[:nm], kind[:nm], t_s[:nm], vals[:nm],
        g_row[:ng], g_meas[:ng], g_time[:ng], g_lat[:ng], g_lon[:ng], g_fq[:ng],
        s_row[:ns], s_ts[:ns], s_time[:ns], skip[: int(res[R_SKIPPED])],
    )  # fmt: skip
