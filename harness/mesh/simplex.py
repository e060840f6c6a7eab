"""Simplicial meshes (triangles in 2D, tetrahedra in 3D): the one record every generator
returns (`SimplexMesh`), and their general geometry: signed measures and orientation, the
edges and boundary facets of a cell array, facet measures, outward normals and each role's
measure, and the elements' quality (angles, dihedral angles, aspect).

The functions take arrays: `points` (N, d), `cells` (M, d + 1), `facets` (B, d), index arrays
int64.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from harness.core.contract import BODY_LABEL, ROLE_LABELS


@dataclass(frozen=True)
class SimplexMesh:
    """One mesh level as every generator returns it (the rectangle's, the box's, a gmsh
    scene's, the adaptive bisections'), in the order its file is written: node k is row k,
    and the facets come before the cells."""

    points: np.ndarray                # (N, d)
    cells: np.ndarray                 # (M, d + 1); generators orient them positively, the
                                      # bisections keep their refinement edge first instead
    facets: np.ndarray                # (B, d) the labelled boundary facets, outward oriented
    labels: np.ndarray                # (B,) each facet's role label (harness/core/contract.py)
    regions: np.ndarray | None = None  # (M,) each cell's material region label; None: one body
    # gmsh's elementary entity of each facet and cell, where the level comes from gmsh's own
    # drawing (the rectangle's curves and strips): its file names them as gmsh's did.
    facet_entities: np.ndarray | None = None
    cell_entities: np.ndarray | None = None

    @property
    def dimension(self) -> int:
        return self.cells.shape[1] - 1

    def cell_labels(self) -> np.ndarray:
        """Each cell's physical tag: its region's label, or BODY_LABEL for a one-region body."""
        return self.regions if self.regions is not None else np.full(len(self.cells), BODY_LABEL)

# The facet opposite vertex k of a positively oriented cell, its vertices in the order that
# makes its normal point out of the cell.
FACETS = {2: ((1, 2), (2, 0), (0, 1)), 3: ((1, 2, 3), (0, 3, 2), (0, 1, 3), (0, 2, 1))}
# The six edges of a tetrahedron (three of a triangle), as local vertex pairs.
EDGES = {d: tuple(itertools.combinations(range(d + 1), 2)) for d in (2, 3)}


def signed_measures(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Signed area (2D) or volume (3D) of each cell: positive for a positively oriented one."""
    edges = points[cells[:, 1:]] - points[cells[:, :1]]
    return np.linalg.det(edges) / math.factorial(cells.shape[1] - 1)


def turned_over(cells: np.ndarray, which: np.ndarray) -> np.ndarray:
    """A copy of `cells` with the cells `which` selects turned over (last two vertices swapped)."""
    cells = cells.copy()
    cells[which, -1], cells[which, -2] = cells[which, -2], cells[which, -1].copy()
    return cells


