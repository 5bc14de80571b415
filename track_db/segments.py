"""Nearest-segment projection in the local metric frame (shapely 2 STRtree + vectorised numpy).

The tree finds, for each query point, the nearest segment(s); the foot point, arc length and signed
lateral offset are then computed exactly with numpy. Ties (a point equally near several segments,
e.g. on a trunk shared by several lines) go to the lowest line id, then the lowest arc length, so
results are deterministic. Segments that coincide (to 0.1 mm, in either direction) are indexed once,
through the occurrence the tie rule would choose.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely

__all__ = ["NearestResult", "SegmentIndex", "project_onto_segments"]

#: distances equal within this are ties [m]
_TIE_M = 1e-6
#: segments whose ends agree to this are indexed once, through their representative [m]
_SAME_M = 1e-4


@dataclass(frozen=True)
class NearestResult:
    """Per query point: the nearest segment and the projection onto it (arrays of equal length)."""

    segment: np.ndarray  #: index of the segment in the SegmentIndex
    line_id: np.ndarray  #: line of that segment (int64)
    s_m: np.ndarray  #: arc length of the foot point [m]
    offset_m: np.ndarray  #: signed lateral offset, > 0 to the right of the direction of travel [m]
    distance_m: np.ndarray  #: distance to the line [m] (= |offset_m|)


def project_onto_segments(px, py, x0, y0, dx, dy, s0, ds):
    """Foot point parameter, arc length, signed offset and distance of points onto given segments."""
    len2 = dx * dx + dy * dy
    t = np.clip(((px - x0) * dx + (py - y0) * dy) / len2, 0.0, 1.0)
    rx = px - (x0 + t * dx)
    ry = py - (y0 + t * dy)
    dist = np.hypot(rx, ry)
    cross = dx * ry - dy * rx  # > 0: point to the left of the direction of travel (east-north frame)
    offset = np.where(cross > 0, -dist, dist)
    return t, s0 + t * ds, offset, dist


class SegmentIndex:
    """All segments of one line or of a whole network, indexed for nearest-segment queries."""

    def __init__(self, line_id, s0, s1, x0, y0, x1, y1) -> None:
        self.line_id = np.ascontiguousarray(line_id, dtype=np.int64)
        self.s0 = np.ascontiguousarray(s0, dtype=np.float64)
        self.ds = np.ascontiguousarray(s1, dtype=np.float64) - self.s0
        self.x0 = np.ascontiguousarray(x0, dtype=np.float64)
        self.y0 = np.ascontiguousarray(y0, dtype=np.float64)
        self.dx = np.ascontiguousarray(x1, dtype=np.float64) - self.x0
        self.dy = np.ascontiguousarray(y1, dtype=np.float64) - self.y0
        # Identical segments (shared trunks: the same vertices in several lines, in either direction) are
        # indexed once, through their representative: the occurrence with the lowest line id, then the
        # lowest arc length, which is also the tie rule. Fewer, non-overlapping segments make the
        # tree's nearest search several times faster on real networks.
        x1a = self.x0 + self.dx
        y1a = self.y0 + self.dy
        swap = (self.x0 > x1a) | ((self.x0 == x1a) & (self.y0 > y1a))
        key = np.column_stack(
            (
                np.where(swap, x1a, self.x0),
                np.where(swap, y1a, self.y0),
                np.where(swap, self.x0, x1a),
                np.where(swap, self.y0, y1a),
            )
        )
        order = np.lexsort((self.s0, self.line_id))  # candidates in tie-rule order
        # segments equal to 0.1 mm are one geometry (transforms of the same vertex can differ by ~1e-12 m)
        _, first = np.unique(np.round(key[order] / _SAME_M), axis=0, return_index=True)
        self._rep = np.sort(order[first])  # representative segment of each distinct geometry
        coords = np.stack(
            (
                np.column_stack((self.x0[self._rep], self.y0[self._rep])),
                np.column_stack((x1a[self._rep], y1a[self._rep])),
            ),
            axis=1,
        )
        self._tree = shapely.STRtree(shapely.linestrings(coords))

    @classmethod
    def for_line(cls, line_id: int, s_m, east_m, north_m) -> SegmentIndex:
        n = len(s_m) - 1
        return cls(np.full(n, line_id), s_m[:-1], s_m[1:], east_m[:-1], north_m[:-1], east_m[1:], north_m[1:])

    @classmethod
    def for_lines(cls, lines) -> SegmentIndex:
        """``lines``: iterable of (line_id, s_m, east_m, north_m)."""
        parts = [cls._parts(*ln) for ln in lines]
        return cls(*(np.concatenate([p[k] for p in parts]) for k in range(7)))

    @staticmethod
    def _parts(line_id, s, e, n):
        return (np.full(len(s) - 1, line_id), s[:-1], s[1:], e[:-1], n[:-1], e[1:], n[1:])

    def nearest(self, east_m: np.ndarray, north_m: np.ndarray) -> NearestResult:
        """Nearest segment of each point (finite coordinates, 1-D arrays)."""
        px = np.ascontiguousarray(east_m, dtype=np.float64)
        py = np.ascontiguousarray(north_m, dtype=np.float64)
        pairs = self._tree.query_nearest(shapely.points(px, py), all_matches=True)
        q, seg = pairs[0], self._rep[pairs[1]]
        _, s, off, dist = project_onto_segments(
            px[q], py[q], self.x0[seg], self.y0[seg], self.dx[seg], self.dy[seg], self.s0[seg], self.ds[seg]
        )
        if q.size != px.size:  # ties: lowest distance, then line id, then arc length
            order = np.lexsort((s, self.line_id[seg], np.round(dist / _TIE_M), q))
            q, seg, s, off, dist = q[order], seg[order], s[order], off[order], dist[order]
            first = np.flatnonzero(np.concatenate(([True], q[1:] != q[:-1])))
            q, seg, s, off, dist = q[first], seg[first], s[first], off[first], dist[first]
        out = np.empty(px.size, dtype=np.int64)
        out[q] = np.arange(q.size)
        return NearestResult(seg[out], self.line_id[seg[out]], s[out], off[out], dist[out])
