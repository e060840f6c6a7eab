"""The one study pipeline: guards -> transaction -> runs -> report -> verdict.

Every study (harness/studies/) is this call with its own three functions:

    run_pipeline(plan, runs=..., report=..., verdict=...)

- its first line names the harness that runs and the results folder it writes into;
- guards, before anything is meshed or run: the results folder can hold results, every
  scene's warnings are printed, its levels are nested (when the study compares levels) and
  enough for its slopes (guards.Slope),
  its finest levels fit in memory (unless overridden), and its meshes fit on the disk;
- the transaction (harness/core/atomic.py): the directories the study writes hold its earlier
  complete output or its new one, never a mix, whatever fails or interrupts it, and one
  study at a time (a second is refused, exit 7 BUSY);
- runs and report inside the transaction, the report written only when the runs finished;
- the verdict after it: a failure message makes the command exit 1 (VERDICT) with that
  one `error:` line, after the report is safely written.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence, TypeVar

from harness.core.atomic import StudyTransaction
from harness.run.quantities import check_probes_on_level
from harness.core.errors import MeshError, SceneError, VerdictError
from harness.core.faults import check_results_root, naming
from harness.core.guards import (Slope, check_memory, check_nested, check_not_shallower, check_slope_levels,
                                 geometry_depth, memory_estimate, mesh_file_bytes, need_disk)
from harness.run.launcher import check_level_ranks
from harness.mesh.mesh import on_grid_blocks
from harness.scene.blocks import check_on_grid
from harness.scene.scene import Scene, load_scene

R = TypeVar("R")


@dataclass(frozen=True)
class Guarded:
    """A scene a study will run, its levels (the scene's own when empty) and how many of them
    its slopes need."""

    scene: Scene
    levels: tuple[int, ...] = ()
    slope: Slope = Slope.NONE

    @property
    def chosen(self) -> tuple[int, ...]:
        return tuple(self.levels or self.scene.levels)


@dataclass(frozen=True)
class Plan:
    """What a study guards and owns. `results`: the root it writes under; `scene_dirs`: the
    scene directories it writes a convergence report into; `outputs`: the directories whose
    every file is its (tables, Markdown, plots); `locked`: directories its runs write into
    that it does not own (`solve`'s scene: locked, not restored); `whole`: directories it
    owns with everything in them (adapt's case folder: its steps, meshes, reference and
    uniform levels); `nested`: whether it compares levels (a convergence study), so they must
    be nested; `ignore_memory`: the memory guard's override."""

    results: Path
    guarded: tuple[Guarded, ...] = ()
    scene_dirs: tuple[Path, ...] = ()
    outputs: tuple[Path, ...] = ()
    locked: tuple[Path, ...] = ()
    whole: tuple[Path, ...] = ()
    nested: bool = False
    ignore_memory: bool = False


def scene_of(case: Path, overrides: Sequence[str] = (), effects: Sequence[str] | None = None) -> Scene:
    """The case with its overrides and, when given, its effects replaced by `effects`."""
    overrides = list(overrides)
    if effects is not None:
        overrides.append("scene.effects=" + repr(list(effects)).replace("'", '"'))
    return load_scene(case, overrides)


def announce(results: Path) -> None:
    """The study's first line: which harness runs (a venv may hold another checkout's) and
    where its results go."""
    code = Path(__file__).resolve().parents[1]
    print(f"harness {code}; results in {Path(results).resolve()}", flush=True)


def check_guards(plan: Plan) -> None:
    """Every guard of the plan, before anything is meshed or run (harness/core/guards.py)."""
    check_results_root(plan.results)
    mesh_bytes = 0
    for item in plan.guarded:
        scene, levels = item.scene, item.chosen
        for warning in scene.warnings:
            print(f"warning: {warning}", file=sys.stderr)
        if plan.nested:
            check_nested(levels)
        given = item.levels and tuple(item.levels) != tuple(scene.levels)
        check_slope_levels(levels, item.slope, "--levels" if given else f"{scene.source} [study] levels")
        if plan.nested:
            for case_dir in plan.scene_dirs:
                if case_dir.name == scene.name:
                    check_not_shallower(case_dir, levels)
        if levels:
            check_probes_on_level(scene, min(levels))  # a gmsh body's probes, in its coarsest mesh
        for n in levels:
            check_blocks_on_grid(scene, n)
            fewer = check_level_ranks(scene, n)
            if fewer:
                print(f"warning: {fewer}", file=sys.stderr)
        if not plan.ignore_memory:
            check_level_memory(scene, levels)
        mesh_bytes += sum(mesh_file_bytes(scene.geometry, n) for n in levels)
    # The meshes are the one part of a study's output whose size is known before it runs: a
    # disk that cannot hold them cannot hold the study (each mesh is checked again when made).
    nearest = next((p for p in [plan.results, *plan.results.parents] if p.is_dir()), None)
    if nearest is not None and mesh_bytes:
        need_disk(nearest, mesh_bytes, "the study's meshes")


def check_blocks_on_grid(scene: Scene, n: int) -> None:
    """The rectangle's or box's blocks on level n's grid, checked before anything is meshed, so
    that the one line names the case file (the mesh generator, which checks it again, knows only
    the geometry)."""
    try:
        check_on_grid(on_grid_blocks(scene.geometry), n)
    except MeshError as exc:
        raise SceneError(f"{scene.source}: {exc}") from None


def check_level_memory(scene: Scene, levels: tuple[int, ...]) -> None:
    """The memory guard of a scene's levels (guards.check_memory), an EnvironmentFault (exit 4)
    when the finest would not fit; also for levels a study chooses once it has run (adapt's
    uniform levels, known only when its reference is)."""
    check_memory(scene.geometry.width, scene.geometry.height, levels, scene.effects, scene.element,
                 depth=geometry_depth(scene.geometry), factorises=scene.factorises,
                 multigrid=scene.multigrid_levels > 0, nodes_at=getattr(scene.geometry, "nodes_at", None))


def level_dofs(scene: Scene, n: int) -> int:
    """The unknowns of the scene's uniform level n as the memory guard counts them, before it
    is meshed (guards.level_nodes): exact for a structured level and a gmsh scene's split one, an
    estimate for an unstructured or remeshed one."""
    return memory_estimate(scene.geometry.width, scene.geometry.height, n, scene.effects, scene.element,
                           geometry_depth(scene.geometry), nodes_at=getattr(scene.geometry, "nodes_at", None))[0]


def run_pipeline(plan: Plan, runs: Callable[[], R], report: Callable[[R], object],
                 verdict: Callable[[R], str | None] = lambda _: None) -> R:
    """Guards, then the runs and the report inside one transaction, then the verdict: a
    message from `verdict` is raised as a VerdictError (exit 1), the report already written
    (a verdict with another exit code raises its own error: crosscheck's 6 and 3)."""
    announce(plan.results)
    check_guards(plan)
    transaction = StudyTransaction(*plan.scene_dirs, outputs=plan.outputs, locked=plan.locked, whole=plan.whole)
    with transaction:
        result = runs()
        # A write that names no file of its own is said to be in the study's first directory.
        with naming(next(iter((*plan.whole, *plan.outputs, *plan.scene_dirs)), plan.results)):
            report(result)
    for path in transaction.swept_after:
        print(f"warning: {path}: the temp dir of a run whose process died during the study (a killed Dask "
              f"worker?), removed; its level was run again and the study is complete", file=sys.stderr)
    failure = verdict(result)
    if failure:
        raise VerdictError(failure)
    return result
