"""The adaptive loop, 2D and 3D: SOLVE -> ESTIMATE -> MARK -> REFINE (docs/adaptivity.md), the
library of `python -m harness adapt`.

- SOLVE: one run on the step's mesh, warm-started from the step before (the point-located
  state of freefem/initial_guess.idp: the meshes are nested, so the transfer is exact);
- ESTIMATE: the run's recovery estimate (freefem/estimator.idp), per cell its combined
  relative indicator `error_indicator` in solution.vtu;
- MARK: Dörfler's bulk criterion on it (bisection.dorfler);
- REFINE: newest-vertex bisection of triangles (harness/mesh/bisection.py) or longest-edge
  bisection of tetrahedra (harness/mesh/tet_bisection.py), each with its closure, the boundary
  roles carried to the halves of every cut boundary facet.

The true error of every step is measured against an overkill reference: the last step's
mesh bisected uniformly (2D: two rounds, each cell into four or more; 3D: three rounds, each tetrahedron
into eight or more), solved warm from the last step. All
adapted meshes are nested in it, so each step's error is computed exactly
(norms.error_norms). The case's uniform levels are measured against the same reference
(their meshes are not nested in it: there the transfer is the nodal interpolant).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np

from harness.mesh import bisection, tet_bisection
from harness.study.engine import InlineMeshes, Progress, run_levels, runs_of
from harness.core.contract import BODY_LABEL
from harness.core.errors import FieldsError, SceneError
from harness.measure.fields import Fields, read_fields
from harness.mesh.msh import write_msh
from harness.mesh.simplex import SimplexMesh, quality
from harness.core.layout import Layout
from harness.mesh.mesh import build_mesh
from harness.measure.norms import error_norms
from harness.run.run import RunResult, WarmStart
from harness.scene.scene import Scene


@dataclass(frozen=True)
class Step:
    index: int                  # 1, 2, ...
    mesh: Path
    run: RunResult
    cells: int
    marked: int                 # cells Dörfler marked on this step (0 on the last)
    quality: dict[str, float]   # min angle, max aspect (simplex.quality)


@dataclass(frozen=True)
class Adaptation:
    steps: list[Step]
    reference: RunResult
    reference_mesh: Path


# The refinement of each dimension: start, refine, uniform, oriented; and the uniform
# bisection rounds that make the reference four (2D) or eight or more (3D) times finer.
REFINERS = {2: bisection, 3: tet_bisection}
REFERENCE_ROUNDS = {2: 2, 3: 3}
CELL_TYPES = {2: ("triangle", "line"), 3: ("tetra", "triangle")}


def check_adaptable(scene: Scene) -> None:
    if scene.initial_guess != "coarser":
        raise SceneError(f"{scene.source}: an adaptive study warm-starts each step from the one before; "
                         f"set scene.initial_guess = \"coarser\" (it is {scene.initial_guess!r})")


def read_start(path: Path, dimension: int) -> SimplexMesh:
    """The first step's mesh: the case's coarsest level as the harness wrote it (MSH 2.2,
    role labels and the cells' region labels in gmsh:physical)."""
    import meshio  # here: its import is the slow part of start-up

    cell_type, facet_type = CELL_TYPES[dimension]
    mesh = meshio.read(path)
    cells = np.vstack([b.data for b in mesh.cells if b.type == cell_type])
    facets, labels, regions = [], [], []
    for block, physical in zip(mesh.cells, mesh.cell_data["gmsh:physical"]):
        if block.type == facet_type:
            facets.append(block.data)
            labels.append(physical)
        elif block.type == cell_type:
            regions.append(physical)
    # The steps' cells keep their material (a multi-region scene's regions, harness/scene/regions.py).
    tags = np.concatenate(regions).astype(np.int64)
    return REFINERS[dimension].start(mesh.points[:, :dimension], cells, np.vstack(facets), np.concatenate(labels),
                                     None if (tags == BODY_LABEL).all() else tags)


def write_step(mesh: SimplexMesh, path: Path) -> dict[str, float]:
    """The step's mesh as MSH 2.2 (cells positive, as FreeFEM needs), and its quality."""
    dimension = mesh.cells.shape[1] - 1
    cells = REFINERS[dimension].oriented(mesh.points, mesh.cells)
    q = quality(mesh.points, cells)
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(f".{path.name}.partial")
    write_msh(replace(mesh, cells=cells), partial)
    partial.replace(path)
    return q


def indicator_on(mesh: SimplexMesh, solution: Path) -> np.ndarray:
    """The run's `error_indicator`, one value per cell of `mesh` in its order (matched by
    the cell's nodes: FreeFEM numbers the nodes as the file does)."""
    import meshio

    cell_type = CELL_TYPES[mesh.cells.shape[1] - 1][0]
    vtu = meshio.read(solution)
    blocks = [(b.data, d) for b, d in zip(vtu.cells, vtu.cell_data["error_indicator"]) if b.type == cell_type]
    cells = np.vstack([c for c, _ in blocks])
    values = np.concatenate([np.ravel(d) for _, d in blocks])
    if len(vtu.points) != len(mesh.points) or len(cells) != len(mesh.cells):
        raise FieldsError(f"{solution}: {len(vtu.points)} nodes and {len(cells)} cells, the step's mesh has "
                          f"{len(mesh.points)} and {len(mesh.cells)}")
    theirs, ours = np.sort(cells.astype(np.int64), axis=1), np.sort(mesh.cells.astype(np.int64), axis=1)
    order_theirs = np.lexsort(theirs.T[::-1])
    order_ours = np.lexsort(ours.T[::-1])
    if not np.array_equal(theirs[order_theirs], ours[order_ours]):
        raise FieldsError(f"{solution}: its cells are not the step's mesh")
    on_ours = np.empty(len(values))
    on_ours[order_ours] = values[order_theirs]
    return on_ours


def solve_on(scene: Scene, mesh: Path, label: int, layout: Layout, warm: WarmStart | None, force: bool,
             progress: Progress) -> RunResult:
    return runs_of(run_levels(scene, {label: mesh}, layout, force=force, progress=progress, warm=warm))[label]


def adapt(scene: Scene, reference_scene: Scene, layout: Layout, steps: int, bulk: float, max_dofs: int | None,
          force: bool, progress: Progress, announce: Callable[[str], None]) -> Adaptation:
    """Up to `steps` solves, each on the refinement of the one before, stopping early when a
    step reaches `max_dofs`; then the reference."""
    check_adaptable(scene)
    start = build_mesh(scene.geometry, scene.levels[0], layout.meshes_dir(scene.name)).path
    dimension = scene.dimension
    refiner = REFINERS[dimension]
    mesh = read_start(start, dimension)
    warm: WarmStart | None = None
    done: list[Step] = []
    for index in range(1, steps + 1):
        path = layout.meshes_dir(scene.name) / f"adapt_{index}.msh"
        q = write_step(mesh, path)
        run = solve_on(scene, path, index, layout, warm, force, progress)
        last = index == steps or (max_dofs is not None and (run.record.dofs or 0) >= max_dofs)
        marked = np.zeros(len(mesh.cells), dtype=bool) if last else bisection.dorfler(indicator_on(mesh, run.solution), bulk)
        done.append(Step(index, path, run, len(mesh.cells), int(marked.sum()), q))
        announce(f"step {index}: {run.record.dofs} dofs, {len(mesh.cells)} cells, "
                 f"{run.record.newton_iterations} Newton its" + ("" if last else f", {int(marked.sum())} cells marked"))
        warm = run.warm_start(path)
        if last:
            break
        mesh = refiner.refine(mesh, marked)
    reference_mesh = layout.meshes_dir(reference_scene.name) / "reference.msh"
    finest = refiner.uniform(mesh, REFERENCE_ROUNDS[dimension])
    write_step(finest, reference_mesh)
    announce(f"reference: the last mesh bisected uniformly ({len(finest.cells)} cells)")
    reference = solve_on(reference_scene, reference_mesh, done[-1].index + 1, layout, warm, force, progress)
    return Adaptation(done, reference, reference_mesh)


def errors_against(reference: Fields, run: RunResult, fields: tuple[str, ...]) -> dict[str, float]:
    """The run's error per field in its norm of E^h, against the reference solution."""
    return error_norms(read_fields(run.solution), reference, list(fields))


def uniform_runs(scene: Scene, layout: Layout, levels: tuple[int, ...], force: bool,
                 progress: Progress) -> dict[int, RunResult]:
    """The case's uniform levels, a chain as in a convergence study."""
    meshes = InlineMeshes(scene, levels, layout)
    return runs_of(run_levels(scene, meshes, layout, force=force, progress=progress))
