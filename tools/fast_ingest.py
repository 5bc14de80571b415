"""The compiled front end of the fast replay: pcap records, INPUT decoding and packing in one pass.

:func:`scan_records` walks the record headers of a memory-mapped classic pcap (the layout
:mod:`tools.fast_pcap` describes: Ethernet, IPv4 without options, UDP); :func:`decode_many` decodes
INPUT_PROTOCOL payloads against listener.codec's tables (:mod:`tools.fast_decode` builds them). Both are
wrapped by those two modules for their callers and tests. :func:`ingest` is the fast replay's single
pass over the file: the same record walk and the same per-datagram decoding (one function,
``_decode_one``, shared with :func:`decode_many`), and in the same loop everything the replay needs
from each datagram, written straight into its final arrays:

- per datagram (up to and including the first valid STOP, where the replay ends): the payload offset
  and the SENSOR_TYPE of a valid datagram (-1 when the codec would reject it),
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

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from llvmlite import ir
from numba import njit
from numba.core import types
from numba.extending import intrinsic

PCAP_MAGIC_US_LE = 0xA1B2C3D4  #: classic pcap, microsecond timestamps, as read little-endian
GLOBAL_HEADER_BYTES = 24
RECORD_HEADER_BYTES = 16
ETH_HEADER_BYTES = 14
#: record header + Ethernet + IPv4 (20) + UDP (8): a payload starts this far after its record header
PAYLOAD_AFTER_RECORD = RECORD_HEADER_BYTES + ETH_HEADER_BYTES + 20 + 8
DLT_EN10MB = 1

# per-frame codes of the record walk
F_DATAGRAM = 0
F_OTHER_PORT = 1
F_NOT_UDP = 2
F_IP_FRAGMENT = 3
F_UDP_LENGTH_MISMATCH = 4

# why the walk gave up (the exact reader takes over)
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
R_NO_EPOCH = 32  #: 16 slots: per SENSOR_TYPE, the last measurement datagram without its epoch (-1: none)
NRES = 48

#: N_DOUBLE of a measurement with its epoch, per SENSOR_TYPE (IMU, odometer, GPS, GROUND TRUTH)
EPOCH_DOUBLES_BY_TYPE = np.array([0, 7, 3, 5, 0, 0, 0, 0, 5, 0, 0, 0, 0, 0, 0, 0], dtype=np.int64)


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
def _i32le(d, i):
    u = _u32le(d, i)
    if u >= 2147483648:
        u -= 4294967296
    return u


@njit(cache=True, _nrt=False)
def _record(d, pos, port):
    """One record at ``pos``: (status U_*, next pos, frame code F_*, payload offset, payload length).

    The checks and their order are those of the dpkt-compatible walk described in tools.fast_pcap."""
    n = d.shape[0]
    if pos + RECORD_HEADER_BYTES > n:
        return U_TRUNCATED, pos, 0, 0, 0
    incl = _u32le(d, pos + 8)
    orig = _u32le(d, pos + 12)
    body = pos + RECORD_HEADER_BYTES
    if body + incl > n or incl != orig:
        return U_TRUNCATED, pos, 0, 0, 0
    nxt = body + incl
    if incl < ETH_HEADER_BYTES + 20 or _u16be(d, body + 12) != 0x0800:
        return U_NOT_ETHERNET_IPV4, nxt, 0, 0, 0
    ip = body + ETH_HEADER_BYTES
    vhl = d[ip]
    if (vhl >> 4) != 4 or (vhl & 0xF) != 5:
        return U_IP_HEADER, nxt, 0, 0, 0
    ip_len = _u16be(d, ip + 2)
    if ip_len < 20 or ip_len > incl - ETH_HEADER_BYTES:
        return U_IP_LENGTH, nxt, 0, 0, 0
    flags_off = _u16be(d, ip + 6)
    if (flags_off & 0x2000) != 0 or (flags_off & 0x1FFF) != 0:
        return U_OK, nxt, F_IP_FRAGMENT, 0, 0
    if d[ip + 9] != 17:
        return U_OK, nxt, F_NOT_UDP, 0, 0
    udp = ip + 20
    udp_bytes = ip_len - 20
    if udp_bytes < 8:
        return U_UDP_HEADER, nxt, 0, 0, 0
    if _u16be(d, udp + 2) != port:
        return U_OK, nxt, F_OTHER_PORT, 0, 0
    ulen = _u16be(d, udp + 4)
    plen = udp_bytes - 8
    if ulen != 0 and ulen - 8 != plen:
        return U_OK, nxt, F_UDP_LENGTH_MISMATCH, 0, 0
    return U_OK, nxt, F_DATAGRAM, udp + 8, plen


@njit(cache=True, _nrt=False)
def _arrival(d, payload):
    """Capture timestamp of the datagram whose payload starts at ``payload``: as dpkt, sec + usec / 1e6."""
    rec = payload - PAYLOAD_AFTER_RECORD
    return np.float64(_u32le(d, rec)) + np.float64(_u32le(d, rec + 4)) / 1e6


@njit(cache=True, _nrt=False)
def _next_datagram(d, pos, port, skip, frames, s):
    """Walk the records from ``pos`` to the next datagram to ``port``, noting the skipped frames in
    ``skip`` (record number, F_*). ``frames``: records walked so far, ``s``: skipped frames so far.

    Returns (status U_*, position after the datagram's record, frames, s, payload offset, payload
    length); the payload offset is -1 when the walk ends: at the end of the file (status U_OK) or at a
    record the fast path does not read (its status)."""
    n = d.shape[0]
    while pos < n:
        status, nxt, code, o, plen = _record(d, pos, port)
        if status == U_TRUNCATED:
            return status, pos, frames, s, -1, 0
        frames += 1
        pos = nxt
        if status != U_OK:
            return status, pos, frames, s, -1, 0
        if code != F_DATAGRAM:
            skip[s, 0] = frames
            skip[s, 1] = code
            s += 1
            continue
        return U_OK, pos, frames, s, o, plen
    return U_OK, pos, frames, s, -1, 0


@njit(cache=True, _nrt=False)
def scan_records(d, port, out_t, out_ip, out_port, out_off, out_len, out_frame, skip, res):
    """Every record: datagrams to ``port`` into out_* (arrival, source address and port, payload offset and
    length, 1-based record number), skipped frames into ``skip`` (record number, F_*).
    ``res``: (status U_*, records, datagrams, skipped)."""
    pos = GLOBAL_HEADER_BYTES
    frames = 0
    k = 0
    s = 0
    while True:
        status, pos, frames, s, o, plen = _next_datagram(d, pos, port, skip, frames, s)
        if o < 0:
            break
        ip = o - 28
        out_t[k] = _arrival(d, o)
        out_ip[k] = (
            (np.uint32(d[ip + 12]) << 24)
            | (np.uint32(d[ip + 13]) << 16)
            | (np.uint32(d[ip + 14]) << 8)
            | np.uint32(d[ip + 15])
        )
        out_port[k] = _u16be(d, o - 8)
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
    per_type,
    max_streams,
    form_size,
    lo,
    hi,
    need_doubles,
    row_off,
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
    """The fast replay's pass over the mapped capture ``d`` (see the module docstring).

    Output arrays are sized by the caller for the most records the file can hold; ``st_key``/``st_last``
    hold ``max_streams`` streams, ``w`` is a MAX_FIELDS scratch row; ``res`` (NRES int64) receives the
    counts and flags (slots R_*)."""
    for q in range(NRES):
        res[q] = 0
    for q in range(16):
        res[R_NO_EPOCH + q] = -1
    res[R_LAST_FIRST] = -1
    res[R_LAST_BREAK] = -1
    pos = GLOBAL_HEADER_BYTES
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
        status, pos, frames, s, o, plen = _next_datagram(d, pos, port, skip, frames, s)
        if o < 0:
            break
        k += 1
        if stopped:  # the replay ended at the STOP; the rest of the file is only walked (for errors)
            continue
        good, t, sq, ni, nd = _decode_one(d, o, plen, form_size, lo, hi, w)
        row_off[r] = o
        if not good:
            row_code[r] = -1
            res[R_BAD] += 1
            r += 1
            continue
        row_code[r] = t
        res[R_TYPES + t] += 1
        # the stream table (listener.seqbuf's key: sender address and port, and the type if per type)
        if not overflow:
            ip = o - 28
            key = (
                (_u16be(d, ip + 12) << 40)
                | (_u16be(d, ip + 14) << 24)
                | (_u16be(d, o - 8) << 8)
                | ((t & 0xFF) if per_type else 0)
            )
            q = -1
            if q_hint < m and st_key[q_hint] == key:
                q = q_hint
            else:
                for p in range(m):
                    if st_key[p] == key:
                        q = p
                        break
            if q < 0:
                if m == max_streams:
                    overflow = True
                else:
                    st_key[m] = key
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
            arrival = _arrival(d, o)
            has_epoch = nd == need_doubles[t]
            if not has_epoch:
                res[R_NO_EPOCH + t] = r
            j = nm
            m_row[j] = r
            m_time[j] = arrival
            kind[j] = t
            v = vals[j]
            for q in range(NV):
                v[q] = np.nan
            # as tools.fast_pack._pack (values beyond the form are NaN in w)
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
            s_time[ns] = _arrival(d, o)
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
def map_capture(path):
    """The file memory-mapped (uint8) after its global header is checked, or why the fast path cannot
    read it (the reasons of :func:`tools.fast_pcap.scan_capture`)."""
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
    return data


def record_capacity(data) -> int:
    """Most records the mapped file can hold (every record is at least 16 + 34 bytes)."""
    size = data.shape[0]
    return max(1, (size - GLOBAL_HEADER_BYTES) // (RECORD_HEADER_BYTES + ETH_HEADER_BYTES + 20) + 1)


@dataclass(frozen=True)
class Ingested:
    """What :func:`ingest_capture` read: views of length ``rows`` / ``meas`` / ... into its arrays."""

    data: np.ndarray  #: the mapped file (uint8)
    res: np.ndarray  #: scalar results (slots R_*)
    row_off: np.ndarray  #: payload offset per row (rows: datagrams up to the first valid STOP)
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

    @property
    def rows(self) -> int:
        return int(self.res[R_ROWS])

    def first_sources(self, start: int) -> list[tuple[int, tuple[str, int], int]]:
        """(row, (host, port), SENSOR_TYPE) of the first valid row of each (source, type) pair from row
        ``start`` on, in row order (for the sender table: listener.senders), vectorised."""
        rows = np.flatnonzero(self.row_code[start:] >= 0) + start
        if rows.size == 0:
            return []
        d = self.data
        ip = self.row_off[rows] - PAYLOAD_AFTER_RECORD + RECORD_HEADER_BYTES + ETH_HEADER_BYTES
        host = np.zeros(rows.size, dtype=np.int64)
        for b in range(4):
            host = (host << 8) | d[ip + 12 + b].astype(np.int64)
        port = (d[ip + 20].astype(np.int64) << 8) | d[ip + 21].astype(np.int64)
        key = (host << 24) | (port << 8) | self.row_code[rows].astype(np.int64)
        _, first = np.unique(key, return_index=True)
        out = []
        for i in np.sort(first).tolist():
            h = int(host[i])
            addr = (".".join(str((h >> s) & 0xFF) for s in (24, 16, 8, 0)), int(port[i]))
            out.append((int(rows[i]), addr, int(self.row_code[rows[i]])))
        return out

    def datagram(self, r: int):
        """(arrival, (host, port), payload) of row r, read from the headers in front of its payload."""
        o = int(self.row_off[r])
        head = bytes(self.data[o - PAYLOAD_AFTER_RECORD : o])
        sec, usec = struct.unpack_from("<II", head, 0)
        ip = RECORD_HEADER_BYTES + ETH_HEADER_BYTES
        (ip_len,) = struct.unpack_from(">H", head, ip + 2)
        (port,) = struct.unpack_from(">H", head, ip + 20)
        host = ".".join(str(b) for b in head[ip + 12 : ip + 16])
        return sec + usec / 1e6, (host, port), bytes(self.data[o : o + ip_len - 28])


def ingest_capture(path, port: int, per_type: bool, max_streams: int, tables):
    """Run :func:`ingest` over the capture at ``path``: an :class:`Ingested`, or a reason string when the
    file is not one the fast path reads (as :func:`tools.fast_pcap.scan_capture` words it).

    ``tables``: (form_size, lo, hi) of :mod:`tools.fast_decode`."""
    data = map_capture(path)
    if isinstance(data, str):
        return data
    cap = record_capacity(data)
    # sized for the most records the file can hold; untouched pages of np.empty are never mapped
    row_off = np.empty(cap, dtype=np.int64)
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
    st_key = np.empty(max(streams, 1), dtype=np.int64)
    st_last = np.empty(max(streams, 1), dtype=np.int64)
    w = np.empty(MAX_FIELDS)
    res = np.zeros(NRES, dtype=np.int64)
    form_size, lo, hi = tables
    ingest(
        data, int(port), bool(per_type), streams, form_size, lo, hi, EPOCH_DOUBLES_BY_TYPE,
        row_off, row_code, m_row, m_time, kind, t_s, vals, g_row, g_meas, g_time, g_lat, g_lon, g_fq,
        s_row, s_ts, s_time, skip, st_key, st_last, w, res,
    )  # fmt: skip
    if res[R_STATUS] != U_OK:
        return f"record {int(res[R_FRAMES])}: {UNSUPPORTED_REASONS[int(res[R_STATUS])]}"
    r, nm, ng, ns = (int(res[x]) for x in (R_ROWS, R_MEAS, R_GPS, R_STROBES))
    return Ingested(
        data, res, row_off[:r], row_code[:r], m_row[:nm], m_time[:nm], kind[:nm], t_s[:nm], vals[:nm],
        g_row[:ng], g_meas[:ng], g_time[:ng], g_lat[:ng], g_lon[:ng], g_fq[:ng],
        s_row[:ns], s_ts[:ns], s_time[:ns], skip[: int(res[R_SKIPPED])],
    )  # fmt: skip