def positively_oriented(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """`cells` with each negative one turned over."""
    return turned_over(cells, signed_measures(points, cells) < 0)


def edge_lengths(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """(M, 3) or (M, 6): each cell's edge lengths in the order of EDGES."""
    d = cells.shape[1] - 1
    return np.column_stack([np.linalg.norm(points[cells[:, i]] - points[cells[:, j]], axis=1) for i, j in EDGES[d]])


def unique_edges(cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mesh's edges once each, (E, 2) with the smaller vertex first, sorted; and (M, 3) or
    (M, 6) the row of each cell's edge in the order of EDGES."""
    d = cells.shape[1] - 1
    pairs = np.stack([cells[:, list(pair)] for pair in EDGES[d]], axis=1)  # (M, k, 2)
    low, high = pairs.min(axis=2), pairs.max(axis=2)
    # One int64 per edge: np.unique on rows (axis=0) imports numpy.ma, 20 ms of a process's start.
    span = np.int64(cells.max() + 1)
    keys, inverse = np.unique(low * span + high, return_inverse=True)
    return np.column_stack([keys // span, keys % span]), inverse.reshape(low.shape)


def cell_facets(cells: np.ndarray) -> np.ndarray:
    """(M, d + 1, d): each cell's facets, the one opposite vertex k at k, outward oriented
    for a positively oriented cell."""
    d = cells.shape[1] - 1
    return np.stack([cells[:, list(f)] for f in FACETS[d]], axis=1)


def boundary_facets(cells: np.ndarray) -> np.ndarray:
    """The facets that belong to one cell only, oriented so that the cell lies on their
    inner side (a positive cell's facet opposite vertex k, in the order that keeps the
    outward normal)."""
    faces = np.vstack([cell_facets(cells)[:, k] for k in range(cells.shape[1])])
    keys = np.sort(faces, axis=1)
    _, first, count = np.unique(keys, axis=0, return_index=True, return_counts=True)
    return faces[first[count == 1]]


def facet_normals(points: np.ndarray, facets: np.ndarray) -> np.ndarray:
    """Normals of oriented facets, of length the facet's measure (2D: the edge's length; 3D:
    twice the triangle's area)."""
    if facets.shape[1] == 2:
        t = points[facets[:, 1]] - points[facets[:, 0]]
        return np.column_stack([t[:, 1], -t[:, 0]])  # a counter-clockwise boundary: the right side is out
    p = points[facets]
    return np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])


def outward_normals(points: np.ndarray, facets: np.ndarray) -> np.ndarray:
    """Unit outward normals of facets oriented by boundary_facets."""
    normal = facet_normals(points, facets)
    return normal / np.linalg.norm(normal, axis=1, keepdims=True)


def facet_measures(points: np.ndarray, facets: np.ndarray) -> np.ndarray:
    """Length (2D) or area (3D) of each facet."""
    size = np.linalg.norm(facet_normals(points, facets), axis=1)
    return size if facets.shape[1] == 2 else 0.5 * size


def label_measures(points: np.ndarray, facets: np.ndarray, labels: np.ndarray) -> dict[int, float]:
    """Total length (2D) or area (3D) of the facets of each label."""
    size = facet_measures(points, facets)
    return {int(label): float(size[labels == label].sum()) for label in np.unique(labels)}


def role_measures(mesh: SimplexMesh) -> dict[str, float]:
    """Length (2D) or area (3D) of each role's facets, for the roles the mesh has."""
    measures = label_measures(mesh.points, mesh.facets, mesh.labels)
    return {role: measures[label] for role, label in ROLE_LABELS.items() if label in measures}


def triangle_angles(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """(M, 3) each triangle's angles in degrees."""
    p = points[cells]
    a = np.linalg.norm(p[:, 1] - p[:, 2], axis=1)
    b = np.linalg.norm(p[:, 2] - p[:, 0], axis=1)
    c = np.linalg.norm(p[:, 0] - p[:, 1], axis=1)
    return np.degrees(np.arccos(np.clip(np.column_stack([
        (b**2 + c**2 - a**2) / (2 * b * c), (a**2 + c**2 - b**2) / (2 * a * c),
        (a**2 + b**2 - c**2) / (2 * a * b)]), -1.0, 1.0)))


def dihedral_angles(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """(M, 6) each tetrahedron's dihedral angles in degrees (pi minus the angle between two
    faces' outward normals)."""
    normals = [outward_normals(points, cells[:, list(f)]) for f in FACETS[3]]
    return np.column_stack([
        np.degrees(np.pi - np.arccos(np.clip(np.einsum("ij,ij->i", normals[i], normals[j]), -1.0, 1.0)))
        for i in range(4) for j in range(i + 1, 4)])


def aspect_ratios(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """R / (d r) per cell, circumradius over d times the inradius: 1 for the regular simplex."""
    d = cells.shape[1] - 1
    p = points[cells]
    volume = np.abs(signed_measures(points, cells))
    if d == 2:
        a = np.linalg.norm(p[:, 1] - p[:, 2], axis=1)
        b = np.linalg.norm(p[:, 2] - p[:, 0], axis=1)
        c = np.linalg.norm(p[:, 0] - p[:, 1], axis=1)
        inradius = volume / (0.5 * (a + b + c))
        circumradius = a * b * c / (4 * volume)
        return circumradius / (2 * inradius)
    areas = np.sum([facet_measures(points, cells[:, list(f)]) for f in FACETS[3]], axis=0)
    inradius = 3 * volume / areas
    edges = p[:, 1:] - p[:, :1]
    centre = np.linalg.solve(2 * edges, (edges**2).sum(axis=2)[..., None])[..., 0]  # from vertex 0
    return np.linalg.norm(centre, axis=1) / (3 * inradius)


def quality(points: np.ndarray, cells: np.ndarray) -> dict[str, float]:
    """min angle (2D) or min dihedral angle (3D) in degrees, and the max aspect ratio."""
    if cells.shape[1] == 3:
        return {"min_angle_deg": float(triangle_angles(points, cells).min()),
                "max_aspect": float(aspect_ratios(points, cells).max())}
    return {"min_dihedral_deg": float(dihedral_angles(points, cells).min()),
            "max_aspect": float(aspect_ratios(points, cells).max())}


# The floor of a level's quality, below which it is named in a warning: slivers and needles
# make P1's interpolation error and the stiffness matrix's condition grow (the constants of
# the error bounds depend on the shape: Shewchuk, "What is a good linear finite element?",
# 2002). The angles are the textbook floors of quality meshers (Ruppert's 20.7 deg guarantee
# in 2D, TetGen's default dihedral bound of about 5-10 deg); the aspect floor is 3x the worst
# tetrahedron of gmsh's own meshes of this project's geometries (3.3), below the 22.9 that
# gmsh's fixed-diagonal split made of them at the first split.
QUALITY_FLOORS = {2: {"min_angle_deg": 15.0, "max_aspect": 10.0},
                  3: {"min_dihedral_deg": 10.0, "max_aspect": 10.0}}
QUALITY_WORDS = {"min_angle_deg": "min angle", "min_dihedral_deg": "min dihedral angle", "max_aspect": "max aspect"}


def quality_warning(measured: dict[str, float]) -> str | None:
    """What of `measured` (quality's dict) is worse than its QUALITY_FLOORS, in words; None
    when nothing is."""
    floors = QUALITY_FLOORS[3 if "min_dihedral_deg" in measured else 2]
    worse = []
    for key, floor in floors.items():
        value = measured[key]
        if (value > floor) if key == "max_aspect" else (value < floor):
            unit = "" if key == "max_aspect" else " deg"
            worse.append(f"{QUALITY_WORDS[key]} {value:.3g}{unit} ({'above' if key == 'max_aspect' else 'below'} "
                         f"{floor:g}{unit})")
    return ", ".join(worse) or None
