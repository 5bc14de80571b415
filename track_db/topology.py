"""Network topology: junctions where lines share vertices or meet within a tolerance.

Method (docs/track-db.md explains it with the Jena and Euskotren numbers):

1. Nodes: every vertex of every line; vertices closer than ``tolerance_m`` are one node
   (single-linkage clusters in the local metric frame).
2. A vertex within ``tolerance_m`` of the interior of another line's segment (no vertex there) also
   becomes a visit of that other line, at the projected arc length (T-junctions, parallel digitising).
3. Each line is the sequence of nodes it visits in order of arc length; the network graph joins
   consecutive nodes. A node with three or more distinct neighbours is a branch point.
4. At a branch point, two visits (of different lines, or the same line passing twice) form a junction
   unless they use the same pair of neighbouring nodes (the same track through the point, in either
   direction). ``kind`` is ``"diverge"`` when they share one side and part on the other, ``"crossing"``
   when they share no neighbour, and ``"end"`` when one of the two lines starts or ends there.

Lines that cross in plan without a common vertex (bridges, tunnels) are not junctions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

__all__ = ["JunctionRow", "find_junctions"]


@dataclass(frozen=True)
class JunctionRow:
    node_id: int  #: branch point number, 1.. in order of first appearance
    kind: str  #: "diverge", "crossing" or "end"
    line_a: int
    s_a_m: float
    line_b: int
    s_b_m: float
    east_m: float
    north_m: float


@dataclass(frozen=True)
class _Visit:
    line: int
    s_m: float
    node: int


def _cluster_nodes(xy: np.ndarray, tolerance_m: float) -> np.ndarray:
    n = xy.shape[0]
    pairs = cKDTree(xy).query_pairs(tolerance_m, output_type="ndarray")
    graph = (
        coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n)) if len(pairs) else None
    )
    if graph is None:
        return np.arange(n)
    _, labels = connected_components(graph, directed=False)
    # renumber by first vertex so that node ids do not depend on scipy's internal order
    _, first = np.unique(labels, return_index=True)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    return rank[labels]


def find_junctions(
    line_ids: list[int],
    s_m: list[np.ndarray],
    east_m: list[np.ndarray],
    north_m: list[np.ndarray],
    tolerance_m: float,
) -> list[JunctionRow]:
    """Junctions of a network given each line's per-vertex arc length and local coordinates."""
    if not line_ids:
        return []
    counts = [a.size for a in s_m]
    xy = np.column_stack((np.concatenate(east_m), np.concatenate(north_m)))
    owner = np.repeat(np.arange(len(line_ids)), counts)
    vidx = np.concatenate([np.arange(c) for c in counts])
    starts = np.concatenate(([0], np.cumsum(counts)[:-1]))
    node = _cluster_nodes(xy, tolerance_m)
    node_xy: dict[int, np.ndarray] = {}
    for nd in np.unique(node):
        node_xy[int(nd)] = xy[node == nd].mean(axis=0)

    visits: list[list[_Visit]] = [
        [_Visit(li, float(s_m[k][i]), int(node[starts[k] + i])) for i in range(counts[k])]
        for k, li in enumerate(line_ids)
    ]

    # vertices near the interior of other segments
    seg_start = np.concatenate([starts[k] + np.arange(counts[k] - 1) for k in range(len(line_ids))])
    seg_geoms = shapely.linestrings(np.stack((xy[seg_start], xy[seg_start + 1]), axis=1))
    tree = shapely.STRtree(seg_geoms)
    pts = shapely.points(xy)
    vi, si = tree.query(pts, predicate="dwithin", distance=tolerance_m)
    a = seg_start[si]
    b = a + 1
    keep = (node[vi] != node[a]) & (node[vi] != node[b])
    keep &= ~((owner[vi] == owner[a]) & ((vi == a) | (vi == b)))
    for v, sa in zip(vi[keep], a[keep], strict=True):
        k = int(owner[sa])
        p0, p1 = xy[sa], xy[sa + 1]
        d = p1 - p0
        t = float(np.clip(np.dot(xy[v] - p0, d) / np.dot(d, d), 0.0, 1.0))
        i = int(vidx[sa])
        s = float(s_m[k][i] + t * (s_m[k][i + 1] - s_m[k][i]))
        visits[k].append(_Visit(line_ids[k], s, int(node[v])))

    # node sequences; neighbours; degrees
    seqs: list[list[_Visit]] = []
    for vs in visits:
        vs.sort(key=lambda v: (v.s_m, v.node))
        seq: list[_Visit] = []
        for v in vs:
            if not seq or seq[-1].node != v.node:
                seq.append(v)
        seqs.append(seq)
    neighbours: dict[int, set[int]] = {}
    at_node: dict[int, list[tuple[_Visit, frozenset[int], bool]]] = {}
    for seq in seqs:
        for j, v in enumerate(seq):
            nb = set()
            if j > 0:
                nb.add(seq[j - 1].node)
            if j + 1 < len(seq):
                nb.add(seq[j + 1].node)
            neighbours.setdefault(v.node, set()).update(nb)
            is_end = j == 0 or j == len(seq) - 1
            at_node.setdefault(v.node, []).append((v, frozenset(nb), is_end))

    branch_nodes = sorted((nd for nd, nb in neighbours.items() if len(nb) >= 3), key=lambda nd: int(nd))
    rows: list[JunctionRow] = []
    for number, nd in enumerate(branch_nodes, start=1):
        here = at_node[nd]
        for p in range(len(here)):
            for q in range(p + 1, len(here)):
                (va, nba, enda), (vb, nbb, endb) = here[p], here[q]
                if nba == nbb:
                    continue  # same track through the node
                if (va.line, va.s_m) > (vb.line, vb.s_m):
                    va, vb = vb, va
                kind = "end" if (enda or endb) else ("crossing" if not (nba & nbb) else "diverge")
                e, n = node_xy[nd]
                rows.append(JunctionRow(number, kind, va.line, va.s_m, vb.line, vb.s_m, float(e), float(n)))
    rows.sort(key=lambda r: (r.node_id, r.line_a, r.s_a_m, r.line_b, r.s_b_m))
    return rows
