"""GNSS fixes for the smartLoc capture: synthesised from the truth, or a robust single-point solution
from the dataset's pseudoranges; and their error against the truth (see tools.adapters.smartloc)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from tools.adapters.common import GnssNoise, gnss_errors_m
from tools.adapters.smartloc import GEOID_UNDULATION_M, SmartLocData, ecef_to_geodetic
from tools.adapters.spp import SppConfig


@dataclass(frozen=True)
class Fix:
    """One GPS datagram's content."""

    t_s: float
    lat_deg: float
    lon_deg: float
    alt_m: float
    fix_quality: int
    num_sv: int
    sigma_h_m: float
    ecef_m: tuple[float, float, float] | None  #: None: no fix


def fix_epochs(t_s: np.ndarray, rate_hz: float, candidates: np.ndarray | None = None) -> np.ndarray:
    """Epochs at rate_hz within the span of t_s: the whole multiples of 1/rate_hz, or (candidates
    given) the first candidate epoch at or after each multiple and before the next."""
    step = 1.0 / rate_hz
    grid = np.arange(math.ceil(t_s[0] / step) * step, t_s[-1] + 1e-9, step)
    if candidates is None:
        return grid
    c = np.unique(candidates)
    idx = np.searchsorted(c, grid - 1e-6, side="left")
    ok = idx < c.size
    picked = c[idx[ok]]
    picked = picked[picked < grid[ok] + step - 1e-6]
    return np.unique(picked)


def synthetic_fixes(data: SmartLocData, noise: GnssNoise, seed: int) -> list[Fix]:
    """Truth ECEF (linear in time) at each epoch + seeded Gauss-Markov + white error."""
    from pyproj import Geod

    t = fix_epochs(data.gt_t_s, noise.rate_hz)
    ecef = np.column_stack([np.interp(t, data.gt_t_s, data.gt_ecef_m[:, i]) for i in range(3)])
    lat, lon, h = ecef_to_geodetic(ecef)
    err = gnss_errors_m(noise, t, np.random.default_rng(seed))
    az = np.degrees(np.arctan2(err[:, 0], err[:, 1]))
    flon, flat, _ = Geod(ellps="WGS84").fwd(lon, lat, az, np.hypot(err[:, 0], err[:, 1]))
    alt = h - GEOID_UNDULATION_M + err[:, 2]
    return [Fix(float(ti), float(a), float(o), float(al), noise.fix_quality, noise.num_sv,
                 noise.reported_sigma_h_m, None)
            for ti, a, o, al in zip(t, np.asarray(flat), np.asarray(flon), alt, strict=True)]


def spp_fixes(input_path: Path, data: SmartLocData, rate_hz: float, cfg: SppConfig) -> list[Fix]:
    """Robust single-point solutions at rate_hz from the pseudoranges; epochs without a solution are
    sent as 'no fix' (NMEA quality 0), as a receiver reports them."""
    from tools.adapters.spp import read_pseudoranges, solve_all

    pr = read_pseudoranges(input_path)
    epochs = fix_epochs(data.gt_t_s, rate_hz, pr.epochs())
    sols = solve_all(pr, epochs, cfg)
    ok = [s for s in sols if s is not None]
    if ok:
        lat, lon, h = ecef_to_geodetic(np.array([s.ecef_m for s in ok]))
    out: list[Fix] = []
    k = 0
    for t, s in zip(epochs.tolist(), sols, strict=True):
        if s is None:
            out.append(Fix(t, 0.0, 0.0, 0.0, 0, 0, 1.0e5, None))
            continue
        ecef = (float(s.ecef_m[0]), float(s.ecef_m[1]), float(s.ecef_m[2]))
        out.append(Fix(t, float(lat[k]), float(lon[k]), float(h[k]) - GEOID_UNDULATION_M, 1,
                        min(s.used, 255), max(s.sigma_h_m, 0.1), ecef))
        k += 1
    return out


def fix_errors(fixes: list[Fix], data: SmartLocData) -> dict:
    """Horizontal error of the fixes against the ground truth at their epochs (metres)."""
    from pyproj import Geod

    good = [f for f in fixes if f.fix_quality > 0]
    if not good:
        return {"fixes": len(fixes), "with_fix": 0}
    t = np.array([f.t_s for f in good])
    ecef = np.column_stack([np.interp(t, data.gt_t_s, data.gt_ecef_m[:, i]) for i in range(3)])
    lat, lon, _ = ecef_to_geodetic(ecef)
    _, _, d = Geod(ellps="WGS84").inv(lon, lat, [f.lon_deg for f in good], [f.lat_deg for f in good])
    d = np.asarray(d)
    return {
        "fixes": len(fixes),
        "with_fix": len(good),
        "horizontal_error_p50_m": float(np.percentile(d, 50)),
        "horizontal_error_p95_m": float(np.percentile(d, 95)),
        "horizontal_error_max_m": float(d.max()),
        "reported_sigma_h_p50_m": float(np.median([f.sigma_h_m for f in good])),
    }


def gnss_metadata(source: str, seed: int, noise: GnssNoise, spp: SppConfig, stats: dict) -> dict:
    """The ``gnss`` section of metadata.json."""
    if source == "synthetic":
        return {
            "source": "synthesised",
            "how": "truth ECEF linearly interpolated at each fix time + Gauss-Markov + white error "
                   "(east/north, exact discretisation, stationary start) + white vertical error",
            "seed": seed,
            "noise": asdict(noise),
            "total_sigma_per_axis_m": noise.total_sigma_m,
            "altitude": f"ellipsoidal height - {GEOID_UNDULATION_M} m (approximate geoid undulation)",
            "error_vs_truth": stats,
        }
    return {
        "source": "real: robust single-point solution from the pseudorange3 records (tools/adapters/spp.py)",
        "how": "Sagnac-corrected ranges, one clock per satellite system, elevation/C-N0 mask, Cauchy "
               "IRLS, height aiding; sigma_h from the weighted covariance; no solution -> quality 0",
        "rate_hz": noise.rate_hz,
        "settings": asdict(spp),
        "error_vs_truth": stats,
    }
