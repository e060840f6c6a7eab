"""Build the scene's structured triangle mesh at level n (h = 1/n) with gmsh, MSH 2.2.

gmsh keeps global state and is not thread-safe: call `build_mesh` from one thread at a time
(the study makes all meshes in the main thread before any FreeFEM run starts).
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Sequence

import gmsh
import numpy as np

from harness.core.atomic import sibling_temp, write_atomic
from harness.core.errors import EnvironmentFault, MeshError
from harness.core.faults import disk_full, fault
from harness.core.guards import mesh_file_bytes, need_disk
from harness.mesh.mesh_check import MeshSummary, check_arrays
from harness.scene.schema import ROLE_LABELS
from harness.scene.segments import Geometry
from harness.mesh.simplex import quality_warning
from harness.scene.box import Box
from harness.mesh import box_mesh, gmsh_mesh
from harness.scene.gmsh_geometry import GmshGeometry
from harness.core.gmsh_api import GMSH, session  # noqa: F401  (GMSH re-exported: whoever meshes from a thread holds it)

# gmsh's transfinite arrangement that cuts each cell along the requested diagonal.
ARRANGEMENT = {"SW-NE": "Right", "NW-SE": "Left"}
BODY_LABEL = 1


def mesh_path(directory: Path, n: int) -> Path:
    # ".msh" alone would be ambiguous with FreeFEM's own format; the name says which one.
    return directory / f"mesh_n{n}.msh"


def coarser_levels(n: int, count: int, coarsest: int = 2) -> list[int]:
    """Up to `count` levels below n, each half the one above, none below `coarsest`: the
    nested family a geometric multigrid at level n coarsens through."""
    levels: list[int] = []
    while len(levels) < count and n % 2 == 0 and n // 2 >= max(coarsest, 1):
        n //= 2
        levels.append(n)
    return levels


def family_levels(geometry: Geometry | Box | GmshGeometry, n: int, count: int, coarsest: int = 2) -> list[int]:
    """`coarser_levels` of the geometry's nested family: a split gmsh scene's starts at its
    own coarsest level."""
    if isinstance(geometry, GmshGeometry) and geometry.levels == "split":
        coarsest = max(coarsest, geometry.coarsest)
    return coarser_levels(n, count, coarsest)


def coarser_meshes(geometry: Geometry | Box | GmshGeometry, n: int, count: int, coarsest: int, directory: Path,
                   make: bool = True) -> list[Path]:
    """The meshes of `family_levels(geometry, n, count, coarsest)`, finest first; made (or
    refreshed) only with `make`: a run's cache key needs their names, not their files (2D
    n = 512's four coarser meshes take 9 s)."""
    levels = family_levels(geometry, n, count, coarsest)
    if not make:
        return [mesh_path(directory, m) for m in levels]
    with GMSH:
        return [build_mesh(geometry, m, directory, warn=False).path for m in levels]


def build_mesh(geometry: Geometry | Box | GmshGeometry, n: int, directory: Path, warn: bool = True) -> MeshSummary:
    """Write mesh_n<n>.msh into `directory` (only replacing it if the bytes change) and
    return its checked summary; `warn`: say when its quality is poor (the study's own levels,
    not the coarser meshes a run asks for again)."""
    if isinstance(geometry, Box):
        return build_box_mesh(geometry, n, directory)
    if isinstance(geometry, GmshGeometry):
        return build_gmsh_mesh(geometry, n, directory, warn)
    cells = {} if geometry.diagonals == "unstructured" else grid_cells(geometry, n)
    level = generate_rectangle(geometry, cells, n)
    # Checked in memory, before writing: re-reading the file took 41 % of the finest mesh's
    # time at n = 64.
    summary = check_arrays(level.points, level.triangles, level.lines, level.labels, geometry, n)
    target = write_level(lambda tmp: write_rectangle_msh(level, tmp), geometry, n, directory)
    return replace(summary, path=target)


def remove_partial_meshes(directory: Path, pids: list[int]) -> None:
    """Remove the temp files of mesh writers that were killed (sibling_temp names carry the pid)."""
    for pid in pids:
        for partial in directory.glob(f".mesh_n*.{pid}-*"):
            partial.unlink(missing_ok=True)


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


@dataclass(frozen=True)
class RectangleMesh:
    """A rectangle scene's level as gmsh made it, held in memory in gmsh's own order (so
    FreeFEM numbers nodes, edges and triangles as it did from gmsh's file)."""

    points: np.ndarray      # (N, 2), row k = gmsh node tag k + 1
    lines: np.ndarray       # (B, 2) boundary edges, curve by curve
    labels: np.ndarray      # (B,) their role labels (physical tags)
    curves: np.ndarray      # (B,) their gmsh curve (elementary tag)
    triangles: np.ndarray   # (M, 3), surface by surface
    surfaces: np.ndarray    # (M,) their gmsh surface


