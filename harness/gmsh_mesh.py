"""Level n of a gmsh scene (harness/gmsh_geometry.py) as MSH 2.2 for FreeFEM, with the
physical tags rewritten to the role labels of harness/contract.py: FreeFEM never sees the
file's own names or numbers.

Levels (geometry.levels):
- split: the mesh of h = 1/coarsest, refined k times by gmsh's uniform split (each triangle
  into 4, each tetrahedron into 8) for n = coarsest * 2^k. On a straight-sided body every
  coarse simplex is a union of fine ones, so a coarse P1 field is exactly a fine one.
- remesh: a new mesh for each h = 1/n: every size of the file scaled by coarsest / n and
  none above h; not nested (the error transfer is the point-located nodal interpolant).

Every level is checked: positive orientation (a surface or volume gmsh meshed the other way
round is turned over), no inverted or degenerate element (refused, naming it), every
boundary facet with a role and no labelled facet inside the body, one outward normal on all
of Gamma_3 (a flat contact part), and the quality of the elements (min angle or dihedral,
max aspect) for the level's summary.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from pathlib import Path

import gmsh
import numpy as np

from harness.contract import ROLE_LABELS
from harness.errors import MeshError
from harness.gmsh_api import session
from harness.gmsh_geometry import GmshGeometry

BODY_LABEL = 1
# gmsh's element type of a simplex of each dimension (1: line, 2: triangle, 4: tetrahedron).
SIMPLEX = {1: 1, 2: 2, 3: 4}
MESHIO_TYPE = {1: "line", 2: "triangle", 3: "tetra"}
# Signed measure below this fraction of (longest edge)^d: a flat element (round-off of a
# well-shaped one is 1e-16; the worst gmsh element a study uses is above 1e-3).
DEGENERATE = 1e-10
# Largest angle between two outward normals of Gamma_3's facets [rad]: round-off of a
# tilted flat face is ~1e-15 (measured on cases/tilted*.geo), a circle of radius R meshed at
# h turns by h / R between facets (0.06 for R = 1 at h = 1/16).
FLAT = 1e-8


@dataclass(frozen=True)
class SimplexMesh:
    points: np.ndarray   # (N, d)
    cells: np.ndarray    # (M, d + 1), positively oriented
    facets: np.ndarray   # (B, d), each boundary facet once, outward oriented
    labels: np.ndarray   # (B,) role label per facet
    quality: dict[str, float]


def split_count(geometry: GmshGeometry, n: int) -> int:
    """k with n = coarsest * 2^k: the refinements of the coarsest mesh that make level n."""
    k = round(math.log2(n / geometry.coarsest)) if n >= geometry.coarsest else -1
    if k < 0 or geometry.coarsest * 2**k != n:
        raise MeshError(f"n={n}: a split level must be the coarsest level {geometry.coarsest} times a power of 2 "
                        "(geometry.coarsest, geometry.levels = \"split\")")
    return k


def generate(geometry: GmshGeometry, n: int) -> SimplexMesh:
    d = geometry.dimension
    refinements = split_count(geometry, n) if geometry.levels == "split" else 0
    with session():
        try:
            gmsh.open(str(geometry.file))
            if geometry.levels == "split":
                gmsh.option.setNumber("Mesh.MeshSizeMax", 1.0 / geometry.coarsest)
            else:
                # gmsh applies the factor after the bound: every size of the file, and the
                # bound 1/coarsest, times coarsest / n, so that no element exceeds h = 1/n.
                gmsh.option.setNumber("Mesh.MeshSizeMax", 1.0 / geometry.coarsest)
                gmsh.option.setNumber("Mesh.MeshSizeFactor", geometry.coarsest / n)
            gmsh.model.mesh.generate(d)
            for _ in range(refinements):
                gmsh.model.mesh.refine()
            points, cells, entity_of_cell = read_cells(d)
            named = read_named_facets(geometry, points)
        except MeshError:
            raise
        except Exception as exc:  # gmsh raises a bare Exception carrying its log line
            raise MeshError(f"gmsh failed on {geometry.file.name} at n={n}: {exc}") from None
    index, points = used_points(points, cells)
    if geometry.levels == "remesh" and n > geometry.coarsest and len(points) <= geometry.coarsest_counts[0]:
        raise MeshError(f"n={n}: gmsh made no more nodes than at the coarsest level {geometry.coarsest}: the file fixes "
                        "its mesh (Transfinite counts?), so remesh cannot refine it; use levels = \"split\"")
    cells = index[cells]
    cells = oriented(points, cells, entity_of_cell, n)
    facets, labels = labelled_boundary(points, cells, {tuple(sorted(index[list(f)])): r for f, r in named.items()}, n)
    check_flat_contact(points, facets, labels, n)
    return SimplexMesh(points, cells, facets, labels, quality(points, cells))


def read_cells(d: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every node (by gmsh tag - 1 rows), the d-simplices and the entity each belongs to."""
    tags, coords, _ = gmsh.model.mesh.getNodes()
    points = np.zeros((int(tags.max()) + 1, 3))
    points[tags.astype(int)] = coords.reshape(-1, 3)
    cells, owners = [], []
    for _, entity in gmsh.model.getEntities(d):
        types, _, nodes = gmsh.model.mesh.getElements(d, entity)
        for kind, block in zip(types, nodes):
            if int(kind) != SIMPLEX[d]:
                name = gmsh.model.mesh.getElementProperties(int(kind))[0]
                raise MeshError(f"gmsh made {name} elements; only first-order triangles (2D) and tetrahedra "
                                "(3D) are solved (no Recombine, Mesh.ElementOrder = 1)")
            block = np.asarray(block, dtype=np.int64).reshape(-1, d + 1)
            cells.append(block)
            owners.append(np.full(len(block), entity))
    if not cells:
        raise MeshError("gmsh made no elements")
    if d == 2 and np.abs(points[:, 2]).max() > 0:
        raise MeshError("a 2D mesh has nodes off the plane z = 0")
    return points[:, :d], np.vstack(cells), np.concatenate(owners)


