"""Local refinement of a tetrahedral mesh by longest-edge bisection, the refinement of the
adaptive loop in 3D (docs/adaptivity.md).

A tetrahedron is bisected through the midpoint of its longest edge into two (Rivara & Levin,
Commun. Appl. Numer. Methods 8 (1992) 281-290). Conformity comes from the closure: every
tetrahedron that holds an edge to be cut must cut its own longest edge first, so the set of
edges to cut grows until no tetrahedron asks for more; then each of them is cut in one
round, and rounds repeat until no tetrahedron holds a cut edge (Rivara's longest-edge
propagation, which terminates). Ties between edges of equal length are broken by the
edge's node pair, one total order over the mesh's edges, so that two tetrahedra sharing
their longest edge agree on it.

The refinement is nested (each tetrahedron is the union of its children: a flat face stays
flat, a coarser P1 field is exactly a finer one) and every boundary triangle that a cut
edge crosses is halved with it, each half keeping its role label. A curved boundary keeps
the chords of the first mesh: new nodes are midpoints, not points on the curve.
"""

from __future__ import annotations

import numpy as np

from harness.mesh.simplex import EDGES, SimplexMesh, positively_oriented

SPAN = np.int64(1) << 31  # node indices stay below 2^31: one int64 key per edge or face part


def start(points: np.ndarray, cells: np.ndarray, facets: np.ndarray, labels: np.ndarray,
          regions: np.ndarray | None = None) -> SimplexMesh:
    return SimplexMesh(points[:, :3].astype(float), cells.astype(np.int64), facets.astype(np.int64),
                       labels.astype(np.int64), regions)


def edge_key(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.minimum(a, b).astype(np.int64) * SPAN + np.maximum(a, b)


def longest_edges(points: np.ndarray, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each cell's refinement edge as local vertex indices (i, j): its longest edge, ties to the
    smaller edge key. Returns (M,) i and (M,) j."""
    pairs = np.array(EDGES[3])                                        # (6, 2)
    ends = cells[:, pairs]                                            # (M, 6, 2)
    length = np.linalg.norm(points[ends[..., 0]] - points[ends[..., 1]], axis=2)
    keys = edge_key(ends[..., 0], ends[..., 1])
    order = _longest_then_smallest_key(length, keys)
    return pairs[order, 0], pairs[order, 1]


def _longest_then_smallest_key(length: np.ndarray, keys: np.ndarray) -> np.ndarray:
    best = np.zeros(len(length), dtype=np.int64)
    for k in range(1, length.shape[1]):
        rows = np.arange(len(length))
        better = (length[:, k] > length[rows, best]) | (
            (length[:, k] == length[rows, best]) & (keys[:, k] < keys[rows, best]))
        best[better] = k
    return best


def refinement_keys(points: np.ndarray, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    i, j = longest_edges(points, cells)
    rows = np.arange(len(cells))
    a, b = cells[rows, i], cells[rows, j]
    return edge_key(a, b), i, j


def cell_edge_keys(cells: np.ndarray) -> np.ndarray:
    return np.column_stack([edge_key(cells[:, i], cells[:, j]) for i, j in EDGES[3]])


def refine(mesh: SimplexMesh, marked: np.ndarray) -> SimplexMesh:
    """`mesh` with the marked tetrahedra (a boolean mask) bisected at their longest edges, and as
    many others as conformity needs; each child lies in its parent's region."""
    points, cells, regions = mesh.points, mesh.cells, mesh.cell_labels()
    facets, labels = mesh.facets, mesh.labels
    ref, _, _ = refinement_keys(points, cells)
    pending = np.unique(ref[np.asarray(marked, dtype=bool)])
    midpoints: dict[int, int] = {}
    while len(pending):
        ref, i, j = refinement_keys(points, cells)
        edges = cell_edge_keys(cells)
        while True:  # the closure on the current mesh
            asks = np.isin(edges, pending).any(axis=1) & ~np.isin(ref, pending)
            if not asks.any():
                break
            pending = np.union1d(pending, ref[asks])
        split = np.isin(ref, pending)
        rows = np.flatnonzero(split)
        a, b = cells[rows, i[rows]], cells[rows, j[rows]]
        cut = edge_key(a, b)
        fresh = np.unique(cut[[k not in midpoints for k in cut.tolist()]])
        lo, hi = fresh // SPAN, fresh % SPAN
        first = len(points)
        points = np.vstack([points, 0.5 * (points[lo] + points[hi])])
        midpoints.update(zip(fresh.tolist(), range(first, first + len(fresh))))
        m = np.array([midpoints[k] for k in cut.tolist()], dtype=np.int64)
        # the children: the parent with a replaced by m, and with b replaced by m
        one, two = cells[rows].copy(), cells[rows].copy()
        one[np.arange(len(rows)), i[rows]] = m
        two[np.arange(len(rows)), j[rows]] = m
        facets, labels = _halve_facets(facets, labels, cells[rows], i[rows], j[rows], m)
        cells = np.vstack([cells[~split], one, two])
        regions = np.concatenate([regions[~split], regions[rows], regions[rows]])
        pending = np.intersect1d(pending, cell_edge_keys(cells).ravel())
    return SimplexMesh(points, cells, facets, labels, regions if mesh.regions is not None else None)


def _halve_facets(facets: np.ndarray, labels: np.ndarray, split: np.ndarray, i: np.ndarray, j: np.ndarray,
                  m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The boundary triangles that are faces of the tetrahedra `split` (cut at their local edge
    (i, j), midpoint m) and hold that edge, each as its two halves with its label. A boundary
    triangle holding an edge another tetrahedron cuts waits for its own tetrahedron's turn."""
    if not len(facets):
        return facets, labels
    halving: dict[tuple[int, ...], tuple[int, int, int]] = {}
    for cell, p, q, mid in zip(split.tolist(), i.tolist(), j.tolist(), m.tolist()):
        a, b = cell[p], cell[q]
        for other in (c for k, c in enumerate(cell) if k not in (p, q)):
            halving[tuple(sorted((a, b, other)))] = (a, b, mid)
    keep, halves, halves_labels = np.ones(len(facets), dtype=bool), [], []
    for row, face in enumerate(facets.tolist()):
        found = halving.get(tuple(sorted(face)))
        if found is None:
            continue
        a, b, mid = found
        c = next(v for v in face if v not in (a, b))
        halves += [(a, mid, c), (mid, b, c)]
        halves_labels += [labels[row], labels[row]]
        keep[row] = False
    if not halves:
        return facets, labels
    return (np.vstack([facets[keep], np.array(halves, dtype=np.int64)]),
            np.concatenate([labels[keep], np.array(halves_labels, dtype=np.int64)]))


def uniform(mesh: SimplexMesh, times: int = 3) -> SimplexMesh:
    """`times` rounds, each bisecting every tetrahedron once at least (the closure may cut some
    twice): 3 rounds make 8 or more children of each."""
    for _ in range(times):
        mesh = refine(mesh, np.ones(len(mesh.cells), dtype=bool))
    return mesh


def oriented(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    return positively_oriented(points, cells)
