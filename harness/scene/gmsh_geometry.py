"""A scene drawn in gmsh (`[geometry] kind = "gmsh"`): a .geo file whose boundary parts are
named physical groups (curves in 2D, surfaces in 3D), each mapped to a role of
harness/core/contract.py ROLE_LABELS by the case file's [geometry.roles] table.

The file is read once when the scene loads, so every mistake in it (a missing file, a gmsh
syntax error, a name without a role, a role naming no group, a body gmsh meshes in the other
dimension) ends the command before anything runs. The contact part is kept
as the facets of a mesh of its own curves or surfaces: straight or flat pieces, so any
level's Gamma_3 nodes are found by lying on them (checks.py), whatever the body's shape.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gmsh
import numpy as np

from harness.core.contract import ROLE_LABELS
from harness.scene.cell_size import Body
from harness.scene.electrodes import Part
from harness.core.errors import SceneError
from harness.core.gmsh_api import session
from harness.core.layout import case_path

LEVEL_KINDS = ("split", "remesh")


# Triangle area [m^2] below which a 2D level is read by freefem/dimension.idp's own reader:
# 100 times gmshload's absolute threshold 1e-8, for remeshed levels that do not scale exactly.
SMALL_CELL = 1e-6

@dataclass(frozen=True)
class GmshGeometry:
    file: Path                      # absolute
    dimension: int
    roles: tuple[tuple[str, str], ...]  # (physical name, role), in the case file's order
    levels: str                     # split: refinements of the coarsest mesh; remesh: a mesh per h
    coarsest: int                   # the level n whose mesh (h = 1/n) split refines
    bounds: tuple[float, ...]       # gmsh's bounding box: xmin, ymin, zmin, xmax, ymax, zmax
    contact: tuple[tuple[tuple[float, ...], ...], ...] = ()  # Gamma_3's facets (d points of d coordinates)
    # The coarsest mesh's vertices, edges, (3D: faces,) cells: the guards' node counts.
    coarsest_counts: tuple[int, ...] = ()
    coarsest_min_cell: float = math.inf  # its smallest triangle's area (2D) [m^2]
    # The file's named physical surfaces (2D) or volumes (3D) with their entities, and the
    # entities of the body in none of them.
    bodies: tuple[tuple[str, tuple[int, ...]], ...] = ()
    unnamed_bodies: tuple[int, ...] = ()
    # The material regions a scene maps (harness/scene/regions.py), in label order: the cells of
    # regions[i] carry the label i + 1 in the mesh; none: every cell carries 1.
    regions: tuple[str, ...] = ()
    # Each physical group's corner points (gmsh's points in the closure of its entities).
    corners: tuple[tuple[str, tuple[tuple[float, ...], ...]], ...] = ()
    body_boxes: tuple[Body, ...] = ()  # each part of the body (harness/scene/cell_size.py)

    def body_parts(self) -> tuple[Body, ...]:
        return self.body_boxes

    def parts(self) -> tuple[Part, ...]:
        """Each part's corner points, for the electrode check (harness/scene/electrodes.py): in a
        drawing whose parts share their end points, parts touch exactly where they share one."""
        roles = self.role_of_name
        return tuple(Part(f"{self.file.name}: {name!r}", roles[name], p, p) for name, points in self.corners
                     for p in points if name in roles)

    @property
    def role_of_name(self) -> dict[str, str]:
        return dict(self.roles)

    def used_roles(self) -> frozenset[str]:
        return frozenset(role for _, role in self.roles)

    def contact_normals(self) -> np.ndarray:
        """A normal of each contact facet (rows; unnormalised)."""
        normals = []
        for facet in self.contact:
            edges = np.array(facet[1:]) - np.array(facet[0])
            normals.append((-edges[0][1], edges[0][0]) if self.dimension == 2 else np.cross(edges[0], edges[1]))
        return np.array(normals, dtype=float).reshape(-1, self.dimension)

    def nodes_at(self, n: int) -> int:
        """Nodes of level n for the memory and disk guards (harness/core/guards.py): exact for a
        split level n = coarsest 2^k (each split adds a node on every edge: V' = V + E; in 2D
        E' = 2E + 3T, T' = 4T; in 3D E' = 2E + 3F + T, F' = 4F + 8T, T' = 8T), and that
        count scaled by the remaining (n / (coarsest 2^k))^d between powers of 2 (remesh)."""
        counts = list(self.coarsest_counts)
        level = self.coarsest
        while 2 * level <= n:
            if self.dimension == 2:
                v, e, t = counts
                counts = [v + e, 2 * e + 3 * t, 4 * t]
            else:
                v, e, f, t = counts
                counts = [v + e, 2 * e + 3 * f + t, 4 * f + 8 * t, 8 * t]
            level *= 2
        return math.ceil(counts[0] * (n / level) ** self.dimension)

    def small_cells(self, n: int) -> bool:
        """Whether level n may hold a triangle below SMALL_CELL: FreeFEM's gmshload refuses
        one under 1e-8 (freefem/dimension.idp), so its runs read meshes with the script's own
        reader (-mesh.small_cells). A split divides areas by 4 exactly; a remesh about as much,
        hence the margin of SMALL_CELL over 1e-8."""
        return self.dimension == 2 and self.coarsest_min_cell * (self.coarsest / n) ** 2 < SMALL_CELL

    # The bounding box: what a study that asks for a scene's extent gets.
    @property
    def width(self) -> float:
        return self.bounds[3] - self.bounds[0]

    @property
    def height(self) -> float:
        axis = 2 if self.dimension == 3 else 1
        return self.bounds[3 + axis] - self.bounds[axis]

    @property
    def ly(self) -> float:
        return self.bounds[4] - self.bounds[1]

    def contact_measure(self) -> float:
        """|Gamma_3|: a length in 2D, an area in 3D."""
        return float(sum(facet_measure(np.array(f)) for f in self.contact))

    def contact_mask(self, points: np.ndarray) -> np.ndarray:
        """Which points lie on Gamma_3 (within 1e-6 of the body's size: solution.vtu holds
        single-precision coordinates)."""
        tol = 1e-6 * max(self.width, self.height, 1e-300)
        on = np.zeros(len(points), dtype=bool)
        for facet in self.contact:
            on |= distance_to_facet(points[:, :self.dimension], np.array(facet), tol) <= tol
        return on


def facet_measure(corners: np.ndarray) -> float:
    edges = corners[1:] - corners[0]
    if len(corners) == 2:
        return float(np.linalg.norm(edges[0]))
    return 0.5 * float(np.linalg.norm(np.cross(edges[0], edges[1])))


def distance_to_facet(points: np.ndarray, corners: np.ndarray, tol: float) -> np.ndarray:
    """Distance of each point to a segment (2D) or a triangle (3D): to the nearest point of
    a segment; to a triangle's plane for a point whose projection falls inside the triangle
    widened by `tol` (a node on an edge shared by two facets belongs to both), infinite
    otherwise."""
    a = corners[0]
    edges = corners[1:] - a                      # (k, d)
    gram = edges @ edges.T
    t = np.linalg.solve(gram, edges @ (points - a).T).T  # (N, k): least-squares coordinates
    if len(edges) == 1:
        t = np.clip(t, 0.0, 1.0)
    else:
        slack = tol / math.sqrt(2.0 * facet_measure(corners))  # tol in barycentric units
        outside = (t < -slack).any(axis=1) | (t.sum(axis=1) > 1 + slack)
        t[outside] = np.nan  # off the triangle's plane region: not on this facet
    nearest = a + t @ edges
    d = np.linalg.norm(points - nearest, axis=1)
    return np.where(np.isnan(d), np.inf, d)


def parse_gmsh(table: dict[str, Any], case_dir: Path, levels: list[int], effects: list[str]) -> GmshGeometry:
    """Read and check the scene's .geo; `levels` (the study's) gives the default coarsest."""
    dimension = table["dimension"]
    file = case_path(case_dir, table["file"], "geometry.file")
    if not file.is_file():
        raise SceneError(f"geometry.file: no such file {file}")
    roles = table["roles"]
    if not isinstance(roles, dict) or not roles:
        raise SceneError("geometry.roles must be a table of physical-group name = role")
    for name, role in roles.items():
        if role not in ROLE_LABELS:
            raise SceneError(f"geometry.roles.{name} = {role!r}: role must be one of {', '.join(ROLE_LABELS)}")
    used = set(roles.values())
    if "contact" in effects and "contact" not in used:
        raise SceneError("geometry.roles: the contact part is empty (no name maps to role contact) but effect "
                         "'contact' is on")
    coarsest = table["coarsest"] or min(levels)
    found, bounds, contact, counts, smallest, bodies, unnamed, corners, boxes = read_geo(
        file, dimension, coarsest, [n for n, r in roles.items() if r == "contact"])
    facet = "curve" if dimension == 2 else "surface"
    for name in found:
        if name not in roles:
            raise SceneError(f"{file.name}: physical {facet} {name!r} has no role in [geometry.roles]")
    for name in roles:
        if name not in found:
            raise SceneError(f"geometry.roles.{name}: {file.name} has no physical {facet} named {name!r} "
                             "(or it holds no entity)")
    if "contact" in used and not contact:
        raise SceneError(f"{file.name}: the contact part is empty (no {facet} in it)")
    return GmshGeometry(file=file, dimension=dimension, roles=tuple(roles.items()), levels=table["levels"],
                        coarsest=coarsest, bounds=bounds, contact=contact, coarsest_counts=counts,
                        coarsest_min_cell=smallest, bodies=bodies, unnamed_bodies=unnamed, corners=corners,
                        body_boxes=boxes)


def read_geo(file: Path, dimension: int, coarsest: int, contact_names: list[str]) -> tuple[
        dict[str, list[int]], tuple[float, ...], tuple[tuple[tuple[float, ...], ...], ...], tuple[int, ...], float,
        tuple[tuple[str, tuple[int, ...]], ...], tuple[int, ...], tuple[tuple[str, tuple[tuple[float, ...], ...]], ...],
        tuple[Body, ...]]:
    """The names of the file's physical groups of dimension d - 1 (with their entities),
    its bounding box, the contact entities' facets, the coarsest level's mesh's counts
    of vertices, edges, (faces,) cells (h = 1/coarsest), (2D) its smallest triangle's area,
    its named physical groups of dimension d (the body's regions) with their entities, the
    body's entities in none of them, each boundary group's corner points and the body's
    parts (harness/scene/cell_size.py)."""
    with session():
        try:
            gmsh.open(str(file))
        except Exception as exc:  # gmsh raises a bare Exception carrying its log line
            raise SceneError(f"gmsh cannot read {file.name}: {exc}") from None
        drawn = gmsh.model.getDimension()
        if drawn != dimension:
            raise SceneError(f"{file.name} draws a {drawn}D body but geometry.dimension = {dimension}")
        if dimension == 2:
            box = gmsh.model.getBoundingBox(-1, -1)
            # OpenCASCADE pads its bounding boxes by ~1e-7: a body in z = 0 is within that.
            if max(abs(box[2]), abs(box[5])) > 1e-6 * max(box[3] - box[0], box[4] - box[1]):
                raise SceneError(f"{file.name}: a 2D body must lie in the plane z = 0")
        found: dict[str, list[int]] = {}
        for dim, tag in gmsh.model.getPhysicalGroups(dimension - 1):
            entities = [int(e) for e in gmsh.model.getEntitiesForPhysicalGroup(dim, tag)]
            name = gmsh.model.getPhysicalName(dim, tag) or str(tag)
            if entities:
                found.setdefault(name, []).extend(entities)
        bodies: dict[str, list[int]] = {}
        for dim, tag in gmsh.model.getPhysicalGroups(dimension):
            name = gmsh.model.getPhysicalName(dim, tag) or str(tag)
            bodies.setdefault(name, []).extend(int(e) for e in gmsh.model.getEntitiesForPhysicalGroup(dim, tag))
        named = {e for group in bodies.values() for e in group}
        unnamed = tuple(int(tag) for _, tag in gmsh.model.getEntities(dimension) if int(tag) not in named)
        bounds = tuple(float(b) for b in gmsh.model.getBoundingBox(-1, -1))
        corners = tuple((name, corner_points(dimension, tags)) for name, tags in found.items())
        boxes = body_pieces(file.name, dimension)
        entities = [e for name in contact_names for e in found.get(name, [])]
        gmsh.option.setNumber("Mesh.MeshSizeMax", 1.0 / coarsest)
        try:
            gmsh.model.mesh.generate(dimension)
        except Exception as exc:
            raise SceneError(f"gmsh cannot mesh {file.name} at h = 1/{coarsest}: {exc}") from None
        counts = simplex_counts(dimension)
        smallest = smallest_triangle() if dimension == 2 else math.inf
        contact = contact_facets(dimension, entities) if entities else ()
    return (found, bounds, contact, counts, smallest, tuple((k, tuple(v)) for k, v in bodies.items()), unnamed,
            corners, boxes)


def body_pieces(file_name: str, dimension: int) -> tuple[Body, ...]:
    """Each physical group of the body (surfaces in 2D, volumes in 3D; the entities in none
    together) by its name and the bounding box of its entities: a part, whatever pieces it was
    drawn in (a strip drawn as three surfaces is one 20 x 1 part, not a 0.5 x 1 piece)."""
    boxes: dict[str, list[list[float]]] = {}
    for _, tag in gmsh.model.getEntities(dimension):
        groups = gmsh.model.getPhysicalGroupsForEntity(dimension, tag)
        name = next((gmsh.model.getPhysicalName(dimension, int(g)) or str(g) for g in groups), "")
        boxes.setdefault(name, []).append(list(gmsh.model.getBoundingBox(dimension, tag)))
    what = "surface" if dimension == 2 else "volume"
    out = []
    for name, found in boxes.items():
        box = np.array(found)
        label = f"{file_name}: physical {what} {name!r}" if name else f"{file_name}: the body"
        out.append(Body(label, tuple(float(x) for x in box[:, :dimension].min(axis=0)),
                        tuple(float(x) for x in box[:, 3:3 + dimension].max(axis=0))))
    return tuple(out)


def corner_points(dimension: int, entities: list[int]) -> tuple[tuple[float, ...], ...]:
    """The coordinates of gmsh's points in the closure of the entities (of dimension d - 1)."""
    closure = gmsh.model.getBoundary([(dimension - 1, e) for e in entities], combined=False, oriented=False,
                                     recursive=True)
    tags = sorted({tag for dim, tag in closure if dim == 0})
    return tuple(tuple(float(x) for x in gmsh.model.getValue(0, tag, [])[:dimension]) for tag in tags)


def smallest_triangle() -> float:
    """The smallest area among the triangles of gmsh's current 2D mesh."""
    tags, coords, _ = gmsh.model.mesh.getNodes()
    points = np.zeros((int(tags.max()) + 1, 3))
    points[tags.astype(np.int64)] = coords.reshape(-1, 3)
    _, nodes = gmsh.model.mesh.getElementsByType(2)  # 3-node triangles
    a, b, c = (points[np.asarray(nodes, dtype=np.int64).reshape(-1, 3)[:, k], :2] for k in range(3))
    u, v = b - a, c - a
    return float(np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]).min() / 2)


