"""Local refinement of a triangle mesh by newest-vertex bisection, the refinement of the
adaptive loop in 2D (docs/adaptivity.md).

Each triangle carries a refinement edge and, opposite it, its newest vertex; a triangle is
bisected through the midpoint of its refinement edge, and the midpoint becomes the newest
vertex of both children (Mitchell, ACM TOMS 15 (1989) 326-347; Binev, Dahmen & DeVore,
Numer. Math. 97 (2004) 219-268). On the first mesh the refinement edge is each triangle's
longest. The refinement is conforming (every edge that is cut is cut in all the triangles
that share it: the closure below), nested (each triangle is the union of its children, so a
coarser P1 field is exactly a finer one and a straight boundary stays straight), and
shape-regular: the triangles that bisection ever makes from one triangle fall into at most
four similarity classes, so the smallest angle is bounded below, independently of the
number of steps.

Cells are stored as (a, b, c): refinement edge (a, b), newest vertex c. Orientation is not
kept during refinement (`oriented` turns cells positive without moving the refinement edge).
"""

from __future__ import annotations

import numpy as np

from harness.mesh.simplex import SimplexMesh, signed_measures


def edge_keys(a: np.ndarray, b: np.ndarray, count: int) -> np.ndarray:
    """One integer per undirected edge of a mesh of `count` nodes."""
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    return lo.astype(np.int64) * count + hi


def longest_edge_first(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """`cells` reordered so that each one's refinement edge is its longest (ties: the first)."""
    p = points[cells]
    opposite = np.column_stack([np.linalg.norm(p[:, (i + 1) % 3] - p[:, (i + 2) % 3], axis=1) for i in range(3)])
    newest = np.argmax(opposite, axis=1)   # the vertex opposite the longest edge
    rows = np.arange(len(cells))
    return np.column_stack([cells[rows, (newest + 1) % 3], cells[rows, (newest + 2) % 3], cells[rows, newest]])


def start(points: np.ndarray, cells: np.ndarray, facets: np.ndarray, labels: np.ndarray,
          regions: np.ndarray | None = None) -> SimplexMesh:
    return SimplexMesh(points[:, :2].astype(float), longest_edge_first(points[:, :2], cells),
                       facets.astype(np.int64), labels.astype(np.int64), regions)


def closure(mesh: SimplexMesh, marked: np.ndarray) -> np.ndarray:
    """The keys of every edge to cut: the marked cells' refinement edges, and the refinement
    edge of every cell that holds an edge to cut (bisection cuts a cell's refinement edge
    first), until no cell asks for more."""
    count = len(mesh.points)
    c = mesh.cells
    refinement = edge_keys(c[:, 0], c[:, 1], count)
    sides = np.column_stack([edge_keys(c[:, 1], c[:, 2], count), edge_keys(c[:, 2], c[:, 0], count)])
    cut = np.unique(refinement[marked])
    while True:
        asks = np.isin(sides, cut).any(axis=1) & ~np.isin(refinement, cut)
        if not asks.any():
            return cut
        cut = np.union1d(cut, refinement[asks])


def refine(mesh: SimplexMesh, marked: np.ndarray) -> SimplexMesh:
    """`mesh` with the marked cells (a boolean mask) bisected, and as many others as
    conformity needs; every cut edge is cut once, at its midpoint, and each child lies in its
    parent's region."""
    count = len(mesh.points)
    cut = closure(mesh, np.asarray(marked, dtype=bool))
    if not len(cut):
        return mesh
    lo, hi = cut // count, cut % count
    points = np.vstack([mesh.points, 0.5 * (mesh.points[lo] + mesh.points[hi])])
    # Keys over the refined node count, so that an edge through a new node never takes the
    # key of an old one.
    big = len(points)
    cut = edge_keys(lo, hi, big)
    midpoint = dict(zip(cut.tolist(), range(count, big)))
    cells, regions = mesh.cells, mesh.cell_labels()
    # A cell's refinement edge is cut at most twice in a row: the children's refinement
    # edges are the parent's two other edges; the grandchildren's hold a new node, never cut.
    while True:
        keys = edge_keys(cells[:, 0], cells[:, 1], big)
        split = np.isin(keys, cut)
        if not split.any():
            break
        a, b, c = cells[split].T
        m = np.array([midpoint[k] for k in keys[split].tolist()], dtype=np.int64)
        cells = np.vstack([cells[~split], np.column_stack([a, c, m]), np.column_stack([c, b, m])])
        regions = np.concatenate([regions[~split], regions[split], regions[split]])
    fkeys = edge_keys(mesh.facets[:, 0], mesh.facets[:, 1], big)
    halved = np.isin(fkeys, cut)
    fm = np.array([midpoint[k] for k in fkeys[halved].tolist()], dtype=np.int64)
    fa, fb = mesh.facets[halved].T
    facets = np.vstack([mesh.facets[~halved], np.column_stack([fa, fm]), np.column_stack([fm, fb])])
    labels = np.concatenate([mesh.labels[~halved], mesh.labels[halved], mesh.labels[halved]])
    return SimplexMesh(points, cells, facets, labels, regions if mesh.regions is not None else None)


def uniform(mesh: SimplexMesh, times: int = 1) -> SimplexMesh:
    """`times` rounds, each bisecting every cell once at least (a child whose refinement edge
    is cut too is bisected again in the same round): two rounds make four or more of each."""
    for _ in range(times):
        mesh = refine(mesh, np.ones(len(mesh.cells), dtype=bool))
    return mesh


def oriented(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """`cells` with positive area, by swapping the ends of the refinement edge where needed."""
    negative = signed_measures(points, cells) < 0
    out = cells.copy()
    out[negative, 0], out[negative, 1] = cells[negative, 1], cells[negative, 0]
    return out


def dorfler(indicator: np.ndarray, fraction: float) -> np.ndarray:
    """Dörfler's bulk marking (SIAM J. Numer. Anal. 33 (1996) 1106-1124): the fewest cells,
    largest indicators first, whose squared indicators sum to `fraction` of the total."""
    squares = np.asarray(indicator, dtype=float) ** 2
    order = np.argsort(-squares, kind="stable")
    total = np.cumsum(squares[order])
    count = int(np.searchsorted(total, fraction * total[-1] * (1 - 1e-12))) + 1
    marked = np.zeros(len(squares), dtype=bool)
    marked[order[:min(count, len(squares))]] = True
    return marked
