"""Decoded datagrams -> ``sfa.batch`` packed arrays (kind, time, values), without Python objects.

Used by the fast replay (:mod:`tools.fast_replay`) and by ``sfa bench`` (the filter core, the C
reference and the baselines all run on the arrays this builds from one capture).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import njit

#: N_DOUBLE of IMU, odometer and GPS datagrams that carry an epoch
EPOCH_DOUBLES = {1: 7, 2: 3, 3: 5}


@njit(cache=True)
def _pack(stype, n_int, values, rows, kind, t_s, vals, lat, lon):
    """One pass: kind, epoch and values per row (GNSS: lat/lon kept aside, fix quality 0 -> (0, 0))."""
    for j in range(rows.shape[0]):
        r = rows[j]
        k = stype[r]
        kind[j] = k
        w = values[r]
        if k == 1:
            for q in range(6):
                vals[j, q] = w[q]
            t_s[j] = w[6]
        elif k == 2:
            vals[j, 0] = w[0]
            vals[j, 1] = w[1]
            t_s[j] = w[2]
        elif k == 3:
            b = 2 if n_int[r] == 2 else 0
            lat[j] = w[b]
            lon[j] = w[b + 1]
            t_s[j] = w[b + 4]
            fq = w[0] if b == 2 else -1.0
            vals[j, 0] = 0.0
            vals[j, 1] = 0.0
            vals[j, 2] = w[b + 3]
            vals[j, 3] = fq
        elif k == 8:  # GROUND TRUTH: the epoch only (initialisations go through TrackFilter)
            t_s[j] = w[n_int[r] + 4]


def pack_rows(dec, rows: np.ndarray, track) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pack the decoded IMU/odometer/GPS datagrams ``rows`` (all with epoch) in the given order.

    GNSS lat/lon go to the track's local frame in one vectorised call (fix quality 0 -> (0, 0): the
    filter counts such a fix as "no fix" before looking at the position, as TrackFilter does).
    GROUND TRUTH rows get kind 8 and their epoch, no values.
    """
    from sfa.batch import NV

    rows = np.ascontiguousarray(rows, dtype=np.int64)
    nm = rows.size
    kind = np.zeros(nm, dtype=np.int64)
    t_s = np.full(nm, math.nan)
    vals = np.full((nm, NV), math.nan)
    lat = np.full(nm, math.nan)
    lon = np.full(nm, math.nan)
    _pack(dec.stype, dec.n_int, dec.values, rows, kind, t_s, vals, lat, lon)
    g = np.flatnonzero((kind == 3) & (vals[:, 3] != 0.0))
    if g.size:
        e, nn = track.to_local(lat[g], lon[g])
        vals[g, 0] = np.asarray(e, dtype=np.float64)
        vals[g, 1] = np.asarray(nn, dtype=np.float64)
    return kind, t_s, vals


@dataclass(frozen=True)
class PackedCapture:
    """A clean capture as filter inputs: the GROUND TRUTH initialisation first, then the measurements."""

    kind: np.ndarray  #: int64 (sfa.layout.M_*)
    t_s: np.ndarray  #: measurement epochs [s]
    values: np.ndarray  #: (n, 7) float64 (sfa.batch.Packed layout)
    line_id: int  #: the line of the GROUND TRUTH
    datagrams: int  #: UDP datagrams to the listener port in the capture
    duration_s: float  #: capture span [s]


def pack_capture(path: str | Path, track, port: int) -> PackedCapture | str:
    """Every valid measurement datagram with epoch, in capture order, behind the first GROUND TRUTH
    (packed as an initialisation, direction +1). Returns a reason string when the capture is not a
    classic Ethernet/IPv4 pcap, has no GROUND TRUTH, or measurements without epoch."""
    from tools.fast_decode import decode_batch
    from tools.fast_pcap import scan_capture

    scan = scan_capture(path, port)
    if isinstance(scan, str):
        return scan
    dec = decode_batch(scan.data, scan.offset, scan.length)
    gt = np.flatnonzero(dec.ok & (dec.stype == 8))
    if gt.size == 0:
        return "no GROUND TRUTH datagram"
    g = int(gt[0])
    if dec.n_double[g] != 5:
        return "GROUND TRUTH without epoch"
    rows = np.arange(g + 1, scan.time_s.size)
    st = dec.stype[rows]
    ok = dec.ok[rows]
    for t, nd in EPOCH_DOUBLES.items():
        if np.any(ok & (st == t) & (dec.n_double[rows] != nd)):
            return "measurements without epoch"
    mrows = rows[ok & ((st == 1) | (st == 2) | (st == 3))]
    kind, t_s, vals = pack_rows(dec, mrows, track)
    gv = dec.values[g]
    ni = int(dec.n_int[g])
    line_id = int(gv[0]) if ni == 1 else int(track.default_line_id)
    init = np.full((1, vals.shape[1]), math.nan)
    init[0, 0] = gv[ni + 3]  # arc length
    init[0, 1] = gv[ni + 0]  # vx
    init[0, 2] = line_id
    init[0, 3] = 1.0
    return PackedCapture(
        np.concatenate([[8], kind]).astype(np.int64),
        np.concatenate([[gv[ni + 4]], t_s]),
        np.vstack([init, vals]),
        line_id,
        int(scan.time_s.size),
        float(scan.time_s[-1] - scan.time_s[0]),
    )
