"""Tetrahedral meshes of a box (0, Lx) x (0, Ly) x (0, Lz): structured ones, nested under
uniform refinement, or gmsh's unstructured ones (box.diagonals = "unstructured"), each a
SimplexMesh with its boundary triangles labelled by role.

Every cube of the grid is cut into the 6 tetrahedra of the Kuhn (Freudenthal) split,
{x in cube : x_a >= x_b >= x_c} for each ordering (a, b, c) of the axes. The tetrahedra are
then the cells of the arrangement of the planes x_i = k h and x_i - x_j = k h, and the planes
at h/2 contain those at h: the mesh at h/2 refines the mesh at h, so a coarse P1 field is
exactly a fine P1 field (the same property the 2D study gets from nested triangle meshes).

Boundary triangles carry the integer label of their face patch's role (harness/core/contract.py),
decided by a function of the triangle's centroid, the way the rectangle's edges are split
into segments in 2D.
"""

from __future__ import annotations

import itertools
from typing import Callable

import gmsh
import numpy as np

from harness.core.contract import ROLE_LABELS
from harness.core.errors import MeshError
from harness.core.gmsh_api import session
from harness.mesh.simplex import SimplexMesh, facet_normals, positively_oriented
from harness.scene.box import Box

# role of a boundary triangle, from its centroid and the outward normal axis (0, 1, 2) and side (-1, +1)
RoleOf = Callable[[np.ndarray, int, int], str]


def generate(box: Box, n: int) -> SimplexMesh:
    """Level n of a box scene: the Kuhn split of its h-grid, or gmsh's tetrahedra."""
    if box.diagonals != "unstructured":
        return kuhn_box(box.lengths, n, box.role_of)
    points, tetrahedra = unstructured_box(box, n)
    tetrahedra = positively_oriented(points, tetrahedra)
    return SimplexMesh(points, tetrahedra, *boundary_faces(points, tetrahedra, box.lengths, box.role_of))


def grid_counts(lengths: tuple[float, float, float], n: int) -> tuple[int, int, int]:
    counts = []
    for length in lengths:
        count = round(length * n)
        if count == 0 or abs(count - length * n) > 1e-9 * max(1.0, length * n):
            raise MeshError(f"n={n}: box side {length} is not a positive multiple of h = 1/{n}")
        counts.append(count)
    return counts[0], counts[1], counts[2]


