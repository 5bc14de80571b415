"""Robust single-point GNSS positioning from smartLoc pseudoranges (``pseudorange3`` records).

The records already have satellite clock and atmospheric delays removed (smartLoc readme), so the
model per satellite i of system k is

    rho_i = |sat_i - x| + omega_e (X_i y - Y_i x) / c + b_k + e_i        (Sagnac term, one clock per system)

with e_i ~ N(0, var_i) for line-of-sight signals. In the street canyon many signals are reflected
(NLOS: positive biases of tens of metres), so the solution is an iteratively reweighted least squares
with Cauchy weights w_i = 1 / (1 + (r_i / (k sigma_i))^2), after a mask on elevation and C/N0, and an
optional height aiding (a pseudo-measurement of the geocentric radius at a known ellipsoidal height,
as receivers do in their 2D mode): the NLOS biases otherwise push the solution ~50 m upwards.

Pure functions over arrays; no files are read here except by :func:`read_pseudoranges`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from tools.errors import ToolError

OMEGA_E_RADPS = 7.2921151467e-5  #: Earth rotation rate (WGS84) [rad/s]
C_MPS = 299_792_458.0  #: speed of light [m/s]
WGS84_A_M = 6_378_137.0  #: WGS84 semi-major axis [m]
WGS84_E2 = 6.69437999014e-3  #: WGS84 first eccentricity squared [-]


@dataclass(frozen=True)
class SppConfig:
    """Single-point solution settings."""

    min_elevation_deg: float = 15.0  #: satellites below this elevation are not used [deg]
    min_cn0_dbhz: float = 30.0  #: satellites below this carrier-to-noise density are not used [dB-Hz]
    min_satellites: int = 5  #: fewer usable satellites (after the mask): no fix [count]
    cauchy_k: float = 2.0  #: Cauchy weight scale, in units of each pseudorange's sigma [-]
    height_aiding_m: float | None = 73.0  #: ellipsoidal height of the aiding; None: no aiding [m]
    height_sigma_m: float = 5.0  #: 1-sigma of the height aiding [m]
    max_iterations: int = 30  #: Gauss-Newton iterations per epoch at most [count]
    robust_after: int = 3  #: plain least-squares iterations before the Cauchy weights start [count]

    def __post_init__(self) -> None:
        if self.min_satellites < 4:
            raise ToolError(f"min_satellites must be >= 4, got {self.min_satellites}")
        for name in ("cauchy_k", "height_sigma_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ToolError(f"SppConfig.{name} must be > 0, got {v!r}")


@dataclass(frozen=True)
class Pseudoranges:
    """``pseudorange3`` records, time-ordered."""

    t_s: np.ndarray  #: epoch time stamp [s]
    rho_m: np.ndarray  #: pseudorange [m]
    var_m2: np.ndarray  #: pseudorange variance [m^2]
    sat_ecef_m: np.ndarray  #: (n, 3) satellite position ECEF [m]
    system: np.ndarray  #: 1 GPS, 2 SBAS, 4 GLONASS, 8 Galileo, 16 QZSS, 32 BeiDou
    elevation_deg: np.ndarray  #: satellite elevation [deg]
    cn0_dbhz: np.ndarray  #: carrier-to-noise density [dB-Hz]

    def epochs(self) -> np.ndarray:
        return np.unique(self.t_s)


def read_pseudoranges(path: str | Path) -> Pseudoranges:
    """The ``pseudorange3`` records of a smartLoc input file; failures name file and line."""
    src = Path(path)
    rows: list[list[float]] = []
    try:
        with open(src, encoding="ascii") as fh:
            for no, line in enumerate(fh, start=1):
                if not line.startswith("pseudorange3"):
                    continue
                parts = line.split()
                if len(parts) < 11:
                    raise ToolError(
                        f"{src}:{no}: pseudorange3 record has {len(parts) - 1} fields, expected 10"
                    )
                try:
                    vals = [float(x) for x in parts[1:11]]
                except ValueError:
                    raise ToolError(f"{src}:{no}: pseudorange3 record has a non-numeric field") from None
                if not all(math.isfinite(v) for v in vals) or vals[2] <= 0.0:
                    raise ToolError(
                        f"{src}:{no}: pseudorange3 record has a non-finite value or variance <= 0"
                    )
                rows.append(vals)
    except UnicodeDecodeError as exc:
        raise ToolError(f"{src}: not a smartLoc text file ({exc.reason})") from None
    except OSError as exc:
        raise ToolError(f"cannot read {src}: {exc}") from None
    if not rows:
        raise ToolError(f"{src}: no pseudorange3 records (the bundled copy has them; a copy reduced to "
                        "odom3 records cannot give a single-point solution)")
    a = np.asarray(rows, dtype=np.float64)
    order = np.argsort(a[:, 0], kind="stable")
    a = a[order]
    return Pseudoranges(a[:, 0], a[:, 1], a[:, 2], a[:, 3:6], a[:, 7].astype(int), a[:, 8], a[:, 9])


def predicted_range_m(x_ecef_m: np.ndarray, sat_ecef_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(geometric range + Sagnac correction [m], unit line-of-sight rows d range / d x)."""
    d = sat_ecef_m - x_ecef_m
    dist = np.linalg.norm(d, axis=1)
    sagnac = OMEGA_E_RADPS * (sat_ecef_m[:, 0] * x_ecef_m[1] - sat_ecef_m[:, 1] * x_ecef_m[0]) / C_MPS
    return dist + sagnac, -d / dist[:, None]


