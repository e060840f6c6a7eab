"""Every scene in cases/: a convergence study each, and one table of what each costs.

`python -m harness.scenes [--cases DIR]` (the `make scenes` target) writes each scene's
own report (results/<scene>/) and results/scenes/summary.csv with the finest level's
unknowns, dofs, time and Newton iterations next to the slopes of the fields it has.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any, Sequence

import pandas as pd

from harness.atomic import write_atomic
from harness.cli import level_list
from harness.errors import HarnessError
from harness.layout import REPO, Layout
from harness.report import write_report
from harness.scene import load_scene
from harness.study import NORMED_FIELDS, Study, run_study


def scene_row(study: Study) -> dict[str, Any]:
    finest = study.runs[study.reference].record
    row: dict[str, Any] = {
        "scene": study.scene.name,
        "effects": " ".join(study.scene.effects),
        "strategy": finest.get("strategy"),
        "unknowns_per_node": finest.get("unknowns_per_node"),
        "n": study.reference,
        "dofs": finest.get("dofs"),
        "wall_s": finest.get("wall_s"),
        "newton_iterations": finest.get("newton_iterations"),
        "sweep_wall_s": study.wall_s,
        "peak_rss_mb": finest.get("peak_rss_mb"),
    }
    for field in NORMED_FIELDS:
        row[f"slope_{field}"] = study.slopes[field]["all"] if field in study.fields else float("nan")
    row["slope_total"] = study.slopes["total"]["all"]
    return row


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m harness.scenes", description=__doc__)
    parser.add_argument("--cases", type=Path, default=REPO / "cases", help="folder of scene files")
    parser.add_argument("--results", type=Path, default=Layout().results)
    parser.add_argument("--levels", help="comma-separated levels instead of each scene's own")
    args = parser.parse_args(argv)
    layout = Layout(results=args.results)
    rows = []
    try:
        for case in sorted(args.cases.glob("*.toml")):
            scene = load_scene(case)
            levels = level_list(args.levels) if args.levels else scene.levels
            print(f"== {scene.name}: {', '.join(scene.effects)}", file=sys.stderr, flush=True)
            study = run_study(scene, levels, layout, jobs=1)
            write_report(study, layout)
            rows.append(scene_row(study))
    except HarnessError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    table = pd.DataFrame(rows)
    out = layout.results / "scenes" / "summary.csv"
    out.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(out, table.to_csv(index=False, float_format="%.6g"))
    print(table.to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    from harness.faults import guarded  # signals, exit codes, one error line

    sys.exit(guarded(main))
