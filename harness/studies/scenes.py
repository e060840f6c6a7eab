"""Every scene in cases/: a convergence study each, and one table of what each costs.

`python -m harness scenes [--cases DIR]` (the `make scenes` target) writes each scene's
own report (results/<scene>/) and results/scenes/summary.csv with the finest level's
unknowns, dofs, time and Newton iterations next to the slopes of the fields it has.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import pandas as pd

from harness.arguments import add_cluster, add_common, add_levels, layout_of
from harness.study.executor import cluster, each
from harness.core.guards import Slope
from harness.core.layout import REPO, Layout
from harness.study.pipeline import Guarded, Plan, run_pipeline
from harness.report.report import write_report
from harness.scene.scene import Scene, load_scene
from harness.measure.norm_table import FIELD_NAMES, TOTAL
from harness.study.study import Study, run_study
from harness.core.writers import write_csv


def scene_row(study: Study) -> dict[str, Any]:
    finest = study.runs[study.reference].record
    row: dict[str, Any] = {
        "scene": study.scene.name,
        "effects": " ".join(study.scene.effects),
        "strategy": finest.strategy,
        "unknowns_per_node": finest.unknowns_per_node,
        "n": study.reference,
        "dofs": finest.dofs,
        "wall_s": finest.wall_s,
        "newton_iterations": finest.newton_iterations,
        "sweep_wall_s": study.wall_s,
        "peak_rss_mb": finest.peak_rss_mb,
    }
    for field in FIELD_NAMES:
        row[f"slope_{field}"] = study.slopes[field]["all"] if field in study.fields else float("nan")
    row[f"slope_{TOTAL}"] = study.slopes[TOTAL]["all"]
    return row


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--cases", type=Path, default=REPO / "cases",
                        help="the folder whose case files (*.toml) are studied, one convergence study each (default: "
                        "cases/)")
    add_levels(parser, what="each scene's own")
    add_common(parser)
    add_cluster(parser)


def scene_study(scene: Scene, levels: tuple[int, ...], layout: Layout, force: bool) -> Study:
    """One scene's study (a task of its own on a cluster)."""
    print(f"== {scene.name}: {', '.join(scene.effects)}", file=sys.stderr, flush=True)
    return run_study(scene, levels or scene.levels, layout, jobs=1, force=force)


def run(args: argparse.Namespace) -> int:
    layout = layout_of(args)
    scenes = [load_scene(case) for case in sorted(args.cases.glob("*.toml"))]
    out = layout.results / "scenes"
    plan = Plan(layout.results, tuple(Guarded(scene, args.levels or (), Slope.AGAINST_FINEST) for scene in scenes),
                scene_dirs=tuple(layout.case_dir(scene.name) for scene in scenes), outputs=(out,), nested=True,
                ignore_memory=args.ignore_memory)

    def runs() -> list[Study]:
        with cluster(args.scheduler, args.cluster) as pool:  # the scenes side by side on a Dask cluster
            return each(pool, lambda scene: scene_study(scene, args.levels, layout, args.force), scenes)

    def report(studies: list[Study]) -> None:
        for study in studies:
            write_report(study, layout)
        table = pd.DataFrame([scene_row(study) for study in studies])
        written = write_csv(table, out / "summary.csv")
        print(table.to_string(index=False, float_format=lambda v: f"{v:.4g}"))
        print(f"wrote {written}")

    run_pipeline(plan, runs, report)
    return 0