def radius_at_height_m(x_ecef_m: np.ndarray, height_m: float) -> float:
    """Geocentric radius of the point at ``height_m`` above the WGS84 ellipsoid below ``x_ecef_m``
    (geodetic latitude by Bowring's single iteration, exact to millimetres near the surface)."""
    x, y, z = (float(v) for v in x_ecef_m)
    p = math.hypot(x, y)
    b = WGS84_A_M * math.sqrt(1.0 - WGS84_E2)
    ep2 = WGS84_E2 / (1.0 - WGS84_E2)
    th = math.atan2(z * WGS84_A_M, p * b)
    lat = math.atan2(z + ep2 * b * math.sin(th) ** 3, p - WGS84_E2 * WGS84_A_M * math.cos(th) ** 3)
    n = WGS84_A_M / math.sqrt(1.0 - WGS84_E2 * math.sin(lat) ** 2)
    return math.hypot((n + height_m) * math.cos(lat), (n * (1.0 - WGS84_E2) + height_m) * math.sin(lat))


@dataclass(frozen=True)
class SppFix:
    """One epoch's solution."""

    t_s: float  #: epoch [s]
    ecef_m: np.ndarray  #: receiver position ECEF [m]
    sigma_h_m: float  #: horizontal 1-sigma per axis from the weighted covariance [m]
    used: int  #: satellites with Cauchy weight >= 0.5 [count]
    masked_in: int  #: satellites that passed the elevation / C/N0 mask [count]


def solve_epoch(
    rho_m: np.ndarray, sigma_m: np.ndarray, sat_ecef_m: np.ndarray, system: np.ndarray, x0_ecef_m: np.ndarray,
    cfg: SppConfig, robust: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(position ECEF, Cauchy weights, 3x3 position covariance) by IRLS; None if singular/divergent."""
    systems = sorted(set(system.tolist()))
    ns = len(systems)
    col = np.array([3 + systems.index(s) for s in system.tolist()])
    x = np.asarray(x0_ecef_m, dtype=float).copy()
    rng, _ = predicted_range_m(x, sat_ecef_m)
    clk = np.array([np.median((rho_m - rng)[system == s]) for s in systems])
    w = np.ones(rho_m.size)
    cov = None
    for it in range(cfg.max_iterations):
        rng, los = predicted_range_m(x, sat_ecef_m)
        r = rho_m - rng - clk[col - 3]  # residual y = z - h(x)
        if robust and it >= cfg.robust_after:
            w = 1.0 / (1.0 + (r / (cfg.cauchy_k * sigma_m)) ** 2)  # Cauchy IRLS weights
        H = np.zeros((rho_m.size, 3 + ns))
        H[:, :3] = los
        H[np.arange(rho_m.size), col] = 1.0
        W = w / sigma_m ** 2
        A = H.T @ (H * W[:, None])  # normal matrix H' W H
        b = H.T @ (W * r)
        if cfg.height_aiding_m is not None and np.linalg.norm(x) > 6.0e6:
            up = np.zeros(3 + ns)
            up[:3] = x / np.linalg.norm(x)  # d|x| / dx
            target = radius_at_height_m(x, cfg.height_aiding_m)
            A += np.outer(up, up) / cfg.height_sigma_m ** 2
            b += up * (target - np.linalg.norm(x)) / cfg.height_sigma_m ** 2
        try:
            dx = np.linalg.solve(A, b)
            cov = np.linalg.inv(A)[:3, :3]
        except np.linalg.LinAlgError:
            return None
        if not np.all(np.isfinite(dx)):
            return None
        x += dx[:3]
        clk += dx[3:]
        if np.linalg.norm(dx[:3]) < 1e-3 and it >= cfg.robust_after + 2:
            break
    if not np.all(np.isfinite(x)) or not 6.2e6 < np.linalg.norm(x) < 6.5e6:
        return None
    return x, w, cov


def enu_rotation(x_ecef_m: np.ndarray) -> np.ndarray:
    """Rows east, north, up at the geocentric direction of ``x_ecef_m`` (enough for a covariance)."""
    x, y, z = (float(v) for v in x_ecef_m)
    lon = math.atan2(y, x)
    lat = math.atan2(z, math.hypot(x, y))
    sl, cl, so, co = math.sin(lat), math.cos(lat), math.sin(lon), math.cos(lon)
    return np.array([[-so, co, 0.0], [-sl * co, -sl * so, cl], [cl * co, cl * so, sl]])


def solve_all(pr: Pseudoranges, epochs_s: np.ndarray, cfg: SppConfig) -> list[SppFix | None]:
    """A solution per requested epoch (None: too few satellites or no convergence). The first solution
    starts from the Earth's centre with plain least squares; later ones from the previous solution."""
    out: list[SppFix | None] = []
    x_prev: np.ndarray | None = None
    for t in epochs_s.tolist():
        m = pr.t_s == t
        m &= (pr.elevation_deg >= cfg.min_elevation_deg) & (pr.cn0_dbhz >= cfg.min_cn0_dbhz)
        n = int(m.sum())
        if n < cfg.min_satellites:
            out.append(None)
            continue
        args = (pr.rho_m[m], np.sqrt(pr.var_m2[m]), pr.sat_ecef_m[m], pr.system[m])
        start = x_prev
        if start is None:
            first = solve_epoch(*args, np.zeros(3), replace(cfg, height_aiding_m=None), robust=False)
            if first is None:
                out.append(None)
                continue
            start = first[0]
        res = solve_epoch(*args, start, cfg)
        if res is None:
            out.append(None)
            continue
        x, w, cov = res
        rot = enu_rotation(x)
        cen = rot @ cov @ rot.T
        sigma_h = math.sqrt(max(0.5 * (cen[0, 0] + cen[1, 1]), 0.0))
        out.append(SppFix(t, x, sigma_h, int(np.sum(w >= 0.5)), n))
        x_prev = x
    return out
