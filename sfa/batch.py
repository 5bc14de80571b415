"""Batch replay: the same compiled step functions as ``TrackFilter.process``, looped in compiled code.

Measurements are packed once into arrays (``pack``), GNSS positions converted to the database's local
frame in one vectorised call, and ``run_packed`` steps through them with no Python object in the loop.
The batch path follows one line (the one of the first GROUND TRUTH) in a known sense of travel
(``InitMeas.direction``, +1 when unknown); junction and direction hypotheses need the per-message
``TrackFilter``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sfa import kernels as K
from sfa import layout as L
from sfa.config import FilterConfig
from sfa.engine import njit  # numba.njit on the JIT; in a compiled process its first call switches to the JIT
from sfa.errors import FilterStateError, MeasurementTypeError
from sfa.measurements import GpsMeas, ImuMeas, InitMeas, OdoMeas
from sfa.track_arrays import TrackArrays

NV = 7  #: values per packed measurement


@dataclass(frozen=True)
class Packed:
    """Measurements as arrays: kind (sfa.layout.M_*), time [s] and up to 7 values each.

    IMU: fx, fy, fz [m/s^2], wx, wy, wz [rad/s]; odometer: speed, sigma [m/s]; GNSS: east, north [m],
    sigma_h [m] (NaN: not reported), fix quality (-1: not reported); init: s [m], v [m/s],
    line id (-1: default), direction (+1/-1; an unknown direction is taken as +1 here).
    """

    kind: np.ndarray  #: int64
    t_s: np.ndarray  #: float64
    values: np.ndarray  #: float64 (n, 7)


@dataclass(frozen=True)
class BatchResult:
    """One row per input measurement: the estimate after it was processed."""

    outcome: np.ndarray  #: sfa.layout.Outcome codes (int64)
    epoch_s: np.ndarray  #: state time [s]
    arc_length_m: np.ndarray  #: [m]
    speed_mps: np.ndarray  #: [m/s]
    sigma_s_m: np.ndarray  #: [m]
    status: np.ndarray  #: FilterStatus codes (int64)
    reason_bits: np.ndarray  #: reason bit masks (int64, sfa.layout.R_*)
    counters: np.ndarray  #: final counters (int64, names in sfa.layout.COUNTER_NAMES)
    x: np.ndarray  #: final state
    P: np.ndarray  #: final covariance


def pack(measurements, track) -> Packed:
    """Pack filter measurements into arrays; GNSS lat/lon go to the local frame of ``track`` at once."""
    n = len(measurements)
    kind = np.zeros(n, dtype=np.int64)
    t = np.full(n, math.nan)
    vals = np.full((n, NV), math.nan)
    gps_rows: list[int] = []
    for i, m in enumerate(measurements):
        if isinstance(m, ImuMeas):
            kind[i] = L.M_IMU
            vals[i, 0:3] = m.f_mps2
            vals[i, 3:6] = m.w_radps
        elif isinstance(m, OdoMeas):
            kind[i] = L.M_ODO
            vals[i, 0] = m.speed_mps
            vals[i, 1] = m.sigma_mps
        elif isinstance(m, GpsMeas):
            kind[i] = L.M_GPS
            vals[i, 0] = m.lat_deg
            vals[i, 1] = m.lon_deg
            vals[i, 2] = math.nan if m.sigma_h_m is None else m.sigma_h_m
            vals[i, 3] = -1.0 if m.fix_quality is None else m.fix_quality
            gps_rows.append(i)
        elif isinstance(m, InitMeas):
            kind[i] = L.M_INIT
            vals[i, 0] = m.arc_length_m
            vals[i, 1] = m.speed_mps
            vals[i, 2] = -1.0 if m.line_id is None else m.line_id
            vals[i, 3] = 1.0 if m.direction is None else m.direction
        else:
            raise MeasurementTypeError(f"not a filter measurement: {type(m).__name__}")
        t[i] = m.t_s
    if gps_rows:
        rows = np.asarray(gps_rows)
        lat, lon = vals[rows, 0], vals[rows, 1]
        ok = np.isfinite(lat) & np.isfinite(lon) & (np.abs(lat) <= 90.0) & (np.abs(lon) <= 180.0)
        east = np.full(rows.shape[0], math.nan)
        north = np.full(rows.shape[0], math.nan)
        if ok.any():
            e, nn = track.to_local(lat[ok], lon[ok])
            east[ok] = np.asarray(e, dtype=np.float64)
            north[ok] = np.asarray(nn, dtype=np.float64)
        vals[rows, 0] = east
        vals[rows, 1] = north
    return Packed(kind, t, vals)


@njit(cache=True)
def run_packed(kind, t, vals, x, P, aux, cnt, mem, cfg, ts, te, tn, tg, tk, out_f, out_i):
    """Step through packed measurements; out_f (n, 4): epoch, s, v, sigma_s; out_i (n, 3): outcome,
    status, reason bits."""
    n = kind.shape[0]
    for i in range(n):
        k = kind[i]
        ti = t[i]
        v = vals[i]
        if k == 1:
            o = K.step_imu(x, P, aux, cnt, mem, cfg, ts, tg, tk, ti, v[0], v[1], v[2], v[3], v[4], v[5])
        elif k == 2:
            o = K.step_odo(x, P, aux, cnt, mem, cfg, ts, tg, ti, v[0], v[1])
        elif k == 3:
            fq = -1 if not math.isfinite(v[3]) else int(v[3])
            o = K.step_gps(x, P, aux, cnt, cfg, ts, te, tn, tg, ti, v[0], v[1], v[2], fq)
        elif k == 8:
            o = K.step_init(x, P, aux, cnt, mem, cfg, ts, tg, ti, v[0], v[1], v[3])
        else:
            o = K.O_INVALID
        st, bits, sig = K.status_of(x, P, aux, cfg, aux[L.A_T_STATE])
        out_f[i, 0] = aux[L.A_T_STATE]
        out_f[i, 1] = x[L.S]
        out_f[i, 2] = x[L.V]
        out_f[i, 3] = sig
        out_i[i, 0] = o
        out_i[i, 1] = st
        out_i[i, 2] = bits


def replay(track, config: FilterConfig, measurements=None, packed: Packed | None = None) -> BatchResult:
    """Run the filter over time-ordered measurements on the line of the first GROUND TRUTH."""
    if packed is None:
        if measurements is None:
            raise FilterStateError("replay needs measurements or packed arrays")
        packed = pack(measurements, track)
    init_rows = np.flatnonzero(packed.kind == L.M_INIT)
    line_id = None
    if init_rows.size:
        lid = packed.values[init_rows[0], 2]
        if math.isfinite(lid) and lid >= 0:
            line_id = int(lid)
    line = TrackArrays.from_line(track.line(line_id))
    cfg = config.to_array()
    n = packed.kind.shape[0]
    x = np.zeros(L.NX)
    P = np.zeros((L.NX, L.NX))
    aux = np.zeros(L.NAUX)
    cnt = np.zeros(L.NCNT, dtype=np.int64)
    out_f = np.zeros((n, 4))
    out_i = np.zeros((n, 3), dtype=np.int64)
    mem = np.zeros(L.NMEM)
    run_packed(packed.kind, packed.t_s, packed.values, x, P, aux, cnt, mem, cfg, line.s_m, line.east_m,
               line.north_m, line.grade, line.curvature_inv_m, out_f, out_i)
    K.sync_block(x, P, aux, cfg, cnt.copy())  # the final covariance up to the final state time
    return BatchResult(out_i[:, 0], out_f[:, 0], out_f[:, 1], out_f[:, 2], out_f[:, 3], out_i[:, 1],
                       out_i[:, 2], cnt, x, P)


def warm_up_batch(cfg: np.ndarray) -> None:
    """Compile the batch loop on a throwaway line."""
    ts = np.array([0.0, 100.0])
    z = np.zeros(2)
    kind = np.array([8, 1, 2, 3], dtype=np.int64)
    t = np.array([0.0, 0.01, 0.02, 0.03])
    vals = np.zeros((4, NV))
    vals[0, 3] = 1.0
    vals[1, 2] = -9.8
    vals[2, 1] = 0.05
    vals[3, 2] = math.nan
    vals[3, 3] = 1.0
    run_packed(kind, t, vals, np.zeros(L.NX), np.zeros((L.NX, L.NX)), np.zeros(L.NAUX),
               np.zeros(L.NCNT, dtype=np.int64), np.zeros(L.NMEM), cfg, ts, ts.copy(), z, z, z,
               np.zeros((4, 4)), np.zeros((4, 3), dtype=np.int64))
