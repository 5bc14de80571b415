"""Figures of a replay against truth: errors, GNSS outages, interval coverage, NEES, ETCS compliance."""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

import numpy as np

from tools.accuracy import accuracy, along_track_errors
from tools.errors import ToolError

#: Outcome codes (sfa.layout.Outcome) that mean "a GNSS fix was available"
_GPS_AVAILABLE = (0, 1, 7)  # accepted, gated, held off
_GPS_ACCEPTED = 0


def read_truth_csv(path: str | Path) -> dict[str, np.ndarray]:
    """Read a truth CSV (header row; at least epoch, arc_length, speed; epochs ascending)."""
    p = Path(path)
    try:
        fh = open(p, newline="")  # noqa: SIM115 - closed below
    except OSError as exc:
        raise ToolError(f"{p}: cannot open truth file: {exc.strerror or exc}") from exc
    with fh:
        reader = csv.reader(fh)
        try:
            header = next(reader)
        except StopIteration:
            raise ToolError(f"{p}: empty truth file") from None
        except (csv.Error, UnicodeDecodeError) as exc:
            raise ToolError(f"{p}: not a CSV file ({exc})") from exc
        cols = [h.strip() for h in header]
        for need in ("epoch", "arc_length", "speed"):
            if need not in cols:
                raise ToolError(f"{p}: truth CSV lacks the column {need!r} (has {', '.join(cols)})")
        names = ["epoch", "arc_length", "speed"]
        if "lat" in cols and "lon" in cols:  # sfa sim's truth has the true path too (for the map)
            names += ["lat", "lon"]
        idx = {name: cols.index(name) for name in names}
        rows: dict[str, list[float]] = {k: [] for k in idx}
        try:
            for lineno, row in enumerate(reader, start=2):
                if not row:
                    continue
                for name, i in idx.items():
                    try:
                        v = float(row[i])
                    except (IndexError, ValueError):
                        raise ToolError(f"{p}: line {lineno}: bad {name} value") from None
                    if not math.isfinite(v):
                        raise ToolError(f"{p}: line {lineno}: {name} is not finite")
                    rows[name].append(v)
        except (csv.Error, UnicodeDecodeError) as exc:
            raise ToolError(f"{p}: not a CSV file ({exc})") from exc
    out = {k: np.array(v, dtype=float) for k, v in rows.items()}
    if out["epoch"].size < 2:
        raise ToolError(f"{p}: truth needs at least two rows")
    if np.any(np.diff(out["epoch"]) <= 0):
        k = int(np.argmax(np.diff(out["epoch"]) <= 0)) + 3
        raise ToolError(f"{p}: line {k}: epochs must be strictly ascending")
    return out


def gnss_outages(updates: dict[str, np.ndarray], min_gap_s: float = 3.0) -> list[tuple[float, float]]:
    """Intervals (sensor time) without an available GNSS fix for longer than ``min_gap_s``."""
    kind = updates["kind"]
    if kind.size == 0:
        return []
    gps = kind == "gps"
    t_all = updates["t"][gps]
    avail = np.isin(updates["outcome"][gps], _GPS_AVAILABLE)
    t = t_all[avail]
    start, end = float(updates["t"][0]), float(updates["t"][-1])
    edges = np.concatenate(([start], t, [end]))
    gaps = np.diff(edges)
    return [(float(edges[i]), float(edges[i + 1])) for i in np.nonzero(gaps > min_gap_s)[0]]


def _in_intervals(t: np.ndarray, intervals: list[tuple[float, float]]) -> np.ndarray:
    mask = np.zeros(t.shape, dtype=bool)
    for a, b in intervals:
        mask |= (t >= a) & (t <= b)
    return mask


