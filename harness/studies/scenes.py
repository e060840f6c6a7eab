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

from harness import executor
from harness.arguments import add_common, add_levels, layout_of
from harness.layout import REPO, Layout
from harness.report import write_report
from harness.scene import load_scene
from harness.study import NORMED_FIELDS, Study, run_study
from harness.writers import write_csv


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
    for field in NORMED_FIELDS:
        row[f"slope_{field}"] = study.slopes[field]["all"] if field in study.fields else float("nan")
    row["slope_total"] = study.slopes["total"]["all"]
    return row


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--cases", type=Path, default=REPO / "cases", help="folder of scene files")
    add_levels(parser, what="each scene's own")
    add_common(parser)
    executor.add_arguments(parser)


def scene_study(case: Path, levels: tuple[int, ...], layout: Layout, force: bool) -> Study:
    """One scene's study (a task of its own on a cluster)."""
    scene = load_scene(case)
    print(f"== {scene.name}: {', '.join(scene.effects)}", file=sys.stderr, flush=True)
    return run_study(scene, levels or scene.levels, layout, jobs=1, force=force)


def run(args: argparse.Namespace) -> int:
    layout = layout_of(args)
    rows = []
    with executor.from_args(args) as pool:  # the scenes side by side on a Dask cluster
        studies = executor.each(pool, lambda case: scene_study(case, args.levels, layout, args.force),
                                sorted(args.cases.glob("*.toml")))
    for study in studies:
        write_report(study, layout)
        rows.append(scene_row(study))
    table = pd.DataFrame(rows)
    out = write_csv(table, layout.results / "scenes" / "summary.csv")
    print(table.to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    print(f"wrote {out}")
    return 0
