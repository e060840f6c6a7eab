"""Level n of a gmsh scene (harness/scene/gmsh_geometry.py) as MSH 2.2 for FreeFEM, with the
physical tags rewritten to the role labels of harness/core/contract.py: FreeFEM never sees the
file's own names or numbers.

Levels (geometry.levels):
- split: the mesh of h = 1/coarsest, refined k times by a uniform split (each triangle into
  4, each tetrahedron into 8) for n = coarsest * 2^k. On a straight-sided body every coarse
  simplex is a union of fine ones, so a coarse P1 field is exactly a fine one. Triangles are
  split by gmsh (the split of a triangle is unique); tetrahedra by harness/mesh/tet_split.py along
  each octahedron's shortest diagonal (gmsh's fixed diagonal lets the quality fall level by
  level), unless a curve or surface of the body is curved: there gmsh's split puts the new
  nodes on the curve, which this harness does not, so gmsh splits such a body.
- remesh: a new mesh for each h = 1/n: every size of the file scaled by coarsest / n and
  none above h; not nested (the error transfer is the point-located nodal interpolant).

Every level is checked: positive orientation (a surface or volume gmsh meshed the other way
round is turned over), no inverted or degenerate element (refused, naming it), every
boundary facet with a role and no labelled facet inside the body, one outward normal on all
of Gamma_3 (a flat contact part); its elements' quality is measured where the level is built
(harness/mesh/mesh.py).
"""

from __future__ import annotations

import itertools
import math

import gmsh
import numpy as np

from harness.mesh import tet_split
from harness.core.contract import ROLE_LABELS
from harness.core.errors import MeshError
from harness.core.gmsh_api import session
from harness.scene.gmsh_geometry import GmshGeometry
from harness.mesh.msh import ELEMENT_TYPE
from harness.mesh.simplex import SimplexMesh, boundary_facets, outward_normals, signed_measures, turned_over

# A cell's name in messages.
CELL_NAME = {2: "triangle", 3: "tetra"}
# Signed measure below this fraction of (longest edge)^d: a flat element (round-off of a
# well-shaped one is 1e-16; the worst gmsh element a study uses is above 1e-3).
DEGENERATE = 1e-10
# Largest angle between two outward normals of Gamma_3's facets [rad]: round-off of a
# tilted flat face is ~1e-15 (measured on cases/tilted*.geo), a circle of radius R meshed at
# h turns by h / R between facets (0.06 for R = 1 at h = 1/16).
FLAT = 1e-8
# A surface whose coarsest mesh nodes lie within this fraction of its extent from one plane is
# flat (round-off of a turned plane is ~1e-16 of it); else curved, and gmsh splits the body.
COPLANAR = 1e-9


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
            by_gmsh = refinements if d == 2 or (refinements and curved_body()) else 0
            for _ in range(by_gmsh):
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
    regions = region_labels(geometry, entity_of_cell)
    facets, labels = labelled_boundary(points, cells, {tuple(sorted(index[list(f)])): r for f, r in named.items()}, n)
    mesh = tet_split.refine(SimplexMesh(points, cells, facets, labels, regions), refinements - by_gmsh)
    check_flat_contact(mesh.points, mesh.facets, mesh.labels, n)
    return mesh


def region_labels(geometry: GmshGeometry, entity_of_cell: np.ndarray) -> np.ndarray | None:
    """Each cell's region label (1 + the region's index in geometry.regions), or None when
    the scene maps no regions (every cell then carries BODY_LABEL, as before regions)."""
    if not geometry.regions:
        return None
    entities = dict(geometry.bodies)
    label_of = {e: i + 1 for i, name in enumerate(geometry.regions) for e in entities[name]}
    return np.array([label_of[int(e)] for e in entity_of_cell], dtype=int)


def curved_body() -> bool:
    """Whether the model gmsh holds (meshed) has a curve that is not a line or a surface whose
    mesh nodes are not on one plane: gmsh's split would put new nodes on it, off the edges'
    midpoints."""
    if any(gmsh.model.getType(1, tag) != "Line" for _, tag in gmsh.model.getEntities(1)):
        return True
    for _, tag in gmsh.model.getEntities(2):
        _, coords, _ = gmsh.model.mesh.getNodes(2, tag, includeBoundary=True)
        xyz = np.asarray(coords).reshape(-1, 3)
        if len(xyz) > 3:
            extent = float(np.ptp(xyz, axis=0).max())
            if np.linalg.svd(xyz - xyz.mean(axis=0), compute_uv=False)[-1] > COPLANAR * extent * math.sqrt(len(xyz)):
                return True
    return False


def read_cells(d: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every node (by gmsh tag - 1 rows), the d-simplices and the entity each belongs to."""
    tags, coords, _ = gmsh.model.mesh.getNodes()
    points = np.zeros((int(tags.max()) + 1, 3))
    points[tags.astype(int)] = coords.reshape(-1, 3)
    cells, owners = [], []
    for _, entity in gmsh.model.getEntities(d):
        types, _, nodes = gmsh.model.mesh.getElements(d, entity)
        for kind, block in zip(types, nodes):
            if int(kind) != ELEMENT_TYPE[d]:
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
                if int(kind) != ELEMENT_TYPE[d - 1]:
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


def oriented(points: np.ndarray, cells: np.ndarray, owners: np.ndarray, n: int) -> np.ndarray:
    """Positively oriented cells. gmsh orients each surface or volume one way: a surface
    drawn clockwise comes out all negative and is turned over; a cell against the majority
    of its entity is inverted, and a flat one degenerate: both refused, named."""
    d = cells.shape[1] - 1
    measure = signed_measures(points, cells)
    longest = np.max([np.linalg.norm(points[cells[:, i]] - points[cells[:, j]], axis=1)
                      for i, j in itertools.combinations(range(d + 1), 2)], axis=0)
    flat = np.abs(measure) <= DEGENERATE * longest**d
    kind = CELL_NAME[d]
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
