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
mesh refined uniformly (2D: two rounds of bisection, each cell into four or more; 3D: one red
split along each octahedron's shortest diagonal, each tetrahedron into eight), solved warm from
the last step. A geometric multigrid solves each step and the reference over the earlier steps'
meshes, in which it is exactly nested. Before a step or the reference is meshed, its memory is
estimated from its node count (harness/core/guards.py): one that would not fit ends the loop
with the steps done, and the study with exit 4 once they are reported. All
adapted meshes are nested in it, so each step's error is computed exactly
(norms.error_norms). The case's uniform levels are measured against the same reference
(their meshes are not nested in it: there the transfer is the nodal interpolant).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np

from harness.core.guards import OVERRIDE_FLAG, available_memory, run_bytes, unknowns_per_node
from harness.mesh import bisection, tet_bisection, tet_split
from harness.study.engine import InlineMeshes, Progress, run_levels, runs_of
from harness.core.contract import BODY_LABEL
from harness.core.errors import EnvironmentFault, FieldsError, SceneError
from harness.measure.fields import Fields, read_fields
from harness.mesh.msh import mark_coarser, mark_small_cells, read_msh, write_msh
from harness.mesh.simplex import SimplexMesh, quality, signed_measures
from harness.scene.gmsh_geometry import SMALL_CELL
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
    mesh_s: float               # making the step's mesh: refining the one before and writing it


@dataclass(frozen=True)
class Adaptation:
    steps: list[Step]
    reference: RunResult | None     # None when none was asked for (errors measured otherwise) or it would not fit
    reference_mesh: Path | None
    refused: str | None = None      # why the loop stopped short: a step or the reference would not fit in memory


# The refinement of each dimension: start, refine, uniform, oriented.
REFINERS = {2: bisection, 3: tet_bisection}
# Dörfler's fraction unless a study says otherwise: half the squared estimate marked per step,
# the value of Dörfler's own experiments (SIAM J. Numer. Anal. 33 (1996) 1106).
DEFAULT_BULK = 0.5
# A multigrid level at most a quarter of the nodes of the one above: fewer levels would leave
# the coarsest LU large; more, each adding a few per cent of nodes, would cost set-ups for
# little coarsening (Dörfler's steps in 3D add 1.2-2 times the nodes).
LEVEL_RATIO = 4
# The smallest cell FreeFEM reads through its gmsh reader, per dimension. 2D: gmshload refuses
# a triangle below 1e-8 (plugin gmsh.cpp, "bug : mes < 1e-8 !"), SMALL_CELL keeps a margin; a
# step below it is read by the script's own reader (freefem/dimension.idp). 3D: gmshload3 has no
# such bound: it read, here, tetrahedra of 6e-25 m^3 (a 1 cm cube bisected 55 times toward a
# corner) and solved on edges of 3e-8 m (a 1 mm cube, 45 times); tests/test_adapt.py solves a
# step of this kind.
READER_FLOOR = {2: SMALL_CELL, 3: 0.0}
CELL_TYPES = {2: ("triangle", "line"), 3: ("tetra", "triangle")}


# MUMPS's null-pivot detection (ICNTL(24) = 1, in the MUMPS users' guide) for the LU of
# a multigrid's coarsest level. The tangent is not symmetric positive definite (elasticity
# coupled to electrostatics and heat, and contact), so a Galerkin product R A P of it can be
# singular where A is not: disc_pad's fifth step
# failed in PETSc's set-up (reason -11) with every coarser step and with the uniform n = 2 as
# its coarsest level, and solves in 3 Newton steps with it. The outer FGMRES still converges to
# the run's tolerance, so the answer does not depend on it.
NULL_PIVOTS = "-mg_coarse_mat_mumps_icntl_24 1"


def adaptive_overrides(scene: Scene) -> list[str]:
    """The `--set` overrides of the adaptive steps and their reference: MUMPS's null-pivot
    detection on a multigrid's coarsest level (NULL_PIVOTS), where the scene has one."""
    options = scene.petsc_options
    if not scene.multigrid_levels or "-mg_coarse_pc_factor_mat_solver_type mumps" not in options \
            or NULL_PIVOTS in options:
        return []
    return [f'run.petsc_options="{options} {NULL_PIVOTS}"']


def check_adaptable(scene: Scene) -> None:
    if scene.initial_guess != "coarser":
        raise SceneError(f"{scene.source}: an adaptive study warm-starts each step from the one before; "
                         f"set scene.initial_guess = \"coarser\" (it is {scene.initial_guess!r})")


def read_start(path: Path, dimension: int) -> SimplexMesh:
    """The first step's mesh: the case's coarsest level as the harness wrote it (MSH 2.2,
    role labels and the cells' region labels in gmsh:physical)."""
    level = read_msh(path)
    if level.dimension != dimension:
        raise SceneError(f"{path}: a {level.dimension}D mesh where the scene is {dimension}D")
    # The steps' cells keep their material (a multi-region scene's regions, harness/scene/regions.py).
    tags = level.cell_labels()
    return REFINERS[dimension].start(level.points, level.cells, level.facets, level.labels,
                                     None if (tags == BODY_LABEL).all() else tags)


def write_step(mesh: SimplexMesh, path: Path) -> dict[str, float]:
    """The step's mesh as MSH 2.2 (cells positive, as FreeFEM needs), and its quality."""
    dimension = mesh.cells.shape[1] - 1
    cells = REFINERS[dimension].oriented(mesh.points, mesh.cells)
    q = quality(mesh.points, cells)
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(f".{path.name}.partial")
    write_msh(replace(mesh, cells=cells), partial)
    # Bisection toward a singular point goes below the triangle area FreeFEM's gmshload
    # accepts (1e-8: cases/mms/lshape.toml's 24th step), whatever the scene's levels are.
    mark_small_cells(path, small_cells(mesh.points, cells))
    partial.replace(path)
    return q


def small_cells(points: np.ndarray, cells: np.ndarray) -> bool:
    """Whether a step's mesh has cells below what FreeFEM's gmsh reader takes (READER_FLOOR)."""
    return float(signed_measures(points, cells).min()) < READER_FLOOR[cells.shape[1] - 1]


def reference_of(mesh: SimplexMesh) -> SimplexMesh:
    """The overkill reference's mesh: `mesh` refined uniformly. 2D: two rounds of newest-vertex
    bisection (each triangle into four or more). 3D: one red split along each octahedron's
    shortest diagonal (tet_split, Ong 1994): eight children of every tetrahedron, of its
    quality, where three rounds of longest-edge bisection gave eight or more (10.7 times the
    unknowns on disc_pad) and the shapes of repeated bisection."""
    if mesh.cells.shape[1] == 4:
        return tet_split.split(mesh)
    return bisection.uniform(mesh, 2)


def multigrid_chain(mesh: SimplexMesh, done: list[Step], nodes: dict[Path, int], levels: int) -> list[Path]:
    """The earlier steps' meshes a geometric multigrid of `mesh` coarsens through, finest first:
    each at most 1/LEVEL_RATIO of the nodes of the level above, at most `levels` of them. The
    steps are nested (each refines the one before), so every transfer is exact."""
    chain: list[Path] = []
    above = len(mesh.points)
    for step in reversed(done):
        if len(chain) == levels:
            break
        if nodes[step.mesh] * LEVEL_RATIO <= above:
            chain.append(step.mesh)
            above = nodes[step.mesh]
    return chain


@dataclass(frozen=True)
class MemoryGuard:
    """The memory a run of a mesh not yet written would need (guards.run_bytes from its node
    count), against what is available; `coarse_nodes`: the nodes of the coarsest step, a
    multigrid's coarsest level."""
    scene: Scene
    coarse_nodes: int
    enabled: bool

    def refusal(self, mesh: SimplexMesh, what: str) -> str | None:
        if not self.enabled:
            return None
        scene = self.scene
        per_node = unknowns_per_node(scene.effects, scene.dimension)
        dofs = per_node * len(mesh.points)
        need = run_bytes(dofs, scene.dimension, scene.factorises, scene.multigrid_levels > 0,
                         per_node * self.coarse_nodes)
        have = available_memory()
        if need <= have:
            return None
        return (f"{what} would need about {need / 1e9:.3g} GB ({dofs:,} dofs, from the measured bytes per dof) "
                f"but {have / 1e9:.3g} GB is available; refused before meshing it, the steps done are reported "
                f"({OVERRIDE_FLAG} runs it anyway)")


def indicator_on(mesh: SimplexMesh, solution: Path, name: str = "error_indicator") -> np.ndarray:
    """The run's cell field `name` (the recovery estimate's `error_indicator`, or a goal's
    `goal_indicator_<goal>`, freefem/goals.idp), one value per cell of `mesh` in its order
    (matched by the cell's nodes: FreeFEM numbers the nodes as the file does)."""
    import meshio

    cell_type = CELL_TYPES[mesh.cells.shape[1] - 1][0]
    vtu = meshio.read(solution)
    blocks = [(b.data, d) for b, d in zip(vtu.cells, vtu.cell_data[name]) if b.type == cell_type]
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


def adapt(scene: Scene, reference_scene: Scene | None, layout: Layout, steps: int, bulk: float,
          max_dofs: int | None, force: bool, progress: Progress, announce: Callable[[str], None],
          memory_guard: bool = True) -> Adaptation:
    """Up to `steps` solves, each on the refinement of the one before, stopping early when a
    step reaches `max_dofs` or the next would not fit in memory (`memory_guard`); then the
    reference, unless `reference_scene` is None (a manufactured case's errors are measured
    against its exact fields, a cost study's against its own reference)."""
    check_adaptable(scene)
    clock = time.perf_counter()
    start = build_mesh(scene.geometry, scene.levels[0], layout.meshes_dir(scene.name)).path
    dimension = scene.dimension
    refiner = REFINERS[dimension]
    mesh = read_start(start, dimension)
    guard = MemoryGuard(scene, len(mesh.points), memory_guard)
    nodes: dict[Path, int] = {}
    warm: WarmStart | None = None
    done: list[Step] = []
    refused: str | None = None
    for index in range(1, steps + 1):
        path = layout.meshes_dir(scene.name) / f"adapt_{index}.msh"
        refused = guard.refusal(mesh, f"step {index}")
        if refused:
            announce(refused)
            break
        q = write_step(mesh, path)
        mark_coarser(path, multigrid_chain(mesh, done, nodes, scene.multigrid_levels))
        nodes[path] = len(mesh.points)
        mesh_s = time.perf_counter() - clock
        run = solve_on(scene, path, index, layout, warm, force, progress)
        last = index == steps or (max_dofs is not None and (run.record.dofs or 0) >= max_dofs)
        marked = np.zeros(len(mesh.cells), dtype=bool) if last else bisection.dorfler(indicator_on(mesh, run.solution), bulk)
        done.append(Step(index, path, run, len(mesh.cells), int(marked.sum()), q, mesh_s))
        announce(f"step {index}: {run.record.dofs} dofs, {len(mesh.cells)} cells, "
                 f"{run.record.newton_iterations} Newton its" + ("" if last else f", {int(marked.sum())} cells marked"))
        warm = run.warm_start(path)
        solved = mesh
        if last:
            break
        clock = time.perf_counter()
        mesh = refiner.refine(mesh, marked)
    if not done:
        raise EnvironmentFault(refused or "no step was run")
    if reference_scene is None:
        return Adaptation(done, None, None, refused)
    finest = reference_of(solved)
    reference_refused = guard.refusal(finest, "the reference")
    if reference_refused:
        announce(reference_refused)
        return Adaptation(done, None, None, refused or reference_refused)
    # Beside the steps' meshes: made from them, it is the study's as theirs are.
    reference_mesh = layout.meshes_dir(scene.name) / "reference.msh"
    write_step(finest, reference_mesh)
    mark_coarser(reference_mesh, multigrid_chain(finest, done, nodes, reference_scene.multigrid_levels))
    announce(f"reference: the last mesh refined uniformly ({len(finest.cells)} cells)")
    reference = solve_on(reference_scene, reference_mesh, done[-1].index + 1, layout, warm, force, progress)
    return Adaptation(done, reference, reference_mesh, refused)


def errors_against(reference: Fields, run: RunResult, fields: tuple[str, ...]) -> dict[str, float]:
    """The run's error per field in its norm of E^h, against the reference solution."""
    return error_norms(read_fields(run.solution), reference, list(fields))


def uniform_runs(scene: Scene, layout: Layout, levels: tuple[int, ...], force: bool,
                 progress: Progress) -> dict[int, RunResult]:
    """The case's uniform levels, a chain as in a convergence study."""
    meshes = InlineMeshes(scene, levels, layout)
    return runs_of(run_levels(scene, meshes, layout, force=force, progress=progress))
