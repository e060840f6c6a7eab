"""Uniform ("red") refinement of a tetrahedral mesh: every tetrahedron into 8, the boundary
triangles each into 4 with their parent's label.

A node is added at the midpoint of every edge. Each tetrahedron keeps its four corner
tetrahedra; the octahedron left in its middle is cut into four along one of its three
diagonals (the segments joining midpoints of opposite edges). The choice is free, and it
decides the quality of the levels: this module takes the shortest diagonal, the rule of
Ong (M. E. G. Ong, "Uniform refinement of a tetrahedron", SIAM J. Sci. Comput. 15(5),
1134-1144, 1994), discussed with Bey's fixed ordering in J. Bey, "Tetrahedral grid
refinement", Computing 55, 355-378 (1995). gmsh's own split cuts along a fixed local
diagonal: on gmsh's tetrahedra of the turned box of cases/mms/tilted3d.toml it is the
shortest in 29 % of them, and the largest aspect ratio grows from 3.30 to 22.9 at the first
split; this split keeps it at 3.30-3.44 (tests/test_tet_split.py).

The octahedron's faces that lie on the parent's faces are the 2D red split's middle
triangles, whatever the diagonal, so neighbouring tetrahedra stay conforming; and every
coarse tetrahedron is the union of its children, so the levels nest.
"""

from __future__ import annotations

import numpy as np

from harness.mesh.simplex import EDGES, SimplexMesh, positively_oriented, unique_edges

# Local numbering of a tetrahedron's 10 nodes after the split: its vertices 0-3, then the
# midpoints of its edges in the order of simplex.EDGES: 4 = 01, 5 = 02, 6 = 03, 7 = 12,
# 8 = 13, 9 = 23.
MID = {pair: 4 + k for k, pair in enumerate(EDGES[3])}
CORNERS = ((0, MID[0, 1], MID[0, 2], MID[0, 3]), (MID[0, 1], 1, MID[1, 2], MID[1, 3]),
           (MID[0, 2], MID[1, 2], 2, MID[2, 3]), (MID[0, 3], MID[1, 3], MID[2, 3], 3))
# The octahedron's three diagonals (midpoints of opposite edges), and for each the cycle of
# the other four midpoints around it: consecutive ones share an edge of the octahedron.
DIAGONALS = ((MID[0, 1], MID[2, 3]), (MID[0, 2], MID[1, 3]), (MID[0, 3], MID[1, 2]))
EQUATORS = ((MID[0, 2], MID[0, 3], MID[1, 3], MID[1, 2]),
            (MID[0, 1], MID[0, 3], MID[2, 3], MID[1, 2]),
            (MID[0, 1], MID[0, 2], MID[2, 3], MID[1, 3]))
# The 2D red split of a triangle (a, b, c) with midpoints 3 = ab, 4 = bc, 5 = ca: its four
# children keep the parent's orientation (the middle one is the parent turned by pi, halved).
TRIANGLE_CHILDREN = ((0, 3, 5), (3, 1, 4), (5, 4, 2), (3, 4, 5))


def shortest_diagonals(nodes: np.ndarray) -> np.ndarray:
    """(M,) which of DIAGONALS is shortest in each octahedron; `nodes` (M, 10, 3) the local
    nodes' coordinates. A tie goes to the first, so the result does not depend on round-off
    of points given in another order."""
    lengths = np.column_stack([np.linalg.norm(nodes[:, a] - nodes[:, b], axis=1) for a, b in DIAGONALS])
    return np.argmin(lengths, axis=1)


def local_children(diagonal: np.ndarray) -> np.ndarray:
    """(M, 8, 4) each tetrahedron's children in local node numbers: the 4 corners, then the
    octahedron's 4 around its diagonal."""
    table = np.array([[*CORNERS, *[(a, b, ring[i], ring[(i + 1) % 4]) for i in range(4)]]
                      for (a, b), ring in zip(DIAGONALS, EQUATORS)])  # (3, 8, 4)
    return table[diagonal]


def split(mesh: SimplexMesh) -> SimplexMesh:
    """One red refinement: children of every tetrahedron along its octahedron's shortest
    diagonal, the new nodes (edge midpoints) after the old ones, edge by edge in sorted order;
    a tetrahedron's 8 children take its place, in order, and its region."""
    edges, cell_edges = unique_edges(mesh.cells)
    offset = len(mesh.points)
    points = np.vstack([mesh.points, 0.5 * (mesh.points[edges[:, 0]] + mesh.points[edges[:, 1]])])
    local = np.hstack([mesh.cells, offset + cell_edges])  # (M, 10) global numbers of the local nodes
    children = local_children(shortest_diagonals(points[local]))
    cells = np.take_along_axis(local[:, None, :], children, axis=2).reshape(-1, 4)
    facets = split_triangles(mesh.facets, edges, offset)
    regions = np.repeat(mesh.regions, 8) if mesh.regions is not None else None
    return SimplexMesh(points, positively_oriented(points, cells), facets, np.repeat(mesh.labels, 4), regions)


def split_triangles(facets: np.ndarray, edges: np.ndarray, offset: int) -> np.ndarray:
    """Each triangle (a, b, c) into its four children, oriented as the parent; the midpoint
    of an edge is node offset + its row in `edges` (sorted pairs, as unique_edges returns)."""
    span = np.int64(max(int(edges.max()), int(facets.max())) + 1)
    keys = edges[:, 0] * span + edges[:, 1]

    def midpoint(i: int, j: int) -> np.ndarray:
        a, b = facets[:, i], facets[:, j]
        return offset + np.searchsorted(keys, np.minimum(a, b) * span + np.maximum(a, b))

    local = np.column_stack([facets, midpoint(0, 1), midpoint(1, 2), midpoint(2, 0)])  # (B, 6)
    return local[:, np.array(TRIANGLE_CHILDREN)].reshape(-1, 3)


def refine(mesh: SimplexMesh, times: int) -> SimplexMesh:
    for _ in range(times):
        mesh = split(mesh)
    return mesh
