"""`python -m harness solve CASE --n N`: one level (after the case's coarser levels when it
is warm-started from them), its run.json summarised and its physical checks printed."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from harness.arguments import add_case, add_scene_options, layout_of, positive_int, prepared_scene
from harness.engine import InlineMeshes, quiet, run_chain, runs_of
from harness.errors import VerdictError
from harness.layout import Layout
from harness.record import RunRecord
from harness.run import check_solver_files
from harness.run_checks import failed_checks, print_checks
from harness.scene import Scene


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_case(parser)
    parser.add_argument("--n", type=positive_int, required=True, help="level n = 1/h")
    add_scene_options(parser)


def run(args: argparse.Namespace) -> int:
    scene, (n,) = prepared_scene(args, (args.n,))
    return solve(scene, n, layout_of(args), args.force)


def solve(scene: Scene, n: int, layout: Layout, force: bool) -> int:
    check_solver_files(scene, layout)
    # Warm-started: the case's levels below n first, each from the one before (cached when
    # unchanged), pipelined as in a convergence study.
    below = sorted(level for level in scene.levels if level < n) if scene.initial_guess == "coarser" else []
    meshes = InlineMeshes(scene, [*below, n], layout)
    result = runs_of(run_chain(scene, meshes, layout, force, quiet))[n]
    print(describe_run(scene.name, result.record, result.directory, result.reused))
    failed = failed_checks(print_checks(scene, [result]))
    if failed:
        raise VerdictError(f"{scene.name} n={n}: {failed}")
    return 0


def describe_run(case: str, record: RunRecord, directory: Path, reused: bool) -> str:
    r = record
    state = "converged" if r.converged else f"NOT converged ({r.reason})"
    return "\n".join([
        f"{case} n={r.n}: {state} in {r.newton_iterations} Newton iterations"
        f" (initial guess {r.initial_guess}){' [reused]' if reused else ''}",
        f"  dofs {r.dofs}, wall {fmt(r.wall_s)} s (assembly {fmt(r.assembly_s)} s, solves {fmt(r.solve_s)} s)",
        f"  max theta {fmt(r.max_theta)}, phi in [{fmt(r.min_phi)}, {fmt(r.max_phi)}], max |u| {fmt(r.max_abs_u)}",
        f"  contact force {fmt(r.contact_force)}, closed part of Gamma_3 {fmt(r.active_measure)}",
        f"  results in {directory}",
    ])


def fmt(value: Any) -> str:
    return f"{value:.4g}" if isinstance(value, (int, float)) and not isinstance(value, bool) else str(value)
