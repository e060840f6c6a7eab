"""`python -m harness convergence CASE`: every level of a case, E^h against the finest level
and its slope; exit 1 when the total slope leaves the case's band or a physical check fails."""

from __future__ import annotations

import argparse

from harness.arguments import add_case, add_common, add_effects, add_goals, add_jobs, add_levels, goal_overrides, layout_of
from harness.core.guards import Slope
from harness.core.layout import Layout
from harness.study.pipeline import Guarded, Plan, run_pipeline, scene_of
from harness.measure import tolerances
from harness.report.report import format_table, tolerance_verdicts, write_report
from harness.measure.run_checks import failed_checks, print_checks
from harness.scene.scene import Scene
from harness.study.study import Study, run_study


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_case(parser)
    add_levels(parser)
    add_jobs(parser)
    add_effects(parser)
    add_goals(parser)
    add_common(parser)


def run(args: argparse.Namespace) -> int:
    scene = scene_of(args.case, args.overrides + goal_overrides(args), args.effects)
    convergence(scene, args.levels or scene.levels, layout_of(args), args.jobs, args.force, args.ignore_memory)
    return 0


def convergence(scene: Scene, levels: tuple[int, ...], layout: Layout, jobs: int, force: bool,
                ignore_memory: bool = False) -> Study:
    plan = Plan(layout.results, (Guarded(scene, levels, Slope.AGAINST_FINEST),), scene_dirs=(layout.case_dir(scene.name),), nested=True,
                ignore_memory=ignore_memory)

    def report(study: Study) -> None:
        paths = write_report(study, layout)
        print(format_table(study))
        for name, fits in study.slopes.items():
            # "window": the fit without the level next to the reference, whose error the
            # reference's own error pollutes (summary.json's slopes.<field>.window).
            print(f"slope {name:>5}: {fits['all']:.3f} (all levels), "
                  f"{fits['window']:.3f} (without the level next to the reference)")
        print(f"sweep wall time {study.wall_s:.1f} s; wrote {', '.join(str(p) for p in paths.values())}")

    return run_pipeline(plan, lambda: run_study(scene, levels, layout, jobs, force), report,
                        lambda study: verdict(study))


def verdict(study: Study) -> str | None:
    """The slope's band first, then the case's tolerances on the finest level
    (harness/measure/tolerances.py, a line each), then every level's physical checks
    (harness/measure/run_checks.py)."""
    scene = study.scene
    failed = failed_checks(print_checks(scene, [study.runs[n] for n in sorted(study.runs)], study.solutions))
    judged = tolerance_verdicts(study)
    for tolerance in judged.values():
        print(tolerance.line())
    low, high = scene.slope_band
    if not study.passed:
        return f"total slope {study.total_slope:.3f} is outside the band [{low}, {high}] of {scene.source}"
    print(f"total slope {study.total_slope:.3f} is inside the band [{low}, {high}]: pass")
    missed = tolerances.failure(judged, f"{scene.name} ({scene.source})")
    if missed:
        return missed
    return f"{scene.name}: {failed}" if failed else None
