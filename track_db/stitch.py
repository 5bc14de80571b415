"""Stitch the unordered, unoriented parts of a MultiLineString (e.g. the ways of an OSM route relation)
into one continuous polyline.

Policy (docs/track-db.md, "Stitching"):

1. Parts are joined where an end of one lies within ``snap_m`` of an end or an interior vertex of
   another (a part touched in its interior is split there).
2. Pieces that still do not touch are bridged by a straight segment between their nearest ends, if
   that gap is at most ``max_gap_m``; otherwise the import fails and names the gap.
3. The line is the longest shortest path of the resulting graph (its weighted diameter): terminus to
   terminus. Parts off that path (stop spurs, depot links, the far side of a terminal loop, the other
   carriageway where both are mapped) are dropped and reported.
4. Orientation: the path is reversed if that brings its start closer to ``start_hint`` (e.g. the
   relation's "from" stop), or else its end closer to ``end_hint`` (the "to" stop); without a hint
   the direction is that of the diameter search (deterministic for a given file).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from .errors import ImportFailed

__all__ = ["StitchResult", "stitch_parts"]

_EARTH_RADIUS_M = 6_371_008.8


@dataclass(frozen=True)
class StitchResult:
    coords: np.ndarray  #: (n, 2 or 3): lon, lat[, alt] in travel order
    refs: list[str]  #: per vertex: "part p vertex v" (or "gap bridge")
    parts_used: int
    parts_dropped: int
    dropped_length_m: float
    gaps_bridged_m: list[float]


def _metric(coords: np.ndarray, lat0: float, lon0: float) -> np.ndarray:
    """Equirectangular metres around (lat0, lon0): only for matching ends and measuring gaps."""
    x = np.radians(coords[:, 0] - lon0) * _EARTH_RADIUS_M * np.cos(np.radians(lat0))
    y = np.radians(coords[:, 1] - lat0) * _EARTH_RADIUS_M
    return np.column_stack((x, y))


def stitch_parts(
    parts: list[np.ndarray],
    *,
    label: str,
    snap_m: float = 0.5,
    max_gap_m: float = 1000.0,
    start_hint: tuple[float, float] | None = None,
    end_hint: tuple[float, float] | None = None,
) -> StitchResult:
    """Stitch ``parts`` (each (k, 2|3) lon, lat[, alt], k >= 2, already validated finite)."""
    if not parts:
        raise ImportFailed(f"{label}: empty geometry")
    allc = np.concatenate(parts)
    lat0, lon0 = float(allc[:, 1].mean()), float(allc[:, 0].mean())
    # pieces: (coords, metric, refs)
    pieces = [
        (p, _metric(p, lat0, lon0), [f"part {k} vertex {v}" for v in range(len(p))])
        for k, p in enumerate(parts)
    ]

    # 1. split parts touched in their interior by another part's end
    changed = True
    while changed:
        changed = False
        ends = np.array([m[i] for _, m, _ in pieces for i in (0, -1)])
        tree = cKDTree(ends)
        for k, (c, m, r) in enumerate(pieces):
            if len(c) < 3:
                continue
            hits = tree.query_ball_point(m[1:-1], snap_m)
            cut = next((i + 1 for i, h in enumerate(hits) if any(e // 2 != k for e in h)), None)
            if cut is not None:
                pieces[k : k + 1] = [(c[: cut + 1], m[: cut + 1], r[: cut + 1]), (c[cut:], m[cut:], r[cut:])]
                changed = True
                break

    # 2. nodes = clusters of piece ends; edges = pieces
    ends = np.array([m[i] for _, m, _ in pieces for i in (0, -1)])
    n_ends = len(ends)
    pairs = cKDTree(ends).query_pairs(snap_m, output_type="ndarray")
    adj = (
        csr_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n_ends, n_ends))
        if len(pairs)
        else None
    )
    node = connected_components(adj, directed=False)[1] if adj is not None else np.arange(n_ends)
    lengths = [float(np.hypot(*np.diff(m, axis=0).T).sum()) for _, m, _ in pieces]
    edges: list[tuple[int, int, float, int]] = []  # (u, v, length, piece index or -1 for a gap bridge)
    for k in range(len(pieces)):
        edges.append((int(node[2 * k]), int(node[2 * k + 1]), lengths[k], k))
    n_nodes = int(node.max()) + 1
    node_xy = np.zeros((n_nodes, 2))
    node_xy[node] = ends

    # 3. bridge disconnected pieces through their nearest ends
    bridges: dict[tuple[int, int], float] = {}
    while True:
        g = _graph(edges, n_nodes)
        n_comp, comp = connected_components(g, directed=False)
        if n_comp == 1:
            break
        used = np.unique([e[i] for e in edges for i in (0, 1)])
        best = None
        for a in used:
            for b in used:
                if comp[a] < comp[b]:
                    d = float(np.hypot(*(node_xy[a] - node_xy[b])))
                    if best is None or d < best[0]:
                        best = (d, int(a), int(b))
        if best is None or best[0] > max_gap_m:
            gap = (
                ""
                if best is None
                else f"; the nearest are {best[0]:.1f} m apart, more than max_gap_m = {max_gap_m:g} m"
            )
            raise ImportFailed(f"{label}: its parts form {n_comp} disconnected pieces{gap}")
        d, a, b = best
        edges.append((a, b, d, -1))
        bridges[(a, b)] = d

    # 4. weighted diameter
    g = _graph(edges, n_nodes)
    dist, pred = dijkstra(g, directed=False, return_predecessors=True)
    finite = np.where(np.isfinite(dist), dist, -1.0)
    flat = int(np.argmax(finite))
    a, b = divmod(flat, n_nodes)
    path_nodes = [b]
    while path_nodes[-1] != a:
        path_nodes.append(int(pred[a, path_nodes[-1]]))
    path_nodes.reverse()
    for hint_latlon, at_start in ((start_hint, True), (end_hint, False)):
        if hint_latlon is None:
            continue
        hint = _metric(np.array([[hint_latlon[1], hint_latlon[0]]]), lat0, lon0)[0]
        d_first = np.hypot(*(node_xy[path_nodes[0]] - hint))
        d_last = np.hypot(*(node_xy[path_nodes[-1]] - hint))
        if (d_last < d_first) if at_start else (d_first < d_last):
            path_nodes.reverse()
        break

    coords: list[np.ndarray] = []
    refs: list[str] = []
    used_pieces: set[int] = set()
    gaps: list[float] = []
    bridged = False
    for u, v in zip(path_nodes[:-1], path_nodes[1:], strict=True):
        cand = [e for e in edges if {e[0], e[1]} == {u, v}]
        e = min(cand, key=lambda e: (e[2], e[3]))
        if e[3] < 0:
            gaps.append(e[2])
            bridged = True  # the bridge is the straight segment between the two pieces
            continue
        c, _, r = pieces[e[3]]
        used_pieces.add(e[3])
        if node[2 * e[3]] != u:
            c, r = c[::-1], r[::-1]
        if coords and not bridged:
            c, r = c[1:], r[1:]  # the joint vertex is already there
        bridged = False
        coords.append(c)
        refs.extend(r)
    dropped = [k for k in range(len(pieces)) if k not in used_pieces]
    return StitchResult(
        coords=np.concatenate(coords),
        refs=refs,
        parts_used=len(used_pieces),
        parts_dropped=len(dropped),
        dropped_length_m=float(sum(lengths[k] for k in dropped)),
        gaps_bridged_m=gaps,
    )


def _graph(edges, n_nodes: int) -> csr_matrix:
    """Simple weighted graph: the shortest of parallel edges, no self loops."""
    best: dict[tuple[int, int], float] = {}
    for u, v, w, _ in edges:
        if u == v:
            continue
        key = (min(u, v), max(u, v))
        best[key] = min(best.get(key, np.inf), max(w, 1e-9))
    if not best:
        return csr_matrix((n_nodes, n_nodes))
    keys = list(best)
    rows = [k[0] for k in keys]
    cols = [k[1] for k in keys]
    return csr_matrix(([best[k] for k in keys], (rows, cols)), shape=(n_nodes, n_nodes))