def read_named_facets(geometry: GmshGeometry, points: np.ndarray) -> dict[tuple[int, ...], str]:
    """Each facet of a named physical group (by its sorted gmsh node tags) -> its role; a
    facet in two groups of different roles is refused."""
    d = geometry.dimension
    roles = geometry.role_of_name
    out: dict[tuple[int, ...], str] = {}
    for dim, tag in gmsh.model.getPhysicalGroups(d - 1):
        name = gmsh.model.getPhysicalName(dim, tag) or str(tag)
        role = roles[name]
        for entity in gmsh.model.getEntitiesForPhysicalGroup(dim, tag):
            types, _, nodes = gmsh.model.mesh.getElements(d - 1, int(entity))
            for kind, block in zip(types, nodes):
                if int(kind) != SIMPLEX[d - 1]:
                    continue
                for facet in np.asarray(block, dtype=np.int64).reshape(-1, d):
                    key = tuple(sorted(int(t) for t in facet))
                    if out.setdefault(key, role) != role:
                        where = place(points[list(key)])
                        raise MeshError(f"the facet at {where} is in parts of two roles, {out[key]} and {role}")
    return out


def place(corners: np.ndarray) -> str:
    """A simplex's centroid, for a message."""
    return "(" + ", ".join(f"{x:.6g}" for x in corners.mean(axis=0)) + ")"


