"""Structured tetrahedral meshes of a box (0, Lx) x (0, Ly) x (0, Lz), nested under uniform
refinement, written as gmsh MSH 2.2 for FreeFEM's `gmshload3`.

Every cube of the grid is cut into the 6 tetrahedra of the Kuhn (Freudenthal) split,
{x in cube : x_a >= x_b >= x_c} for each ordering (a, b, c) of the axes. The tetrahedra are
then the cells of the arrangement of the planes x_i = k h and x_i - x_j = k h, and the planes
at h/2 contain those at h: the mesh at h/2 refines the mesh at h, so a coarse P1 field is
exactly a fine P1 field (the same property the 2D study gets from nested triangle meshes).

Boundary triangles carry the integer label of their face patch's role (harness/contract.py),
decided by a function of the triangle's centroid, the way the rectangle's edges are split
into segments in 2D.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import meshio
import numpy as np

from harness.contract import ROLE_LABELS
from harness.errors import MeshError

# role of a boundary triangle, from its centroid and the outward normal axis (0, 1, 2) and side (-1, +1)
RoleOf = Callable[[np.ndarray, int, int], str]
BODY_LABEL = 1


@dataclass(frozen=True)
class BoxMesh:
    points: np.ndarray  # (N, 3)
    tetrahedra: np.ndarray  # (M, 4), positively oriented
    triangles: np.ndarray  # (B, 3), outward oriented
    labels: np.ndarray  # (B,) role label per boundary triangle


def grid_counts(lengths: tuple[float, float, float], n: int) -> tuple[int, int, int]:
    counts = []
    for length in lengths:
        count = round(length * n)
        if count == 0 or abs(count - length * n) > 1e-9 * max(1.0, length * n):
            raise MeshError(f"n={n}: box side {length} is not a positive multiple of h = 1/{n}")
        counts.append(count)
    return counts[0], counts[1], counts[2]


def kuhn_box(lengths: tuple[float, float, float], n: int, role_of: RoleOf) -> BoxMesh:
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
    tetrahedra = orient_positive(points, np.vstack(tets))
    triangles, labels = boundary_faces(points, tetrahedra, lengths, role_of)
    return BoxMesh(points, tetrahedra, triangles, labels)


def signed_volumes(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    a, b, c, d = (points[tets[:, k]] for k in range(4))
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) / 6.0


def orient_positive(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """FreeFEM's assembly needs positive volumes: swap two vertices of the others."""
    tets = tets.copy()
    negative = signed_volumes(points, tets) < 0
    tets[negative, 2], tets[negative, 3] = tets[negative, 3], tets[negative, 2].copy()
    return tets


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
            normal = np.cross(points[face[:, 1]] - points[face[:, 0]], points[face[:, 2]] - points[face[:, 0]])
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


def write_msh(mesh: BoxMesh, path: Path) -> None:
    """MSH 2.2 (the only gmsh version FreeFEM reads), physical tags = labels."""
    body = np.full(len(mesh.tetrahedra), BODY_LABEL)
    cells = [("triangle", mesh.triangles), ("tetra", mesh.tetrahedra)]
    data = {"gmsh:physical": [mesh.labels, body], "gmsh:geometrical": [mesh.labels, body]}
    meshio.write(path, meshio.Mesh(mesh.points, cells, cell_data=data), file_format="gmsh22", binary=False)
