"""The rectangle scene's level n (h = 1/n) with gmsh: transfinite strips between the
breakpoints of its boundary segments, snapped onto the h-lattice (nested levels), or gmsh's
unstructured triangles with their interior nodes shifted (geometry.diagonals =
"unstructured"); a SimplexMesh in gmsh's own order, with gmsh's curves and strips as its
entities, so that its file is the one gmsh would write (harness/mesh/msh.py, AS_GMSH).

gmsh keeps global state and is not thread-safe: call `generate` from one thread at a time
(the study makes all meshes in the main thread before any FreeFEM run starts).
"""

from __future__ import annotations

from dataclasses import replace

import gmsh
import numpy as np

from harness.core.contract import BODY_LABEL, ROLE_LABELS
from harness.core.errors import MeshError
from harness.core.gmsh_api import session
from harness.mesh.simplex import SimplexMesh, signed_measures
from harness.scene.segments import Geometry

# gmsh's transfinite arrangement that cuts each cell along the requested diagonal.
ARRANGEMENT = {"SW-NE": "Right", "NW-SE": "Left"}


def generate(geometry: Geometry, n: int) -> SimplexMesh:
    """The level-n mesh: gmsh's transfinite strips snapped onto the h-lattice, or (geometry.diagonals
    = "unstructured") its unstructured triangles distorted. The nodes are moved in numpy, not by
    gmsh's per-node setNode, which took 44 % of the finest mesh's time at n = 64."""
    cells = {} if geometry.diagonals == "unstructured" else grid_cells(geometry, n)
    try:
        with session():
            gmsh.model.add("scene")
            add_strips(geometry, cells, size=0.0 if cells else 1.0 / n)
            gmsh.model.mesh.generate(2)
            mesh, inner = read_rectangle()
    except MeshError:
        raise
    except Exception as exc:  # gmsh raises a bare Exception with its own log text
        raise MeshError(f"gmsh failed: {exc}") from None
    points = snap_to_lattice(mesh.points, n) if cells else distort(mesh.points, mesh.cells, inner, n)
    return replace(mesh, points=points)


def grid_cells(geometry: Geometry, n: int) -> dict[float, int]:
    """Number of cells along each breakpoint coordinate and the height; each must be a
    whole number of h = 1/n or the strips cannot be structured."""
    cells = {}
    for x in geometry.breakpoints() + (geometry.height,):
        count = round(x * n)
        if abs(count - x * n) > 1e-9 * max(1.0, x * n):  # round-off of x*n only
            raise MeshError(f"n={n}: {x} is not a multiple of h = 1/{n}")
        cells[x] = count
    if cells[geometry.height] == 0:
        raise MeshError(f"n={n}: height {geometry.height} is below h = 1/{n}")
    return cells


def read_rectangle() -> tuple[SimplexMesh, np.ndarray]:
    """gmsh's mesh in the order its MSH 2.2 writer uses (nodes by tag, then each physical
    curve's edges, then each surface's triangles), and the nodes inside the surfaces (in
    gmsh's order: distort's random shifts follow it)."""
    tags, coords, _ = gmsh.model.mesh.getNodes()
    tags = tags.astype(np.int64)
    if tags.min() != 1 or tags.max() != len(tags):
        raise MeshError("gmsh numbered its nodes with gaps")
    points = np.zeros((len(tags), 3))
    points[tags - 1] = coords.reshape(-1, 3)
    lines, labels, curves = [], [], []
    for _, curve in gmsh.model.getEntities(1):
        for group in gmsh.model.getPhysicalGroupsForEntity(1, curve):
            _, _, nodes = gmsh.model.mesh.getElements(1, curve)
            block = np.asarray(nodes[0], dtype=np.int64).reshape(-1, 2) - 1
            lines.append(block)
            labels.append(np.full(len(block), group))
            curves.append(np.full(len(block), curve))
    triangles, surfaces = [], []
    for _, surface in gmsh.model.getEntities(2):
        _, _, nodes = gmsh.model.mesh.getElements(2, surface)
        block = np.asarray(nodes[0], dtype=np.int64).reshape(-1, 3) - 1
        triangles.append(block)
        surfaces.append(np.full(len(block), surface))
    inner, _, _ = gmsh.model.mesh.getNodes(2, -1, includeBoundary=False)
    mesh = SimplexMesh(points[:, :2], np.vstack(triangles), np.vstack(lines), np.concatenate(labels),
                       facet_entities=np.concatenate(curves), cell_entities=np.concatenate(surfaces))
    return mesh, inner.astype(np.int64) - 1


