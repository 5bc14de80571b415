"""A real log judged from many start times, not one.

One run over a short real log is one draw. On smartLoc's real GNSS (283 s of single-point fixes tens of
metres off in a street canyon) the filter's p95 from the log's first second is 1.5 m with the default
GNSS model and 4.4 m with the maximum-likelihood one; started 10 s later, the same filters give 6.7 m
and 3.1 m over 140 s (docs/filter.md, "Session 35"). Which estimator is better cannot be read from one
start: it depends on whether a detector happens to fire in the first minute.

This module re-initialises the filter from the truth (arc length, speed, line; the sense of travel left
open, as ``sfa convert`` does) at every ``step_s`` of the log and runs it for ``window_s``, on the
measurements the replay dates (``tools.replay``, ``record_measurements``). The baselines (plain FilterPy
EKF, odometer dead reckoning) run on the same windows from the same initialisation. A window's figures
are :func:`tools.accuracy.accuracy`'s over every estimate inside it (SFA after each measurement).
Windows overlap, so they are not independent draws; they are many anchors of the one log.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tools.errors import ToolError


@dataclass(frozen=True)
class WindowConfig:
    """Where the windows start and how long they run."""

    window_s: float = 140.0  #: length of each run [s]
    step_s: float = 10.0  #: start times every step_s from the log's first measurement [s]

    def __post_init__(self) -> None:
        for name in ("window_s", "step_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ToolError(f"WindowConfig.{name} must be > 0 s, got {v!r}")


def window_starts(t_first_s: float, t_last_s: float, wc: WindowConfig) -> np.ndarray:
    """Start times [s] of every window that fits in [t_first_s, t_last_s]."""
    n = int(math.floor((t_last_s - t_first_s - wc.window_s) / wc.step_s + 1e-9)) + 1
    if n < 1:
        raise ToolError(f"the log lasts {t_last_s - t_first_s:.1f} s, "
                        f"shorter than one {wc.window_s:g} s window")
    return t_first_s + wc.step_s * np.arange(n)


def _window(measurements, t0: float, t1: float) -> list:
    """The measurements in [t0, t1], the log's own initialisation left out."""
    from sfa.measurements import InitMeas

    return [m for m in measurements if not isinstance(m, InitMeas) and t0 <= m.t_s <= t1]


def run_window(track, measurements, truth: dict, cfg, t0: float, t1: float) -> dict:
    """SFA (``cfg``) and the baselines over [t0, t1], initialised from the truth at t0: each one's
    p95 and max |along-track error| [m], and SFA's interval coverage."""
    from sfa.filter import TrackFilter
    from sfa.measurements import InitMeas
    from tools.accuracy import accuracy
    from tools.baselines import baseline_estimates

    line = next((m.line_id for m in measurements if isinstance(m, InitMeas)), None)
    init = InitMeas(t0, float(np.interp(t0, truth["epoch"], truth["arc_length"])),
                    float(abs(np.interp(t0, truth["epoch"], truth["speed"]))), line, None)
    meas = [init, *_window(measurements, t0, t1)]
    f = TrackFilter(track, cfg)
    rows = []
    for m in meas:
        f.process(m)
        e = f.estimate()
        if math.isfinite(e.epoch_s) and math.isfinite(e.arc_length_m):
            rows.append((e.epoch_s, e.arc_length_m, e.interval_low_m, e.interval_high_m))
    est = np.array(rows, dtype=np.float64).reshape(-1, 4)
    a = accuracy(est[:, 0], est[:, 1], truth["epoch"], truth["arc_length"], est[:, 2], est[:, 3])
    out = {"t0": t0, "sfa_p95": a.p95_m, "sfa_max": a.max_m,
           "sfa_coverage": math.nan if a.coverage is None else a.coverage}
    base = baseline_estimates(track, meas)
    for key, name in (("plain-ekf", "plain FilterPy EKF"), ("odo-dr", "odometer dead reckoning")):
        b = accuracy(base[name]["epoch"], base[name]["arc_length"], truth["epoch"], truth["arc_length"])
        out[f"{key}_p95"], out[f"{key}_max"] = b.p95_m, b.max_m
    return out


def windowed(track, measurements, truth: dict, cfg, wc: WindowConfig = WindowConfig()) -> list[dict]:
    """:func:`run_window` from every start of :func:`window_starts`."""
    t = [m.t_s for m in measurements]
    return [run_window(track, measurements, truth, cfg, float(t0), float(t0) + wc.window_s)
            for t0 in window_starts(min(t), max(t), wc)]


def summary(windows: list[dict], limit_m: float) -> dict:
    """Over the windows: the median, mean and worst of SFA's p95, the windows at or under ``limit_m``,
    the median p95 of each baseline, the windows where SFA's p95 is not above the EKF's, and the
    windows' mean and lowest coverage."""
    p95 = np.array([w["sfa_p95"] for w in windows])
    ekf = np.array([w["plain-ekf_p95"] for w in windows])
    return {
        "windows": len(windows), "limit_m": limit_m,
        "sfa_p95_median": float(np.median(p95)), "sfa_p95_mean": float(np.mean(p95)),
        "sfa_p95_worst": float(np.max(p95)), "within_limit": int(np.sum(p95 <= limit_m)),
        "sfa_max_median": float(np.median([w["sfa_max"] for w in windows])),
        "sfa_coverage_mean": float(np.nanmean([w["sfa_coverage"] for w in windows])),
        "sfa_coverage_min": float(np.nanmin([w["sfa_coverage"] for w in windows])),
        "plain-ekf_p95_median": float(np.median(ekf)),
        "odo-dr_p95_median": float(np.median([w["odo-dr_p95"] for w in windows])),
        "windows_sfa_le_ekf": int(np.sum(p95 <= ekf)),
        "windows_sfa_le_odo": int(np.sum(p95 <= np.array([w["odo-dr_p95"] for w in windows]))),
    }


def markdown_table(rows: list[dict]) -> str:
    """One line per :func:`summary` (with its ``family`` label and ``limit_m``)."""
    lines = ["| log | windows | SFA p95 median / mean / worst [m] | windows with SFA p95 <= limit | "
             "95 % coverage, mean (lowest window) | plain EKF median p95 [m] | odometer DR median p95 [m] | "
             "windows SFA <= EKF | windows SFA <= odometer DR |", "|" + "---|" * 9]
    for r in rows:
        lines.append(
            f"| {r['family']} | {r['windows']} | {r['sfa_p95_median']:.3f} / {r['sfa_p95_mean']:.3f} / "
            f"{r['sfa_p95_worst']:.3f} | {r['within_limit']} (<= {r['limit_m']:g} m) | "
            f"{100 * r['sfa_coverage_mean']:.1f} % ({100 * r['sfa_coverage_min']:.1f} %) | "
            f"{r['plain-ekf_p95_median']:.3f} | {r['odo-dr_p95_median']:.3f} | {r['windows_sfa_le_ekf']} | "
            f"{r['windows_sfa_le_odo']} |")
    return "\n".join(lines)