def generate_rectangle(geometry: Geometry, cells: dict[float, int], n: int) -> RectangleMesh:
    """The level-n mesh: gmsh's transfinite strips snapped onto the h-lattice, or (no
    `cells`) its unstructured triangles distorted. The nodes are moved in numpy, not by
    gmsh's per-node setNode, which took 44 % of the finest mesh's time at n = 64."""
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
    points = snap_to_lattice(mesh.points, n) if cells else distort(mesh.points, mesh.triangles, inner, n)
    return replace(mesh, points=points)


def read_rectangle() -> tuple[RectangleMesh, np.ndarray]:
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
    mesh = RectangleMesh(points[:, :2], np.vstack(lines), np.concatenate(labels), np.concatenate(curves),
                         np.vstack(triangles), np.concatenate(surfaces))
    return mesh, inner.astype(np.int64) - 1


def write_rectangle_msh(mesh: RectangleMesh, target: Path) -> None:
    """MSH 2.2 byte for byte as gmsh's own writer makes it (coordinates %.16g, physical and
    elementary tags; tests/test_mesh.py compares), so FreeFEM reads what it read from gmsh.
    Each section is one printf-style format over the whole array: meshio's writer formats
    line by line and took 0.36 s of the 0.43 s of n = 64's mesh."""
    names = sorted([(1, int(label), role) for role, label in ROLE_LABELS.items() if (mesh.labels == label).any()]
                   + [(2, BODY_LABEL, "body")])
    lines, triangles = len(mesh.lines), len(mesh.triangles)
    nodes = np.column_stack([np.arange(1, len(mesh.points) + 1), mesh.points])
    edges = np.column_stack([np.arange(1, lines + 1), mesh.labels, mesh.curves, mesh.lines + 1])
    cells = np.column_stack([np.arange(lines + 1, lines + triangles + 1), np.full(triangles, BODY_LABEL),
                             mesh.surfaces, mesh.triangles + 1])
    text = "".join([
        "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n",
        f"$PhysicalNames\n{len(names)}\n", "".join(f'{d} {t} "{name}"\n' for d, t, name in names), "$EndPhysicalNames\n",
        f"$Nodes\n{len(nodes)}\n", ("%d %.16g %.16g 0\n" * len(nodes)) % tuple(nodes.ravel().tolist()), "$EndNodes\n",
        f"$Elements\n{lines + triangles}\n",
        ("%d 1 2 %d %d %d %d\n" * lines) % tuple(edges.ravel().tolist()),
        ("%d 2 2 %d %d %d %d %d\n" * triangles) % tuple(cells.ravel().tolist()),
        "$EndElements\n",
    ])
    target.write_text(text)


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
        a, b, c = (moved[tri[:, k]] for k in range(3))
        area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
        bad = np.unique(tri[area <= 0.05 / n**2])  # inverted or nearly flat: undo its nodes
        bad = bad[np.isin(bad, inner) & (moved[bad] != points[bad]).any(axis=1)]
        if not len(bad):
            return moved
        moved[bad] = points[bad]


def build_box_mesh(box: Box, n: int, directory: Path) -> MeshSummary:
    """The Kuhn tetrahedral mesh of a box scene (harness/mesh/box_mesh.py), checked: the area of
    each role's triangles equals its patches' area (role_lengths holds areas in 3D)."""
    if box.diagonals == "unstructured":
        points, tetrahedra = unstructured_box(box, n)
        tetrahedra = box_mesh.orient_positive(points, tetrahedra)
        triangles, labels = box_mesh.boundary_faces(points, tetrahedra, box.lengths, box.role_of)
        mesh = box_mesh.BoxMesh(points, tetrahedra, triangles, labels)
    else:
        mesh = box_mesh.kuhn_box(box.lengths, n, box.role_of)
    areas = dict.fromkeys(ROLE_LABELS, 0.0)
    p = mesh.points[mesh.triangles]
    tri_area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    for role, label in ROLE_LABELS.items():
        areas[role] = float(tri_area[mesh.labels == label].sum())
    areas = {role: a for role, a in areas.items() if a > 0}
    expected = box.role_areas()
    for role in set(areas) | set(expected):
        if not np.isclose(areas.get(role, 0.0), expected.get(role, 0.0), rtol=1e-9, atol=1e-12):
            raise MeshError(f"mesh n={n}: role {role} covers {areas.get(role, 0.0):.6g}, its patches {expected.get(role, 0.0):.6g}")
    target = write_level(lambda tmp: box_mesh.write_msh(mesh, tmp), box, n, directory)
    return MeshSummary(path=target, n=n, nodes=len(mesh.points), triangles=len(mesh.tetrahedra), role_lengths=areas)