def add_strips(geometry: Geometry, cells: dict[float, int], size: float = 0.0) -> None:
    """One transfinite surface per vertical strip between consecutive breakpoints; with no
    `cells`, plain surfaces that gmsh meshes unstructured with triangles of about `size`."""
    geo = gmsh.model.geo
    xs, height = geometry.breakpoints(), geometry.height
    low = [geo.addPoint(x, 0.0, 0.0, size) for x in xs]
    high = [geo.addPoint(x, height, 0.0, size) for x in xs]
    verticals = [geo.addLine(a, b) for a, b in zip(low, high)]
    roles: dict[str, list[int]] = {role: [] for role in ROLE_LABELS}
    roles[geometry.left].append(verticals[0])
    roles[geometry.right].append(verticals[-1])
    surfaces = []
    for i in range(len(xs) - 1):
        bottom = geo.addLine(low[i], low[i + 1])
        top = geo.addLine(high[i + 1], high[i])
        # Counter-clockwise loop, so the triangles come out positively oriented.
        loop = geo.addCurveLoop([bottom, verticals[i + 1], top, -verticals[i]])
        surface = geo.addPlaneSurface([loop])
        if cells:
            across = cells[xs[i + 1]] - cells[xs[i]] + 1
            for line in (bottom, top):
                geo.mesh.setTransfiniteCurve(line, across)
            geo.mesh.setTransfiniteSurface(
                surface, ARRANGEMENT[geometry.diagonals], [low[i], low[i + 1], high[i + 1], high[i]]
            )
        mid = 0.5 * (xs[i] + xs[i + 1])
        roles[role_at(geometry.bottom, mid)].append(bottom)
        roles[role_at(geometry.top, mid)].append(top)
        surfaces.append(surface)
    for line in verticals if cells else ():
        geo.mesh.setTransfiniteCurve(line, cells[height] + 1)
    geo.synchronize()
    for role, curves in roles.items():
        if curves:
            gmsh.model.addPhysicalGroup(1, curves, ROLE_LABELS[role], name=role)
    gmsh.model.addPhysicalGroup(2, surfaces, BODY_LABEL, name="body")


def role_at(segments, x: float) -> str:
    return next(s.role for s in segments if s.x0 < x < s.x1)


def snap_to_lattice(points: np.ndarray, n: int) -> np.ndarray:
    """Every node exactly on the h-lattice. gmsh's transfinite nodes carry ~1e-12 round-off;
    exact lattice nodes make level n's nodes exactly nodes of level 2n."""
    snapped = np.round(points * n) / n
    # Anything beyond round-off means the mesh is not the structured lattice we asked for.
    if np.abs(snapped - points).max() > 1e-6 / n:
        raise MeshError(f"n={n}: gmsh placed nodes off the h-lattice")
    return snapped


def distort(points: np.ndarray, tri: np.ndarray, inner: np.ndarray, n: int, fraction: float = 0.3) -> np.ndarray:
    """Shift every interior node by a pseudo-random vector of up to `fraction` h per
    coordinate (seeded by n: the same mesh every time); a node whose shift would invert a
    triangle keeps its place. Boundary nodes stay, so the boundary roles are exact."""
    moved = points.copy()
    moved[inner] += np.random.default_rng(n).uniform(-fraction, fraction, (len(inner), 2)) / n
    while True:
        # Inverted or nearly flat (below a 20th of a lattice cell's half, h^2 / 2): undo its nodes.
        bad = np.unique(tri[signed_measures(moved, tri) <= 0.025 / n**2])
        bad = bad[np.isin(bad, inner) & (moved[bad] != points[bad]).any(axis=1)]
        if not len(bad):
            return moved
        moved[bad] = points[bad]
