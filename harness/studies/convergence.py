"""`python -m harness convergence CASE`: every level of a case, E^h against the finest level
and its slope; exit 1 when the total slope leaves the case's band or a physical check fails."""

from __future__ import annotations

import argparse
import sys

from harness.arguments import add_case, add_jobs, add_levels, add_scene_options, layout_of, prepared_scene
from harness.atomic import StudyTransaction
from harness.contract import ExitCode
from harness.errors import VerdictError
from harness.layout import Layout
from harness.report import format_table, write_report
from harness.run_checks import failed_checks, print_checks
from harness.scene import Scene
from harness.study import run_study


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_case(parser)
    add_levels(parser)
    add_jobs(parser)
    add_scene_options(parser)


def run(args: argparse.Namespace) -> int:
    scene, levels = prepared_scene(args, args.levels, nested=True)
    return convergence(scene, levels, layout_of(args), args.jobs, args.force)


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
        return int(ExitCode.VERDICT)
    print(f"total slope {study.total_slope:.3f} is inside the band [{low}, {high}]: pass")
    if failed:
        raise VerdictError(f"{scene.name}: {failed}")
    return 0
