"""The batch loop ``sfa bench`` checks ``sfa.batch.run_packed``'s disk-cached compile against.

:func:`run_replay_loop` is ``sfa.batch.run_packed``'s loop with the NIS and the output rule, compiled into
a disk cache keyed on every source it is built from (below). The replay's own filter loop, with the
hypotheses, is ``sfa.bank.run_segment`` (driven through ``sfa.filter.TrackFilter.run``).
"""

from __future__ import annotations

import hashlib
import math
import os
from pathlib import Path

import numba
from numba import njit

import sfa
from sfa import kernels as K
from sfa import layout as L


def source_key(paths) -> str:
    """A hash of numba's version and of the files' names and contents (20 hex digits)."""
    h = hashlib.sha256(numba.__version__.encode())
    for path in paths:
        h.update(Path(path).name.encode() + b"\0" + Path(path).read_bytes() + b"\0")
    return h.hexdigest()[:20]


def _keyed_cache_dir() -> str | None:
    """A numba disk-cache directory for this module's loops keyed on the sources they are built from.

    Numba keys a cached function on its own file only; these loops inline ``sfa.kernels`` and read
    ``sfa.layout``'s slots at compile time, so a cache keyed on this file alone would go stale when the
    filter changes. The directory's name is a hash of every ``sfa/*.py`` and of this file: any edit
    there selects a new, empty directory (the loops compile once, about 25 s, then load in well under
    a second). Under ``numba.config.CACHE_DIR`` (``NUMBA_CACHE_DIR``) if set, else beside this file in
    ``__pycache__``; None (no disk cache, compiled per process) where that cannot be written."""
    key = source_key([*sorted(Path(sfa.__file__).parent.glob("*.py")), Path(__file__)])
    base = numba.config.CACHE_DIR or str(Path(__file__).parent / "__pycache__")
    where = os.path.join(base, f"fast_loop-{key}")
    try:
        os.makedirs(where, exist_ok=True)
        probe = os.path.join(where, f".probe-{os.getpid()}")
        with open(probe, "w"):
            pass
        os.remove(probe)
    except OSError:
        return None
    return where


#: where the loops below are cached (numba reads config.CACHE_DIR when a function is decorated, so it is
#: set around their definitions and put back at the end of the module)
CACHE_DIR = _keyed_cache_dir()
_CACHE = CACHE_DIR is not None
_CACHE_DIR_BEFORE = numba.config.CACHE_DIR
if _CACHE:
    numba.config.CACHE_DIR = CACHE_DIR

@njit(cache=_CACHE)
def run_replay_loop(
    kind, t, vals, x, P, aux, cnt, mem, cfg, ts, te, tn, tg, tk, last_epoch, last_s, out_f, out_i
):
    """``sfa.batch.run_packed``'s loop with the NIS and the output rule (no hypotheses, no stale rule):
    the reference ``sfa bench`` checks ``run_packed``'s disk-cached compile against. Returns the outputs."""
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


numba.config.CACHE_DIR = _CACHE_DIR_BEFORE
