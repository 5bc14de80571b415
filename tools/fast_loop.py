"""The filter loop of the fast replay: ``sfa.batch.run_packed`` plus what the replay result records.

Same kernels, same order, same dispatch as :func:`sfa.batch.run_packed` (IMU, odometer, GNSS,
initialisation by ``kind``), and after every measurement the reported estimate (state time, arc
length, speed, sigma, status, reason bits), the NIS the per-message filter reports for odometer and
GNSS updates, and whether the listener would send an output for it: ``listener.pipeline``'s rule
(finite estimate, epoch not older than the last output, and not the same epoch with the same arc
length). tests/test_fast_replay.py checks this loop against ``run_packed`` on the same inputs.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from sfa import kernels as K
from sfa import layout as L


# Not cached on disk: numba's cache is keyed on this file only, so a cached loop would keep running
# the sfa.kernels it was compiled with after sfa/kernels.py changes (compiled once per process).
@njit(cache=False)
def run_replay_loop(
    kind, t, vals, x, P, aux, cnt, mem, cfg, ts, te, tn, tg, tk, last_epoch, last_s, out_f, out_i
):
    """Step through packed measurements (layout of sfa.batch.Packed).

    out_f (n, 5): epoch [s], s [m], v [m/s], sigma_s [m], nis (NaN for IMU/init);
    out_i (n, 4): outcome, status, reason bits, 1 when the listener sends an output after it.
    ``last_epoch`` / ``last_s``: the listener's last output before the first row (-inf / NaN: none).
    Returns the number of outputs.
    """
    n = kind.shape[0]
    outputs = 0
    for i in range(n):
        k = kind[i]
        ti = t[i]
        v = vals[i]
        nis = math.nan
        if k == 1:
            o = K.step_imu(x, P, aux, cnt, mem, cfg, ts, tg, tk, ti, v[0], v[1], v[2], v[3], v[4], v[5])
        elif k == 2:
            o = K.step_odo(x, P, aux, cnt, mem, cfg, ts, tg, ti, v[0], v[1])
            nis = aux[L.A_LAST_NIS_ODO]
        elif k == 3:
            fq = -1 if not math.isfinite(v[3]) else int(v[3])
            o = K.step_gps(x, P, aux, cnt, cfg, ts, te, tn, tg, ti, v[0], v[1], v[2], fq)
            nis = aux[L.A_LAST_NIS_GPS]
        elif k == 8:
            o = K.step_init(x, P, aux, cnt, mem, cfg, ts, tg, ti, v[0], v[1], v[3])
        else:
            o = K.O_INVALID
        epoch = aux[L.A_T_STATE]
        st, bits, sig = K.status_of(x, P, aux, cfg, epoch)
        s = x[L.S]
        out_f[i, 0] = epoch
        out_f[i, 1] = s
        out_f[i, 2] = x[L.V]
        out_f[i, 3] = sig
        out_f[i, 4] = nis
        out_i[i, 0] = o
        out_i[i, 1] = st
        out_i[i, 2] = bits
        send = 0
        if math.isfinite(epoch) and math.isfinite(s) and epoch >= last_epoch:
            if not (epoch == last_epoch and s == last_s):
                send = 1
                last_epoch = epoch
                last_s = s
                outputs += 1
        out_i[i, 3] = send
    return outputs


@njit(cache=True)
def interp_many(ts, arr, s, valid):
    """``sfa.kernels.interp_at`` per element where ``valid`` and ts[0] <= s <= ts[-1]; NaN elsewhere."""
    out = np.full(s.shape[0], np.nan)
    lo = ts[0]
    hi = ts[ts.shape[0] - 1]
    for i in range(s.shape[0]):
        if valid[i] and lo <= s[i] <= hi:
            out[i] = K.interp_at(ts, arr, s[i])
    return out