def write_level(write: Callable[[Path], None], geometry: Geometry | Box | GmshGeometry, n: int,
                directory: Path) -> Path:
    """mesh_n<n>.msh in `directory` by `write` into a temp file, replacing the level's file
    only when the bytes change (a cached run keyed by the mesh's checksum stays valid)."""
    directory.mkdir(parents=True, exist_ok=True)
    target = mesh_path(directory, n)
    need_disk(directory, mesh_file_bytes(geometry, n), f"the mesh of n={n}")
    tmp = sibling_temp(target).with_suffix(".msh")
    try:
        write(tmp)
        if not target.exists() or target.read_bytes() != tmp.read_bytes():
            os.replace(tmp, target)
    except OSError as exc:
        if disk_full(directory):  # a failed write() names no file: say which one
            raise EnvironmentFault(f"no space left on the device for {target} (the mesh of n={n})") from None
        raise fault(exc, f"mesh of n={n}") from None
    finally:
        tmp.unlink(missing_ok=True)
    return target


def build_gmsh_mesh(geometry: GmshGeometry, n: int, directory: Path, warn: bool = True) -> MeshSummary:
    """Level n of a scene drawn in gmsh (harness/mesh/gmsh_mesh.py), its labels the roles'; with
    `warn`, one warning line when its quality is below simplex.QUALITY_FLOORS."""
    mesh = gmsh_mesh.generate(geometry, n)
    target = write_level(lambda tmp: gmsh_mesh.write_msh(mesh, tmp), geometry, n, directory)
    worse = quality_warning(mesh.quality) if warn else None
    if worse:
        print(f"warning: mesh n={n} of {geometry.file.name}: {worse}: expect larger errors and slower convergence "
              "at every level split from it; mesh the coarsest level finer or better (gmsh's Mesh.Optimize, "
              "Mesh.OptimizeNetgen)", file=sys.stderr, flush=True)
    return MeshSummary(path=target, n=n, nodes=len(mesh.points), triangles=len(mesh.cells),
                       role_lengths=gmsh_mesh.role_measures(mesh), quality=mesh.quality)


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


def graded_coordinate(t: np.ndarray, focus: Sequence[float], power: float) -> np.ndarray:
    """A monotone map of [a, b] onto itself that fixes the focus points and the breakpoints
    between them and packs the lattice towards the focus points: on a segment from a focus
    point f to the next breakpoint or focus point g (half-way between two focus points),
    s = (t - f)/(g - f) becomes s^power: cells of size ~h^power at the focus against
    power * h far from it (an r^(1/2) singularity asks for power >= 2 with P1, which
    coarsens the rest of the mesh too much here: see docs/cost.md)."""
    out = t.astype(float).copy()
    points = sorted(focus)
    for i, f in enumerate(points):
        left = (points[i - 1] + f) / 2 if i > 0 else None
        right = (f + points[i + 1]) / 2 if i + 1 < len(points) else None
        lo = left if left is not None else -np.inf
        hi = right if right is not None else np.inf
        for end in (lo, hi):
            if not np.isfinite(end):
                end = t.min() if end < 0 else t.max()
            span = end - f
            if span == 0:
                continue
            mask = (t - f) / span >= 0
            mask &= (t >= min(f, end)) & (t <= max(f, end))
            out[mask] = f + span * ((t[mask] - f) / span) ** power
    return out


def graded_msh(uniform: Path, target: Path, width: float, focus_x: Sequence[float], power: float) -> None:
    """Copy a structured MSH 2.2 mesh with its nodes moved by graded_coordinate in x
    (towards focus_x) and in y (towards y = 0). The topology, labels and orientation (both
    maps are increasing) are unchanged; the family is no longer nested."""
    lines = uniform.read_text().splitlines()
    start = lines.index("$Nodes") + 2
    count = int(lines[start - 1])
    rows = [line.split() for line in lines[start:start + count]]
    xy = np.array([[float(r[1]), float(r[2])] for r in rows])
    gx = graded_coordinate(np.clip(xy[:, 0], 0, width), focus_x, power)
    gy = graded_coordinate(xy[:, 1], [0.0], power)
    for i, r in enumerate(rows):
        lines[start + i] = f"{r[0]} {float(gx[i])!r} {float(gy[i])!r} {r[3]}"
    target.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(target, "\n".join(lines) + "\n")


def contact_ends(geometry: Geometry) -> list[float]:
    """The x of the ends of the contact segments on the bottom (the ends of Gamma_3)."""
    return sorted({x for seg in geometry.bottom if seg.role == "contact" for x in (seg.x0, seg.x1)})


def build_graded_mesh(geometry: Geometry, n: int, directory: Path, power: float) -> Path:
    """The level-n mesh graded towards the ends of Gamma_3 (x) and the bottom (y) with
    `power` (graded_msh); the uniform mesh when power is 1."""
    uniform = build_mesh(geometry, n, directory).path
    if power == 1.0:
        return uniform
    graded = uniform.with_name(f"graded_n{n}.msh")
    graded_msh(uniform, graded, geometry.width, contact_ends(geometry), power)
    return graded
