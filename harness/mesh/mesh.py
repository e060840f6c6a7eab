"""One level's mesh file for any scene: the level from its generator (a SimplexMesh: the
rectangle's in harness/mesh/rectangle_mesh.py, the box's in box_mesh.py, a gmsh scene's in
gmsh_mesh.py), checked, then written as MSH 2.2 (harness/mesh/msh.py) only where its bytes
change; and the nested families of coarser levels, and graded copies of a level.

gmsh keeps global state and is not thread-safe: call `build_mesh` from one thread at a time
(the study makes all meshes in the main thread before any FreeFEM run starts).
"""

from __future__ import annotations

import os
import sys
from dataclasses import replace
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from harness.core.atomic import sibling_temp, write_atomic
from harness.core.errors import EnvironmentFault, MeshError
from harness.core.faults import disk_full, fault
from harness.core.guards import mesh_file_bytes, need_disk
from harness.mesh import box_mesh, gmsh_mesh, rectangle_mesh
from harness.mesh.jitter import Jitter, jittered
from harness.mesh.mesh_check import MeshSummary, check_arrays
from harness.mesh.msh import AS_GMSH, AS_GRADED, AS_MESHIO, MshStyle, msh_text, write_msh
from harness.mesh.simplex import SimplexMesh, quality, quality_warning, role_measures
from harness.scene.blocks import Block, block_labels, check_on_grid
from harness.scene.box import Box
from harness.scene.gmsh_geometry import GmshGeometry
from harness.scene.segments import Geometry
from harness.core.gmsh_api import GMSH  # noqa: F401  (re-exported: whoever meshes from a thread holds it)


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


def build_mesh(geometry: Geometry | Box | GmshGeometry, n: int, directory: Path, warn: bool = True,
               jitter: Jitter | None = None) -> MeshSummary:
    """Write mesh_n<n>.msh into `directory` (only replacing it if the bytes change) and
    return its checked summary; `warn`: say when its quality is poor (the study's own levels,
    not the coarser meshes a run asks for again); `jitter`: its interior nodes moved so
    (harness/mesh/jitter.py, the branch-stability study's meshes only), after the checks,
    which a move of round-off's order cannot change. A run's key holds its mesh's checksum,
    so a run on a jittered mesh is never served one on the level as generated."""
    level, summary, style = checked_level(geometry, n, warn)
    if jitter is not None:
        level = jittered(level, jitter)
    target = write_level(lambda tmp: write_msh(level, tmp, style), geometry, n, directory)
    return replace(summary, path=target)


def checked_level(geometry: Geometry | Box | GmshGeometry, n: int,
                  warn: bool) -> tuple[SimplexMesh, MeshSummary, MshStyle]:
    """Level n from its scene's generator, checked in memory before it is written (re-reading
    the file took 41 % of the finest rectangle's time at n = 64), its summary (path left
    empty) and the style its file has always had (harness/mesh/msh.py)."""
    if isinstance(geometry, Box):
        check_on_grid(on_grid_blocks(geometry), n)
        level = with_regions(box_mesh.generate(geometry, n), geometry)
        areas = check_role_areas(level, geometry, n)
        return level, MeshSummary(Path(), n, len(level.points), len(level.cells), areas), AS_MESHIO
    if isinstance(geometry, GmshGeometry):
        level = gmsh_mesh.generate(geometry, n)
        measured = quality(level.points, level.cells)
        worse = quality_warning(measured) if warn else None
        if worse:
            print(f"warning: mesh n={n} of {geometry.file.name}: {worse}: expect larger errors and slower convergence "
                  "at every level split from it; mesh the coarsest level finer or better (gmsh's Mesh.Optimize, "
                  "Mesh.OptimizeNetgen)", file=sys.stderr, flush=True)
        summary = MeshSummary(Path(), n, len(level.points), len(level.cells), role_measures(level), measured)
        return level, summary, AS_MESHIO
    check_on_grid(on_grid_blocks(geometry), n)
    level = with_regions(rectangle_mesh.generate(geometry, n), geometry)
    return level, check_arrays(level.points, level.cells, level.facets, level.labels, geometry, n), AS_GMSH


def on_grid_blocks(geometry: Geometry | Box | GmshGeometry) -> tuple[Block, ...]:
    """The blocks whose sides every level's grid must hold: a structured rectangle's or box's
    (their cells take the block of their centroid); none of the box's unstructured tetrahedra,
    which gmsh cuts along the blocks' faces (Box.cuts), nor of a gmsh scene."""
    if isinstance(geometry, GmshGeometry) or getattr(geometry, "diagonals", "") == "unstructured":
        return ()
    return tuple(geometry.blocks)


def with_regions(level: SimplexMesh, geometry: Geometry | Box) -> SimplexMesh:
    """`level` with each cell's region label when the scene maps its blocks to materials
    (harness/scene/blocks.py); as generated otherwise, so its file keeps its bytes."""
    if not geometry.regions:
        return level
    centroids = level.points[level.cells].mean(axis=1)
    return replace(level, regions=block_labels(geometry.blocks, geometry.regions, centroids))


def check_role_areas(level: SimplexMesh, box: Box, n: int) -> dict[str, float]:
    """Each role's area, which must be its patches' area (role_lengths holds areas in 3D)."""
    areas = role_measures(level)
    expected = box.role_areas()
    for role in set(areas) | set(expected):
        if not np.isclose(areas.get(role, 0.0), expected.get(role, 0.0), rtol=1e-9, atol=1e-12):
            raise MeshError(f"mesh n={n}: role {role} covers {areas.get(role, 0.0):.6g}, its patches {expected.get(role, 0.0):.6g}")
    return areas


def remove_partial_meshes(directory: Path, pids: list[int]) -> None:
    """Remove the temp files of mesh writers that were killed (sibling_temp names carry the pid)."""
    for pid in pids:
        for partial in directory.glob(f".mesh_n*.{pid}-*"):
            partial.unlink(missing_ok=True)


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


def graded_level(level: SimplexMesh, width: float, focus_x: Sequence[float], power: float) -> SimplexMesh:
    """`level` with its nodes moved by graded_coordinate in x (towards focus_x) and in y
    (towards y = 0). The topology, labels and orientation (both maps are increasing) are
    unchanged; the family is no longer nested."""
    x, y = level.points[:, 0], level.points[:, 1]
    moved = np.column_stack([graded_coordinate(np.clip(x, 0, width), focus_x, power),
                             graded_coordinate(y, [0.0], power)])
    return replace(level, points=moved)


def contact_ends(geometry: Geometry) -> list[float]:
    """The x of the ends of the contact segments on the bottom (the ends of Gamma_3)."""
    return sorted({x for seg in geometry.bottom if seg.role == "contact" for x in (seg.x0, seg.x1)})


def build_graded_mesh(geometry: Geometry, n: int, directory: Path, power: float) -> Path:
    """The level-n mesh graded towards the ends of Gamma_3 (x) and the bottom (y) with
    `power` (graded_level), as graded_n<n>.msh; the uniform mesh when power is 1."""
    if power == 1.0:
        return build_mesh(geometry, n, directory).path
    level, _, _ = checked_level(geometry, n, warn=False)
    graded = graded_level(level, geometry.width, contact_ends(geometry), power)
    target = directory / f"graded_n{n}.msh"
    target.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(target, msh_text(graded, AS_GRADED))
    return target