def kuhn_box(lengths: tuple[float, float, float], n: int, role_of: RoleOf) -> SimplexMesh:
    nx, ny, nz = grid_counts(lengths, n)
    axes = [np.linspace(0.0, length, count + 1) for length, count in zip(lengths, (nx, ny, nz))]
    gx, gy, gz = np.meshgrid(*axes, indexing="ij")
    points = np.column_stack([gx.ravel(), gy.ravel(), gz.ravel()])

    def vertex(i: np.ndarray, j: np.ndarray, k: np.ndarray) -> np.ndarray:
        return (i * (ny + 1) + j) * (nz + 1) + k

    ci, cj, ck = (a.ravel() for a in np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij"))
    tets = []
    for order in itertools.permutations(range(3)):
        # Walk from the cube's lowest corner to its highest, one axis at a time in `order`.
        corner = np.zeros((3, ci.size), dtype=np.int64)
        path = [vertex(ci, cj, ck)]
        for axis in order:
            corner[axis] += 1
            path.append(vertex(ci + corner[0], cj + corner[1], ck + corner[2]))
        tets.append(np.column_stack(path))
    # FreeFEM's assembly needs positive volumes: half the walks run the other way round.
    tetrahedra = positively_oriented(points, np.vstack(tets))
    return SimplexMesh(points, tetrahedra, *boundary_faces(points, tetrahedra, lengths, role_of))


def boundary_faces(
    points: np.ndarray, tets: np.ndarray, lengths: tuple[float, float, float], role_of: RoleOf
) -> tuple[np.ndarray, np.ndarray]:
    """The tetrahedra's faces on the box's boundary, oriented outwards, with role labels."""
    faces = np.vstack([tets[:, [1, 2, 3]], tets[:, [0, 3, 2]], tets[:, [0, 1, 3]], tets[:, [0, 2, 1]]])
    tol = 1e-12 * max(lengths)
    triangles, labels = [], []
    for axis in range(3):
        for side, value in ((-1, 0.0), (1, lengths[axis])):
            on = np.all(np.abs(points[faces, axis] - value) < tol, axis=1)
            face = faces[on]
            normal = facet_normals(points, face)
            flip = np.sign(normal[:, axis]) != side
            face[flip, 1], face[flip, 2] = face[flip, 2], face[flip, 1].copy()
            centroids = points[face].mean(axis=1)
            roles = [role_of(c, axis, side) for c in centroids]
            unknown = set(roles) - set(ROLE_LABELS)
            if unknown:
                raise MeshError(f"unknown boundary role(s) {sorted(unknown)} (known: {', '.join(ROLE_LABELS)})")
            triangles.append(face)
            labels.append(np.array([ROLE_LABELS[r] for r in roles]))
    return np.vstack(triangles), np.concatenate(labels)


def unstructured_box(box: Box, n: int) -> tuple[np.ndarray, np.ndarray]:
    """gmsh's tetrahedra of about size 1/n (Delaunay, one thread: the same mesh every time)
    on the box cut into blocks at every patch edge, so that each boundary triangle lies in
    one patch; (points, tetrahedra) as index arrays."""
    try:
        with session(threads=1):
            gmsh.model.add("box")
            x, y, z = (box.cuts(axis) for axis in range(3))
            blocks = [(3, gmsh.model.occ.addBox(x0, y0, z0, x1 - x0, y1 - y0, z1 - z0))
                      for x0, x1 in zip(x, x[1:]) for y0, y1 in zip(y, y[1:]) for z0, z1 in zip(z, z[1:])]
            if len(blocks) > 1:
                gmsh.model.occ.fragment(blocks[:1], blocks[1:])  # shared faces: one conforming mesh
            gmsh.model.occ.synchronize()
            gmsh.option.setNumber("Mesh.MeshSizeMax", 1.0 / n)
            gmsh.option.setNumber("Mesh.Algorithm3D", 1)
            gmsh.model.mesh.generate(3)
            tags, coords, _ = gmsh.model.mesh.getNodes()
            _, nodes = gmsh.model.mesh.getElementsByType(4)  # 4-node tetrahedra
    except Exception as exc:  # gmsh raises a bare Exception with its own log text
        raise MeshError(f"gmsh failed on the box at n={n}: {exc}") from None
    index = np.full(int(tags.max()) + 1, -1)
    index[tags.astype(int)] = np.arange(len(tags))
    points = coords.reshape(-1, 3)
    return points, index[nodes.astype(int)].reshape(-1, 4)


def kuhn_weights(points: np.ndarray, grid: np.ndarray, spacing: float, at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """P1 interpolation on a Kuhn mesh: for each point of `at` (K, 3), the 4 nodes of the
    tetrahedron that holds it (indices into `points`) and its barycentric weights.

    In the cube with lowest corner c and local coordinates t in [0, 1]^3, the tetrahedron
    is the one with t_a >= t_b >= t_c (kuhn_box walks from c along a, then b, then c), and
    the weights of its vertices c, c + e_a, c + e_a + e_b, c + 1 are 1 - t_a, t_a - t_b,
    t_b - t_c, t_c. `grid` maps integer grid coordinates to point indices (-1: none).
    """
    scaled = at / spacing
    cube = np.clip(np.floor(scaled + 1e-9).astype(np.int64), 0, np.array(grid.shape) - 2)
    t = scaled - cube
    order = np.argsort(-t, axis=1, kind="stable")
    ts = np.take_along_axis(t, order, axis=1)
    weights = np.column_stack([1.0 - ts[:, 0], ts[:, 0] - ts[:, 1], ts[:, 1] - ts[:, 2], ts[:, 2]])
    corner = cube.copy()
    nodes = [grid[corner[:, 0], corner[:, 1], corner[:, 2]]]
    rows = np.arange(len(at))
    for step in range(3):
        corner[rows, order[:, step]] += 1
        nodes.append(grid[corner[:, 0], corner[:, 1], corner[:, 2]])
    nodes = np.column_stack(nodes)
    if np.any(nodes < 0):
        raise MeshError("kuhn_weights: a point's tetrahedron has a vertex missing from the coarse grid")
    return nodes, weights


def grid_index(points: np.ndarray) -> tuple[np.ndarray, float]:
    """The structured grid of a Kuhn mesh's points: integer coordinates -> point index, and h."""
    xs = np.unique(np.round(points[:, 0], 12))
    spacing = float(np.min(np.diff(xs)))
    ijk = np.rint(points / spacing).astype(np.int64)
    # (solution.vtu stores coordinates in single precision: snap within 1e-3 h)
    if np.max(np.abs(ijk * spacing - points)) > 1e-3 * spacing:
        raise MeshError("grid_index: the points are not on a grid of spacing h")
    grid = np.full(tuple(ijk.max(axis=0) + 1), -1, dtype=np.int64)
    grid[ijk[:, 0], ijk[:, 1], ijk[:, 2]] = np.arange(len(points))
    return grid, spacing