def used_points(points: np.ndarray, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """gmsh tag -> row of the points the cells use (-1: none), and those points."""
    used = np.unique(cells)
    index = np.full(len(points), -1, dtype=np.int64)
    index[used] = np.arange(len(used))
    return index, points[used]


def signed_measures(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    edges = points[cells[:, 1:]] - points[cells[:, :1]]
    return np.linalg.det(edges) / math.factorial(cells.shape[1] - 1)


def turned_over(cells: np.ndarray, which: np.ndarray) -> np.ndarray:
    """A copy of `cells` with the cells `which` selects turned over (last two vertices swapped)."""
    cells = cells.copy()
    cells[which, -1], cells[which, -2] = cells[which, -2], cells[which, -1].copy()
    return cells


def oriented(points: np.ndarray, cells: np.ndarray, owners: np.ndarray, n: int) -> np.ndarray:
    """Positively oriented cells. gmsh orients each surface or volume one way: a surface
    drawn clockwise comes out all negative and is turned over; a cell against the majority
    of its entity is inverted, and a flat one degenerate: both refused, named."""
    d = cells.shape[1] - 1
    measure = signed_measures(points, cells)
    longest = np.max([np.linalg.norm(points[cells[:, i]] - points[cells[:, j]], axis=1)
                      for i, j in itertools.combinations(range(d + 1), 2)], axis=0)
    flat = np.abs(measure) <= DEGENERATE * longest**d
    kind = MESHIO_TYPE[d]
    if flat.any():
        i = int(np.flatnonzero(flat)[0])
        raise MeshError(f"n={n}: {kind} {i + 1} at {place(points[cells[i]])} is degenerate "
                        f"(measure {measure[i]:.3g}, longest edge {longest[i]:.3g})")
    for entity in np.unique(owners):
        mine = owners == entity
        sign = 1.0 if np.count_nonzero(measure[mine] > 0) >= np.count_nonzero(measure[mine] < 0) else -1.0
        against = np.flatnonzero(mine & (np.sign(measure) != sign))
        if len(against):
            i = int(against[0])
            raise MeshError(f"n={n}: {kind} {i + 1} at {place(points[cells[i]])} is inverted "
                            f"(its orientation is against the rest of its {'surface' if d == 2 else 'volume'} {entity})")
        if sign < 0:
            cells = turned_over(cells, mine)
    return cells


def boundary_facets(cells: np.ndarray) -> np.ndarray:
    """The facets that belong to one cell only, oriented so that the cell lies on their
    inner side (a positive cell's facet opposite vertex k, in the order that keeps the
    outward normal)."""
    d = cells.shape[1] - 1
    if d == 2:
        local = [[1, 2], [2, 0], [0, 1]]
    else:
        local = [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]]
    faces = np.vstack([cells[:, f] for f in local])
    keys = np.sort(faces, axis=1)
    _, first, count = np.unique(keys, axis=0, return_index=True, return_counts=True)
    return faces[first[count == 1]]


def outward_normals(points: np.ndarray, facets: np.ndarray) -> np.ndarray:
    """Unit outward normals of facets oriented by boundary_facets."""
    if facets.shape[1] == 2:
        t = points[facets[:, 1]] - points[facets[:, 0]]
        normal = np.column_stack([t[:, 1], -t[:, 0]])  # a counter-clockwise boundary: the right side is out
    else:
        p = points[facets]
        normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    return normal / np.linalg.norm(normal, axis=1, keepdims=True)


def labelled_boundary(points: np.ndarray, cells: np.ndarray, named: dict[tuple[int, ...], str],
                      n: int) -> tuple[np.ndarray, np.ndarray]:
    """The boundary facets with the label of their part's role; an unnamed boundary facet,
    or a named facet inside the body, is refused."""
    facets = boundary_facets(cells)
    labels = np.zeros(len(facets), dtype=np.int64)
    seen = set()
    for i, facet in enumerate(facets):
        key = tuple(sorted(int(v) for v in facet))
        role = named.get(key)
        if role is None:
            where = place(points[facet])
            raise MeshError(f"n={n}: the boundary facet at {where} is in no named part: give it a physical group and a role")
        labels[i] = ROLE_LABELS[role]
        seen.add(key)
    inside = [k for k in named if k not in seen]
    if inside:
        where = place(points[list(inside[0])])
        raise MeshError(f"n={n}: the named facet at {where} ({named[inside[0]]}) is inside the body, not on its boundary")
    return facets, labels


def check_flat_contact(points: np.ndarray, facets: np.ndarray, labels: np.ndarray, n: int) -> None:
    """One outward normal on all of Gamma_3: FreeFEM's contact terms use the facets' normal
    and the active set and pressed start its nodal or mean value, which are the normal only
    on a flat part."""
    on = labels == ROLE_LABELS["contact"]
    if not on.any():
        return
    normals = outward_normals(points, facets[on])
    mean = normals.mean(axis=0)
    mean /= np.linalg.norm(mean)
    # From the chord |n - mean|: arccos of a dot product near 1 would turn round-off 1e-16 into 1e-8 rad.
    angle = 2.0 * np.arcsin(np.clip(np.linalg.norm(normals - mean, axis=1) / 2.0, 0.0, 1.0))
    worst = int(np.argmax(angle))
    if angle[worst] > FLAT:
        where = place(points[facets[on][worst]])
        raise MeshError(f"n={n}: the contact part is not flat: the facet at {where} turns {angle[worst]:.3g} rad from "
                        "the mean normal (curved contact parts are not supported)")


def quality(points: np.ndarray, cells: np.ndarray) -> dict[str, float]:
    """min angle (2D) or min dihedral angle (3D) in degrees, and the max aspect ratio
    R / (d r) (circumradius over d times the inradius: 1 for the regular simplex)."""
    d = cells.shape[1] - 1
    p = points[cells]
    volume = np.abs(signed_measures(points, cells))
    if d == 2:
        a = np.linalg.norm(p[:, 1] - p[:, 2], axis=1)
        b = np.linalg.norm(p[:, 2] - p[:, 0], axis=1)
        c = np.linalg.norm(p[:, 0] - p[:, 1], axis=1)
        angles = np.degrees(np.arccos(np.clip(np.column_stack([
            (b**2 + c**2 - a**2) / (2 * b * c), (a**2 + c**2 - b**2) / (2 * a * c),
            (a**2 + b**2 - c**2) / (2 * a * b)]), -1.0, 1.0)))
        inradius = volume / (0.5 * (a + b + c))
        circumradius = a * b * c / (4 * volume)
        return {"min_angle_deg": float(angles.min()), "max_aspect": float((circumradius / (2 * inradius)).max())}
    faces = [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]]
    normals = []
    areas = []
    for f in faces:
        q = p[:, f]
        cross = np.cross(q[:, 1] - q[:, 0], q[:, 2] - q[:, 0])
        areas.append(0.5 * np.linalg.norm(cross, axis=1))
        normals.append(cross / np.linalg.norm(cross, axis=1, keepdims=True))
    dihedral = [np.degrees(np.pi - np.arccos(np.clip(np.einsum("ij,ij->i", normals[i], normals[j]), -1.0, 1.0)))
                for i in range(4) for j in range(i + 1, 4)]
    inradius = 3 * volume / np.sum(areas, axis=0)
    edges = p[:, 1:] - p[:, :1]
    centre = np.linalg.solve(2 * edges, (edges**2).sum(axis=2)[..., None])[..., 0]  # from vertex 0
    circumradius = np.linalg.norm(centre, axis=1)
    return {"min_dihedral_deg": float(np.min(dihedral)), "max_aspect": float((circumradius / (3 * inradius)).max())}


