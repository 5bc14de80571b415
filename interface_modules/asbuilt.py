"""As-built geometry: the path the simulated train really runs on, which is not the filter's database.

A database digitised from a map (OSM ways, GTFS shapes) is a polyline whose vertices lie near the
real track; its smoothed curvature is the import's (a 20 m Gaussian by default), not the track's.
A simulator that drew its truth from that very database would hand the filter a world that matches
its map exactly (the failure described in docs/simulator.md, "Mismatch"). ``as_built_line`` makes
the truth path instead from the reference line's *source vertices*:

1. the polyline densified to ``step_m``;
2. its corners rounded by a Gaussian of ``corner_sigma_m`` on the positions (a real track has no
   corner; the map's vertex sits on the outside of the real curve), a kernel unlike the database's
   (which smooths the heading with ``smoothing_sigma_m``);
3. a smooth random lateral offset of standard deviation ``lateral_sigma_m`` (digitisation and
   survey error, and the track's own alignment), a sum of sinusoids with wavelengths uniformly
   distributed in log between ``min_wavelength_m`` and ``max_wavelength_m``; its curvature
   perturbation is the offset's second derivative (about ``lateral_sigma_m (2 pi / lambda)^2``);
4. heading, curvature and grade of that path by ``track_db.smoothing.compute_profile`` with
   ``profile_sigma_m`` (numerical only: the path is smooth already).

The result is a ``track_db.TrackLine`` in the reference line's local frame, so every simulator model
(driver, IMU, GNSS) runs on it unchanged. Positions on it map to the reference line's arc length by
projection (``ReferenceMap``): the truth table and GROUND TRUTH are given in the filter's frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class AsBuiltConfig:
    """How the as-built path differs from the digitised line (all lengths in metres)."""

    #: True (the default since session 10): the truth runs on the as-built path; False: on the database
    #: itself (perfect-knowledge mode: label any figure made with it as such, docs/simulator.md)
    enabled: bool = True
    lateral_sigma_m: float = 0.5  #: standard deviation of the random lateral offset [m]
    min_wavelength_m: float = 40.0  #: shortest wavelength of the lateral offset [m]
    max_wavelength_m: float = 800.0  #: longest wavelength of the lateral offset [m]
    components: int = 24  #: sinusoids in the lateral offset [-]
    corner_sigma_m: float = 8.0  #: Gaussian that rounds the map's corners, on positions [m]
    step_m: float = 1.0  #: vertex spacing of the as-built path [m]
    profile_sigma_m: float = 2.0  #: smoothing of the as-built path's own heading profile [m]

    def __post_init__(self) -> None:
        for name in ("lateral_sigma_m", "corner_sigma_m", "profile_sigma_m"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0.0):
                raise ValueError(f"as_built.{name} must be a finite number >= 0, got {v!r}")
        for name in ("min_wavelength_m", "max_wavelength_m", "step_m"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0.0):
                raise ValueError(f"as_built.{name} must be a finite number > 0, got {v!r}")
        if self.max_wavelength_m < self.min_wavelength_m:
            raise ValueError(
                f"as_built.max_wavelength_m ({self.max_wavelength_m!r}) < min_wavelength_m "
                f"({self.min_wavelength_m!r})")
        if not isinstance(self.components, int) or self.components < 1:
            raise ValueError(f"as_built.components must be an integer >= 1, got {self.components!r}")


def _gaussian_smooth(values: np.ndarray, sigma_samples: float) -> np.ndarray:
    """Gaussian smoothing along axis 0 with the ends held (reflect-free: the end samples repeat)."""
    if sigma_samples <= 0.0:
        return values.copy()
    half = int(math.ceil(3.0 * sigma_samples))
    k = np.exp(-0.5 * (np.arange(-half, half + 1) / sigma_samples) ** 2)
    k /= k.sum()
    pad = np.concatenate([np.repeat(values[:1], half, axis=0), values, np.repeat(values[-1:], half, axis=0)])
    out = np.empty_like(values)
    for j in range(values.shape[1]):
        out[:, j] = np.convolve(pad[:, j], k, mode="valid")
    return out


def lateral_offset(s_m: np.ndarray, cfg: AsBuiltConfig, rng: np.random.Generator) -> np.ndarray:
    """Smooth random lateral offset [m] at arc lengths ``s_m``: standard deviation lateral_sigma_m."""
    if cfg.lateral_sigma_m == 0.0:
        return np.zeros_like(s_m)
    lam = np.exp(rng.uniform(math.log(cfg.min_wavelength_m), math.log(cfg.max_wavelength_m), cfg.components))
    phase = rng.uniform(0.0, 2.0 * math.pi, cfg.components)
    # equal power per component: the sum's variance is components * a^2 / 2
    a = cfg.lateral_sigma_m * math.sqrt(2.0 / cfg.components)
    return a * np.sin(2.0 * math.pi * s_m[:, None] / lam[None, :] + phase[None, :]).sum(axis=1)


def as_built_line(reference, cfg: AsBuiltConfig, rng: np.random.Generator):
    """The as-built ``TrackLine`` of ``reference`` (a ``track_db.TrackLine``), see the module doc."""
    from track_db.line import TrackLine
    from track_db.smoothing import compute_profile

    s0 = np.asarray(reference.s_m, dtype=float)
    e0 = np.asarray(reference.east_m, dtype=float)
    n0 = np.asarray(reference.north_m, dtype=float)
    # the source polyline in its own local length (the database's s is geodesic; close to it)
    seg = np.hypot(np.diff(e0), np.diff(n0))
    keep = np.concatenate(([True], seg > 1e-9))
    e0, n0, s0 = e0[keep], n0[keep], s0[keep]
    u = np.concatenate(([0.0], np.cumsum(np.hypot(np.diff(e0), np.diff(n0)))))
    n = max(3, int(math.ceil(u[-1] / cfg.step_m)) + 1)
    grid = np.linspace(0.0, u[-1], n)
    pos = np.column_stack((np.interp(grid, u, e0), np.interp(grid, u, n0)))
    pos = _gaussian_smooth(pos, cfg.corner_sigma_m / (grid[1] - grid[0]))
    # lateral offset along the rounded path's normal (right of travel: (dn, -de) for heading from north)
    d = np.gradient(pos, axis=0)
    d /= np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-12)[:, None]
    normal = np.column_stack((d[:, 1], -d[:, 0]))
    pos = pos + lateral_offset(grid, cfg, rng)[:, None] * normal
    s = np.concatenate(([0.0], np.cumsum(np.hypot(np.diff(pos[:, 0]), np.diff(pos[:, 1])))))
    alt = None
    if getattr(reference, "has_altitude", False):
        alt = np.interp(grid, u, np.asarray(reference.alt_m, dtype=float)[keep])
    prof = compute_profile(s, pos[:, 0], pos[:, 1], alt, sigma_m=cfg.profile_sigma_m,
                           step_m=min(2.0, cfg.step_m * 2.0))
    frame = reference.frame  # the same local frame as the reference (one projection)
    lat, lon = frame.to_geodetic(pos[:, 0], pos[:, 1])
    return TrackLine(
        line_id=reference.line_id,
        name=f"{reference.name} (as built)",
        frame=frame,
        s_m=s,
        lat_deg=np.asarray(lat, dtype=float),
        lon_deg=np.asarray(lon, dtype=float),
        alt_m=alt if alt is not None else np.full(s.size, np.nan),
        east_m=np.ascontiguousarray(pos[:, 0]),
        north_m=np.ascontiguousarray(pos[:, 1]),
        profile_step_m=prof.step_m,
        heading_rad=prof.heading_rad,
        curvature_per_m=prof.curvature_per_m,
        grade=prof.grade,
        has_altitude=alt is not None,
        source="as-built",
        attribution=reference.attribution,
    )


class ReferenceMap:
    """Arc length on the as-built path -> arc length on the reference (database) line, by projection.

    Tabulated once every ``step_m`` along the as-built path (a projection per truth sample would cost
    a spatial query each); the reference arc length is monotone along the path, so it interpolates."""

    def __init__(self, built, reference, step_m: float = 1.0) -> None:
        grid = np.arange(0.0, built.length_m, step_m)
        grid = np.append(grid, built.length_m)
        e, nn = built.point_at(grid)
        s_ref, _offset = reference.project(np.asarray(e), np.asarray(nn))
        s_ref = np.asarray(s_ref, dtype=float)
        self._grid = grid
        self._s_ref = np.maximum.accumulate(np.clip(s_ref, 0.0, reference.length_m))

    def __call__(self, s_built_m):
        return np.interp(s_built_m, self._grid, self._s_ref)

    def inverse(self, s_ref_m):
        """Arc length on the as-built path of the reference arc length ``s_ref_m`` (first passage)."""
        return np.interp(s_ref_m, self._s_ref, self._grid)
