"""Smoothed heading, curvature and grade profiles of a digitised line.

OSM and GTFS vertices are noisy and 18-50 m apart, so the polyline's own corners are not the track's
curvature. Method (documented in docs/track-db.md):

1. Resample the local (east, north) polyline and the altitude on a uniform arc-length grid
   ``g_i = i * step`` (step <= ``step_m``, last sample at the line length); cell chords
   ``c_j = P(g_{j+1}) - P(g_j)`` are the mean direction of the polyline over each cell.
2. At every sample, a Gaussian-weighted sum (standard deviation ``sigma_m``, truncated at 3 sigma) of
   the chords of the cells placed *symmetrically* around it. Near the line ends the window shrinks so
   that it stays symmetric (the first and last samples use their single adjacent cell).
3. heading = unwrap(atan2(V_east, V_north)), clockwise from north; grade = weighted mean of
   dAlt/ds over the same window (0 without altitude).
4. curvature = d(heading)/ds, second-order central differences on the grid.

Why this filter: a weighted sum of chords symmetric about a point of a circular arc is parallel to the
tangent there, so the heading (and curvature) of a circle is unbiased for any smoothing length. A
Gaussian kernel suppresses the ripple that a polyline's corners put into the curvature by a factor of
about ``2 exp(-2 pi^2 sigma^2 / spacing^2)`` (under 1 % once sigma >= 0.6 x vertex spacing), where a
Savitzky-Golay window leaves several percent.

Queries evaluate heading with a cubic Hermite spline through (heading_i, curvature_i), and curvature as
the exact derivative of that spline, so ``d(heading_at)/ds == curvature_at`` holds by construction and
curvature is continuous.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Profile", "compute_profile", "hermite_value", "hermite_derivative", "linear_value"]


@dataclass(frozen=True)
class Profile:
    """Uniformly sampled profiles of one line: sample i is at ``s = i * step_m``."""

    step_m: float  #: grid step [m]; the last sample is at the line length
    heading_rad: np.ndarray  #: smoothed heading, unwrapped, clockwise from north [rad]
    curvature_per_m: np.ndarray  #: d(heading)/ds [1/m], > 0 turning right (clockwise)
    grade: np.ndarray  #: smoothed dAlt/ds [dimensionless], > 0 climbing; 0 where altitude is unknown


def _symmetric_weighted_sums(cells: np.ndarray, step: float, sigma_m: float) -> tuple[np.ndarray, np.ndarray]:
    """For each grid sample i (n = len(cells) + 1), sum_k w_k * cells[i+k] over the symmetric window.

    Cells i-m .. i+m-1 (centres at (k + 1/2) * step from sample i) with Gaussian weights, m = min(M, i,
    n-1-i); the end samples use their one adjacent cell. Returns (sums with shape (n, ...), weight sums).
    """
    n_cells = cells.shape[0]
    n = n_cells + 1
    big_m = max(1, int(math.ceil(3.0 * sigma_m / step)))
    big_m = min(big_m, n_cells // 2) if n_cells >= 2 else 1
    # the same bytes on every machine: weights from libm (not numpy's SIMD exp), sums as a fixed
    # sequence of elementwise multiply-adds (IEEE-exact per element; no BLAS dot/convolve, whose
    # kernels differ by CPU: the bundled database did not rebuild byte for byte on OpenBLAS's
    # Haswell kernels after it was built on SkylakeX ones)
    w = np.array([math.exp(-0.5 * (((k + 0.5) * step) / sigma_m) ** 2) for k in range(-big_m, big_m)])
    out = np.zeros((n,) + cells.shape[1:])
    wsum = np.zeros(n)
    # interior: full window, i = M .. n-1-M: out[i] = sum_k w[k] cells[i - M + k], k in order
    if n - 2 * big_m > 0:
        inner = out[big_m : n - big_m]
        for k in range(2 * big_m):
            inner += w[k] * cells[k : k + n - 2 * big_m]
        wsum[big_m : n - big_m] = math.fsum(w)
    # near the ends: symmetric shrinking windows
    for i in list(range(0, min(big_m, n))) + list(range(max(big_m, n - big_m), n)):
        m = min(big_m, i, n - 1 - i)
        if m == 0:
            j = 0 if i == 0 else n_cells - 1
            out[i] = cells[j]
            wsum[i] = 1.0
            continue
        wk = w[big_m - m : big_m + m]
        for k in range(2 * m):
            out[i] += wk[k] * cells[i - m + k]
        wsum[i] = math.fsum(wk)
    return out, wsum


def compute_profile(
    s_m: np.ndarray,
    east_m: np.ndarray,
    north_m: np.ndarray,
    alt_m: np.ndarray | None,
    *,
    sigma_m: float,
    step_m: float,
) -> Profile:
    """Profiles of the polyline with per-vertex arc length ``s_m`` (strictly increasing, s_m[0] = 0)."""
    length = float(s_m[-1])
    n = max(3, int(math.ceil(length / step_m)) + 1)
    grid = np.linspace(0.0, length, n)
    step = length / (n - 1)
    pos = np.column_stack((np.interp(grid, s_m, east_m), np.interp(grid, s_m, north_m)))
    chords = np.diff(pos, axis=0)
    vec, _ = _symmetric_weighted_sums(chords, step, sigma_m)
    # libm's atan2 per sample: numpy's vectorised arctan2 differs in the last bit between CPU features
    heading = np.unwrap(np.array([math.atan2(e, nn) for e, nn in zip(vec[:, 0].tolist(), vec[:, 1].tolist(),
                                                                    strict=True)]))
    # the end samples only see one cell, centred half a step inside: extrapolate them linearly instead
    if n >= 4:
        heading[0] = 2.0 * heading[1] - heading[2]
        heading[-1] = 2.0 * heading[-2] - heading[-3]
    else:
        heading[:] = heading[1]
    curvature = np.gradient(heading, step, edge_order=2)
    if alt_m is not None:
        dalt = np.diff(np.interp(grid, s_m, alt_m))[:, None]
        total, wsum = _symmetric_weighted_sums(dalt, step, sigma_m)
        grade = total[:, 0] / wsum / step
    else:
        grade = np.zeros(n)
    return Profile(
        step,
        np.ascontiguousarray(heading, dtype=np.float64),
        np.ascontiguousarray(curvature, dtype=np.float64),
        np.ascontiguousarray(grade, dtype=np.float64),
    )


def _cell(s_m: np.ndarray, step_m: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    u = np.asarray(s_m, dtype=np.float64) / step_m
    i = np.clip(np.floor(u).astype(np.int64), 0, n - 2)
    return i, u - i


def hermite_value(s_m, step_m: float, y: np.ndarray, dy: np.ndarray) -> np.ndarray:
    """Cubic Hermite spline through (i*step, y_i) with slopes dy_i, evaluated at s_m."""
    i, t = _cell(s_m, step_m, y.size)
    t2 = t * t
    t3 = t2 * t
    h00 = 2 * t3 - 3 * t2 + 1
    h10 = t3 - 2 * t2 + t
    h01 = -2 * t3 + 3 * t2
    h11 = t3 - t2
    return h00 * y[i] + h10 * step_m * dy[i] + h01 * y[i + 1] + h11 * step_m * dy[i + 1]


def hermite_derivative(s_m, step_m: float, y: np.ndarray, dy: np.ndarray) -> np.ndarray:
    """Exact derivative d/ds of :func:`hermite_value` (continuous, equals dy_i at the nodes)."""
    i, t = _cell(s_m, step_m, y.size)
    t2 = t * t
    d00 = 6 * t2 - 6 * t
    d10 = 3 * t2 - 4 * t + 1
    d01 = -6 * t2 + 6 * t
    d11 = 3 * t2 - 2 * t
    return (d00 * y[i] + d01 * y[i + 1]) / step_m + d10 * dy[i] + d11 * dy[i + 1]


def linear_value(s_m, step_m: float, y: np.ndarray) -> np.ndarray:
    """Linear interpolation of the uniform samples y at s_m."""
    i, t = _cell(s_m, step_m, y.size)
    return y[i] + t * (y[i + 1] - y[i])