def write_msh(mesh: SimplexMesh, path: Path) -> None:
    """MSH 2.2 (the only gmsh version FreeFEM reads), physical tags = role labels, body 1."""
    d = mesh.cells.shape[1] - 1
    points = np.zeros((len(mesh.points), 3))
    points[:, :d] = mesh.points
    body = np.full(len(mesh.cells), BODY_LABEL)
    cells = [(MESHIO_TYPE[d - 1], mesh.facets), (MESHIO_TYPE[d], mesh.cells)]
    data = {"gmsh:physical": [mesh.labels, body], "gmsh:geometrical": [mesh.labels, body]}
    import meshio  # here, not at start-up: its import (95 ms, its CLI pulls in rich) would delay FreeFEM's start (freefem.launch warms it)
    meshio.write(path, meshio.Mesh(points, cells, cell_data=data), file_format="gmsh22", binary=False)


def role_measures(mesh: SimplexMesh) -> dict[str, float]:
    """Length (2D) or area (3D) of each role's facets."""
    p = mesh.points[mesh.facets]
    if mesh.facets.shape[1] == 2:
        size = np.linalg.norm(p[:, 1] - p[:, 0], axis=1)
    else:
        size = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    return {role: float(size[mesh.labels == label].sum()) for role, label in ROLE_LABELS.items()
            if (mesh.labels == label).any()}
