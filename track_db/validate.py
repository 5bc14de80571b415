"""Validation of imported line geometry; every failure names the line, the vertex (row) and the reason."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .errors import ImportFailed
from .geodesy import segment_lengths_m

__all__ = ["CUSP_DEG", "DUPLICATE_TOLERANCE_M", "max_turn_deg", "validate_vertices"]

#: consecutive vertices closer than this are "duplicated points" [m]
DUPLICATE_TOLERANCE_M = 1e-3

#: a vertex where the polyline turns by more than this is a reversal cusp (the route doubles back) [deg]
CUSP_DEG = 150.0


def max_turn_deg(lat_deg: np.ndarray, lon_deg: np.ndarray) -> float:
    """Largest change of direction at a vertex of the polyline [deg] (equirectangular, for screening)."""
    lat = np.asarray(lat_deg, dtype=np.float64)
    if lat.size < 3:
        return 0.0
    x = np.radians(np.asarray(lon_deg, dtype=np.float64)) * np.cos(np.radians(np.mean(lat)))
    h = np.arctan2(np.diff(x), np.diff(np.radians(lat)))
    if h.size < 2:
        return 0.0
    return float(np.degrees(np.max(np.abs(np.angle(np.exp(1j * np.diff(h)))))))


def _where(label: str, refs: Sequence[str] | None, k: int) -> str:
    ref = refs[k] if refs is not None and k < len(refs) else f"vertex {k}"
    return f"{label}: {ref}"


def validate_vertices(
    label: str,
    lat_deg: np.ndarray,
    lon_deg: np.ndarray,
    alt_m: np.ndarray | None,
    *,
    max_gap_m: float,
    refs: Sequence[str] | None = None,
) -> np.ndarray:
    """Check one line's vertices; return its geodesic segment lengths [m]. Raises ImportFailed."""
    n = lat_deg.size
    if n == 0:
        raise ImportFailed(f"{label}: empty geometry")
    if lon_deg.size != n or (alt_m is not None and alt_m.size != n):
        raise ImportFailed(f"{label}: latitude, longitude and altitude arrays differ in length")
    for name, arr in (("latitude", lat_deg), ("longitude", lon_deg), ("altitude", alt_m)):
        if arr is None:
            continue
        bad = np.flatnonzero(~np.isfinite(arr))
        if bad.size:
            raise ImportFailed(f"{_where(label, refs, int(bad[0]))}: non-finite {name} ({arr[bad[0]]})")
    bad = np.flatnonzero(np.abs(lat_deg) > 90.0)
    if bad.size:
        raise ImportFailed(
            f"{_where(label, refs, int(bad[0]))}: latitude {lat_deg[bad[0]]} outside [-90, 90]"
        )
    bad = np.flatnonzero(np.abs(lon_deg) > 180.0)
    if bad.size:
        raise ImportFailed(
            f"{_where(label, refs, int(bad[0]))}: longitude {lon_deg[bad[0]]} outside [-180, 180]"
        )
    if n < 2:
        raise ImportFailed(f"{label}: empty geometry (a line needs at least 2 vertices, got {n})")
    seg = segment_lengths_m(lat_deg, lon_deg)
    dup = np.flatnonzero(seg < DUPLICATE_TOLERANCE_M)
    if dup.size:
        k = int(dup[0])
        raise ImportFailed(
            f"{_where(label, refs, k + 1)}: duplicated point (same position as the previous vertex, "
            f"{seg[k]:.4f} m apart)"
        )
    gap = np.flatnonzero(seg > max_gap_m)
    if gap.size:
        k = int(gap[0])
        raise ImportFailed(
            f"{_where(label, refs, k + 1)}: gap of {seg[k]:.1f} m from the previous vertex exceeds "
            f"max_gap_m = {max_gap_m:g} m"
        )
    return seg