def _nees_band(n: int, p: float = 0.95) -> tuple[float, float]:
    """Two-sided ``p`` band of the mean of ``n`` chi-square(1) variables (Wilson-Hilferty)."""
    if n <= 0:
        return (math.nan, math.nan)
    z = 1.959963984540054 if abs(p - 0.95) < 1e-12 else _z_of(p)
    a = 2.0 / (9.0 * n)

    def q(zz: float) -> float:
        return max(0.0, (1.0 - a + zz * math.sqrt(a)) ** 3)

    return (q(-z), q(z))


def _z_of(p: float) -> float:
    from statistics import NormalDist

    return NormalDist().inv_cdf(0.5 + p / 2.0)


def replay_metrics(result, truth: dict[str, np.ndarray] | None) -> dict[str, Any]:
    """metrics.json content: accuracy figures (with truth) plus every pipeline counter."""
    new = result.new_estimates()
    out: dict[str, Any] = {
        "label": result.label,
        "messages": int(result.datagrams),
        "skipped_disabled_sensor": int(result.skipped_sensor),
        "outputs": int(result.estimates["epoch"].size),
        "new_estimates": int(new["epoch"].size),
        "retransmissions": int(result.estimates["epoch"].size - new["epoch"].size),
        "capture": result.capture,
        "pipeline": result.metrics,
    }
    outages = gnss_outages(result.updates)
    out["gnss_outages"] = [[a, b] for a, b in outages]
    status = new["status"]
    if status.size:
        out["status_fraction"] = {
            name: float(np.mean(status == code))
            for code, name in enumerate(("initialising", "nominal", "degraded", "lost"))
        }
    if truth is None or new["epoch"].size == 0:
        return out
    t = new["epoch"]
    acc = accuracy(
        t, new["arc_length"], truth["epoch"], truth["arc_length"], new["interval_low"], new["interval_high"]
    )
    out.update(
        rms_m=acc.rms_m,
        p50_m=acc.p50_m,
        p95_m=acc.p95_m,
        max_m=acc.max_m,
        compared=acc.n,
        interval_coverage=acc.coverage,
    )
    err = along_track_errors(t, new["arc_length"], truth["epoch"], truth["arc_length"])
    ok = np.isfinite(err)
    in_out = _in_intervals(t, outages) & ok
    out["outage_max_m"] = float(np.max(np.abs(err[in_out]))) if in_out.any() else None
    out["outage_p95_m"] = float(np.percentile(np.abs(err[in_out]), 95)) if in_out.any() else None
    # NEES of the arc length, subsampled to one estimate per second (neighbouring errors are correlated)
    sigma = new["sigma"]
    good = ok & np.isfinite(sigma) & (sigma > 0)
    if good.any():
        tt = t[good]
        keep = np.concatenate(([True], np.floor(tt[1:]) != np.floor(tt[:-1])))
        nees = (err[good][keep] / sigma[good][keep]) ** 2
        lo, hi = _nees_band(int(nees.size))
        out["nees_mean"] = float(np.mean(nees))
        out["nees_band_95"] = [lo, hi]
        out["nees_samples"] = int(nees.size)
    # ETCS odometry accuracy: |error| <= 5 m + 5 % of the distance travelled since the last
    # accepted GNSS fix (the fix plays the role of the reference location)
    upd = result.updates
    acc_fix_t = upd["t"][(upd["kind"] == "gps") & (upd["outcome"] == _GPS_ACCEPTED)]
    s_truth = np.interp(t, truth["epoch"], truth["arc_length"])
    if acc_fix_t.size:
        k = np.searchsorted(acc_fix_t, t, side="right") - 1
        ref_t = np.where(k >= 0, acc_fix_t[np.clip(k, 0, None)], truth["epoch"][0])
    else:
        ref_t = np.full(t.shape, truth["epoch"][0])
    s_ref = np.interp(ref_t, truth["epoch"], truth["arc_length"])
    bound = 5.0 + 0.05 * np.abs(s_truth - s_ref)
    out["etcs_compliance"] = float(np.mean(np.abs(err[ok]) <= bound[ok])) if ok.any() else None
    return out
