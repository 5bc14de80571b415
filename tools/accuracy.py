"""Accuracy of estimates against truth: the figures replay, the demo and the benchmarks report."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np


@dataclass(frozen=True)
class Accuracy:
    """Absolute along-track error statistics of estimates against interpolated truth."""

    n: int  #: estimates compared
    rms_m: float  #: root mean square error [m]
    p50_m: float  #: median absolute error [m]
    p95_m: float  #: 95th percentile of the absolute error [m]
    max_m: float  #: largest absolute error [m]
    coverage: float | None  #: fraction of estimates whose interval contains the truth (None: no interval)

    def as_dict(self) -> dict:
        return asdict(self)


def along_track_errors(
    epoch_s: np.ndarray, arc_length_m: np.ndarray, truth_epoch_s: np.ndarray, truth_arc_length_m: np.ndarray
) -> np.ndarray:
    """Signed error ``estimate - truth`` with truth linearly interpolated at each estimate's epoch [m].

    Estimates outside the truth's time span are dropped (NaN) rather than extrapolated.
    """
    epoch = np.asarray(epoch_s, dtype=float)
    truth = np.interp(epoch, truth_epoch_s, truth_arc_length_m)
    err = np.asarray(arc_length_m, dtype=float) - truth
    outside = (epoch < truth_epoch_s[0]) | (epoch > truth_epoch_s[-1])
    err[outside] = np.nan
    return err


def accuracy(
    epoch_s, arc_length_m, truth_epoch_s, truth_arc_length_m, interval_low_m=None, interval_high_m=None
) -> Accuracy:
    """Statistics of :func:`along_track_errors`; interval coverage when bounds are given."""
    err = along_track_errors(epoch_s, arc_length_m, truth_epoch_s, truth_arc_length_m)
    ok = np.isfinite(err)
    a = np.abs(err[ok])
    if a.size == 0:
        return Accuracy(0, float("nan"), float("nan"), float("nan"), float("nan"), None)
    coverage = None
    if interval_low_m is not None and interval_high_m is not None:
        truth = np.interp(np.asarray(epoch_s, dtype=float)[ok], truth_epoch_s, truth_arc_length_m)
        lo = np.asarray(interval_low_m, dtype=float)[ok]
        hi = np.asarray(interval_high_m, dtype=float)[ok]
        inside = (truth >= lo) & (truth <= hi)
        coverage = float(np.mean(inside))
    return Accuracy(
        n=int(a.size),
        rms_m=float(np.sqrt(np.mean(a**2))),
        p50_m=float(np.percentile(a, 50)),
        p95_m=float(np.percentile(a, 95)),
        max_m=float(a.max()),
        coverage=coverage,
    )
