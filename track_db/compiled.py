"""Compiled (numba) point/tangent/curvature kernels over ``TrackLine.arrays()``, for filter cores that
run many queries per measurement or whole replay campaigns in compiled code.

These kernels do no range checking (the caller keeps s within [0, length_m]; values outside are
clamped to the end segments) and return results in caller-provided arrays. They implement the same
formulas as :class:`track_db.line.TrackLine` and are tested against it to 1e-12.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["point_tangent_at", "point_tangent_at_one", "curvature_at", "compiled_point_tangent"]


@njit(cache=True, fastmath=False, nogil=True)
def _segment(s_m: np.ndarray, s: float) -> int:
    lo = 0
    hi = s_m.size - 2
    while lo < hi:  # largest i with s_m[i] <= s, clamped to [0, n-2]
        mid = (lo + hi + 1) >> 1
        if s_m[mid] <= s:
            lo = mid
        else:
            hi = mid - 1
    return lo


@njit(cache=True, nogil=True)
def point_tangent_at_one(s_m, east_m, north_m, s):
    """(east, north, te, tn) at one arc length."""
    i = _segment(s_m, s)
    ds = s_m[i + 1] - s_m[i]
    de = east_m[i + 1] - east_m[i]
    dn = north_m[i + 1] - north_m[i]
    t = (s - s_m[i]) / ds
    length = np.sqrt(de * de + dn * dn)
    return east_m[i] + t * de, north_m[i] + t * dn, de / length, dn / length


@njit(cache=True, nogil=True)
def point_tangent_at(s_m, east_m, north_m, s, out_e, out_n, out_te, out_tn):
    """Vectorised :func:`point_tangent_at_one` into the four output arrays."""
    for k in range(s.size):
        e, n, te, tn = point_tangent_at_one(s_m, east_m, north_m, s[k])
        out_e[k] = e
        out_n[k] = n
        out_te[k] = te
        out_tn[k] = tn


@njit(cache=True, nogil=True)
def curvature_at(heading_rad, curvature_per_m, step_m, s, out):
    """Curvature [1/m] at each s: the derivative of the heading's cubic Hermite spline (TrackLine)."""
    n = heading_rad.size
    for k in range(s.size):
        u = s[k] / step_m
        i = int(np.floor(u))
        if i < 0:
            i = 0
        if i > n - 2:
            i = n - 2
        t = u - i
        t2 = t * t
        out[k] = (
            ((6 * t2 - 6 * t) * heading_rad[i] + (-6 * t2 + 6 * t) * heading_rad[i + 1]) / step_m
            + (3 * t2 - 4 * t + 1) * curvature_per_m[i]
            + (3 * t2 - 2 * t) * curvature_per_m[i + 1]
        )


def compiled_point_tangent(arrays: dict[str, np.ndarray], s: np.ndarray):
    """Convenience wrapper: (east, north, te, tn) arrays for the arc lengths s."""
    s = np.ascontiguousarray(s, dtype=np.float64)
    out = [np.empty_like(s) for _ in range(4)]
    point_tangent_at(arrays["s_m"], arrays["east_m"], arrays["north_m"], s, *out)
    return tuple(out)
