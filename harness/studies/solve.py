"""`python -m harness solve CASE --n N`: one level (after the case's coarser levels when it
is warm-started from them), its run.json summarised and its physical checks printed."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from harness.arguments import add_case, add_common, add_effects, add_goals, goal_overrides, layout_of, positive_int
from harness.scene.cell_size import thin_warnings
from harness.study.engine import InlineMeshes, quiet, run_levels, runs_of
from harness.measure.fields import Fields, read_fields
from harness.core.layout import Layout
from harness.study.pipeline import Guarded, Plan, run_pipeline, scene_of
from harness.run.record import RunRecord
from harness.run.run import RunResult, check_solver_files
from harness.measure.run_checks import failed_checks, print_checks
from harness.scene.scene import Scene


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_case(parser)
    parser.add_argument("--n", type=positive_int, required=True,
                        help="the level to solve: cells of about 1/n in the model's units (the coarser levels of the "
                        "case run first when it starts from them)")
    add_effects(parser)
    add_goals(parser)
    add_common(parser)


def run(args: argparse.Namespace) -> int:
    scene = scene_of(args.case, args.overrides + goal_overrides(args), args.effects)
    solve(scene, args.n, layout_of(args), args.force, args.ignore_memory)
    return 0


def solve(scene: Scene, n: int, layout: Layout, force: bool, ignore_memory: bool = False) -> RunResult:
    """One level; it writes its level dir alone (swapped in whole, harness/run/run.py), so the
    pipeline's transaction owns nothing; it locks the scene's directory, which a study of
    the same scene would otherwise change under it."""
    plan = Plan(layout.results, (Guarded(scene, (n,)),), locked=(layout.case_dir(scene.name),),
                ignore_memory=ignore_memory)

    def runs() -> RunResult:
        check_solver_files(scene, layout)
        # Warm-started: the case's levels below n first, each from the one before (cached when
        # unchanged), pipelined as in a convergence study.
        below = sorted(level for level in scene.levels if level < n) if scene.initial_guess == "coarser" else []
        meshes = InlineMeshes(scene, [*below, n], layout)
        return runs_of(run_levels(scene, meshes, layout, force=force, progress=quiet))[n]

    parsed: dict[int, Fields] = {}

    def report(result: RunResult) -> None:
        print(describe_run(scene.name, result.record, result.directory, result.reused, scene))
        parsed[n] = fields = read_fields(result.solution)
        for line in thin_warnings(scene.geometry.body_parts(), n, fields.points, fields.cells):
            print(f"warning: {line}", file=sys.stderr)

    def verdict(result: RunResult) -> str | None:
        failed = failed_checks(print_checks(scene, [result], parsed))
        return f"{scene.name} n={n}: {failed}" if failed else None

    return run_pipeline(plan, runs, report, verdict)


def describe_run(case: str, record: RunRecord, directory: Path, reused: bool, scene: Scene | None = None) -> str:
    r = record
    # The quantities the lines above do not show (run.json's quantities, docs/quantities.md).
    shown = {"contact_force_normal", "contact_extent", "max_theta", "max_abs_u"}
    units = {q.name: q.unit(scene.dimension) for q in scene.quantities} if scene else {}
    rest = [f"{name} {fmt(value)} {units.get(name, '')}".rstrip()
            for name, value in (r.quantities or {}).items() if name not in shown]
    state = "converged" if r.converged else f"NOT converged ({r.reason})"
    c = r.checks or {}
    floating = [f"  floating electrode {k + 1} at {fmt(volts)} V, charge {fmt(charge)} (given {fmt(given)})"
                for k, (volts, charge, given) in enumerate(zip(c.get("floating_potential", []), c.get("floating_charge", []),
                                                               c.get("floating_charge_given", [])))]
    return "\n".join([
        f"{case} n={r.n}: {state} in {r.newton_iterations} Newton iterations"
        f" (initial guess {r.initial_guess}){' [reused]' if reused else ''}",
        f"  dofs {r.dofs}, wall {fmt(r.wall_s)} s (assembly {fmt(r.assembly_s)} s, solves {fmt(r.solve_s)} s)",
        f"  max theta {fmt(r.max_theta)}, phi in [{fmt(r.min_phi)}, {fmt(r.max_phi)}], max |u| {fmt(r.max_abs_u)}",
        f"  contact force {fmt(r.contact_force)}, closed part of Gamma_3 {fmt(r.active_measure)}",
        *floating,
        *([f"  {', '.join(rest)}"] if rest else []),
        # each goal's dual-weighted estimate of Q_exact - Q_h (freefem/goals.idp, docs/goals.md)
        *([f"  goal estimates (Q_exact - Q_h, {r.goal_dofs} P2 unknowns, {fmt(r.goal_s)} s): "
           + ", ".join(f"{name} {fmt(value)} {units.get(name, '')}".rstrip() for name, value in r.goal_estimates.items())]
          if r.goal_estimates else []),
        f"  results in {directory}",
    ])


def fmt(value: Any) -> str:
    return f"{value:.4g}" if isinstance(value, (int, float)) and not isinstance(value, bool) else str(value)