def simplex_counts(dimension: int) -> tuple[int, ...]:
    """Vertices, edges, (faces,) cells of gmsh's current mesh of the body."""
    cells = []
    for _, entity in gmsh.model.getEntities(dimension):
        for kind, _, nodes in zip(*gmsh.model.mesh.getElements(dimension, entity)):
            name, _, order, per = gmsh.model.mesh.getElementProperties(int(kind))[:4]
            if per != dimension + 1 or order != 1:
                raise SceneError(f"gmsh makes {name} elements; only first-order triangles (2D) and tetrahedra (3D) "
                                 "are solved (no Recombine, Mesh.ElementOrder = 1)")
            cells.append(np.asarray(nodes, dtype=np.int64).reshape(-1, per))
    if not cells:
        raise SceneError(f"gmsh made no {dimension}D elements")
    cells = np.vstack(cells)
    counts = [len(np.unique(cells))]
    for k in range(2, dimension + 1):  # edges, then (3D) faces
        pieces = np.vstack([cells[:, list(c)] for c in itertools.combinations(range(dimension + 1), k)])
        counts.append(len(np.unique(np.sort(pieces, axis=1), axis=0)))
    return tuple(counts + [len(cells)])


def contact_facets(dimension: int, entities: list[int]) -> tuple[tuple[tuple[float, ...], ...], ...]:
    """The facets of the meshed contact entities: straight segments or flat triangles that
    cover them exactly when they are straight or flat (checked per level by
    harness/mesh/gmsh_mesh.py)."""
    tags, coords, _ = gmsh.model.mesh.getNodes()
    where = dict(zip((int(t) for t in tags), coords.reshape(-1, 3)[:, :dimension]))
    out = []
    for entity in entities:
        for kind, _, nodes in zip(*gmsh.model.mesh.getElements(dimension - 1, entity)):
            per = gmsh.model.mesh.getElementProperties(int(kind))[3]
            for cell in np.asarray(nodes, dtype=int).reshape(-1, per)[:, :dimension]:
                out.append(tuple(tuple(float(x) for x in where[int(t)]) for t in cell))
    return tuple(out)
