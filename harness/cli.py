"""Command line: `python -m harness convergence CASE` and `python -m harness solve CASE --n N`."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Any, NoReturn, Sequence

from harness.contract import ExitCode
from harness.atomic import StudyTransaction
from harness.errors import VerdictError
from harness.faults import check_results_root, guarded
from harness.guards import OVERRIDE_FLAG, check_memory, check_nested
from harness.run_checks import failed_checks, print_checks
from harness.layout import Layout
from harness.mesh import build_mesh
from harness.report import format_table, write_report
from harness.run import WarmStart, check_solver_files, run_level
from harness.scene import Scene, load_scene
from harness.study import run_study

EXIT_ERROR = int(ExitCode.INPUT)  # a bad command line
EXIT_OUT_OF_BAND = int(ExitCode.VERDICT)  # the study ran, but its slope leaves the case's band


class Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        # One line, like every other expected failure, instead of argparse's usage dump.
        self.exit(EXIT_ERROR, f"error: {message} (see --help)\n")


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be positive")
    return value


def level_list(text: str) -> tuple[int, ...]:
    return tuple(positive_int(part) for part in text.split(","))


def parser() -> Parser:
    top = Parser(prog="python -m harness", description=__doc__)
    commands = top.add_subparsers(dest="command", required=True, parser_class=Parser)
    study = commands.add_parser("convergence", help="run every level and measure E^h and its slope")
    study.add_argument("--levels", type=level_list, help="comma-separated n = 1/h (default: the case's)")
    study.add_argument("--jobs", type=positive_int, default=os.cpu_count() or 1, help="parallel runs")
    solve = commands.add_parser("solve", help="solve one level and summarise run.json")
    solve.add_argument("--n", type=positive_int, required=True, help="level n = 1/h")
    for sub in (study, solve):
        sub.add_argument("case", type=Path, help="case file, e.g. cases/paper.toml")
        sub.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                         help="override a case-file value, e.g. contact.S=0 (repeatable)")
        sub.add_argument("--effects", help="comma-separated effects, replacing the case's "
                         "(e.g. piezoelectric,contact,friction,electric_contact)")
        sub.add_argument("--force", action="store_true", help="rerun even if inputs are unchanged")
        sub.add_argument("--results", type=Path, default=Layout().results, help="results root")
        sub.add_argument("--freefem", type=Path, default=Layout().freefem, help="solver scripts")
        sub.add_argument(OVERRIDE_FLAG, dest="ignore_memory", action="store_true",
                         help="run a level even when its estimated memory exceeds what is available")
    return top


def main(argv: Sequence[str] | None = None) -> int:
    args = parser().parse_args(argv)
    return guarded(lambda: dispatch(args))


def dispatch(args: argparse.Namespace) -> int:
    layout = Layout(results=args.results, freefem=args.freefem)
    overrides = list(args.overrides)
    if args.effects is not None:
        names = [e.strip() for e in args.effects.split(",") if e.strip()]
        overrides.append("scene.effects=" + repr(names).replace("'", '"'))
    scene = load_scene(args.case, overrides)
    for warning in scene.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    check_results_root(layout.results)
    levels = (args.n,) if args.command == "solve" else (args.levels or scene.levels)
    if args.command == "convergence":
        check_nested(levels)
    if not args.ignore_memory:
        check_memory(scene.geometry.width, scene.geometry.height, levels, scene.effects, scene.element)
    if args.command == "solve":
        return solve(scene, args.n, layout, args.force)
    return convergence(scene, levels, layout, args.jobs, args.force)


def solve(scene: Scene, n: int, layout: Layout, force: bool) -> int:
    check_solver_files(scene, layout)
    warm = None
    if scene.initial_guess == "coarser":
        # The case's levels below n, each started from the one before (cached when unchanged).
        for coarse in sorted(level for level in scene.levels if level < n):
            mesh = build_mesh(scene.geometry, coarse, layout.meshes_dir(scene.name))
            run = run_level(scene, mesh.path, coarse, layout, force, warm)
            warm = run.warm_start(mesh.path)
    mesh = build_mesh(scene.geometry, n, layout.meshes_dir(scene.name))
    result = run_level(scene, mesh.path, n, layout, force, warm)
    print(describe_run(scene.name, result.record, result.directory, result.reused))
    failed = failed_checks(print_checks(scene, [result]))
    if failed:
        raise VerdictError(f"{scene.name} n={n}: {failed}")
    return 0


def convergence(scene: Scene, levels: tuple[int, ...], layout: Layout, jobs: int, force: bool) -> int:
    with StudyTransaction(layout.case_dir(scene.name)):
        study = run_study(scene, levels, layout, jobs, force)
        paths = write_report(study, layout)
    print(format_table(study))
    failed = failed_checks(print_checks(scene, [study.runs[n] for n in sorted(study.runs)]))
    for name, fits in study.slopes.items():
        print(f"slope {name:>5}: {fits['all']:.3f} (all levels), {fits['window']:.3f} (window)")
    print(f"sweep wall time {study.wall_s:.1f} s; wrote {', '.join(str(p) for p in paths.values())}")
    low, high = scene.slope_band
    if not study.passed:
        print(f"error: total slope {study.total_slope:.3f} is outside the band [{low}, {high}] "
              f"of {scene.source}", file=sys.stderr)
        return EXIT_OUT_OF_BAND
    print(f"total slope {study.total_slope:.3f} is inside the band [{low}, {high}]: pass")
    if failed:
        raise VerdictError(f"{scene.name}: {failed}")
    return 0


def describe_run(case: str, record: dict[str, Any], directory: Path, reused: bool) -> str:
    get = record.get
    state = "converged" if get("converged") else f"NOT converged ({get('reason')})"
    return "\n".join([
        f"{case} n={get('n')}: {state} in {get('newton_iterations')} Newton iterations"
        f" (initial guess {get('initial_guess')}){' [reused]' if reused else ''}",
        f"  dofs {get('dofs')}, wall {fmt(get('wall_s'))} s"
        f" (assembly {fmt(get('assembly_s'))} s, solves {fmt(get('solve_s'))} s)",
        f"  max theta {fmt(get('max_theta'))}, phi in [{fmt(get('min_phi'))}, {fmt(get('max_phi'))}],"
        f" max |u| {fmt(get('max_abs_u'))}",
        f"  contact force {fmt(get('contact_force'))}, active length {fmt(get('active_length'))}",
        f"  results in {directory}",
    ])


def fmt(value: Any) -> str:
    return f"{value:.4g}" if isinstance(value, (int, float)) and not isinstance(value, bool) else str(value)
