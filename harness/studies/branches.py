"""`python -m harness branches [CASE]` (`make branches`): the solution branches of the paper's
scene, into results/branches/; of any other case (a gmsh scene, say) into
results/branches_<case>/.

The benchmark's data break the paper's uniqueness condition, and Newton reaches different
solutions from different starts. Each start below is a convergence study of the case
(cases/paper.toml unless told; levels 2 ... 64):

- zero:            the coarsest level from zero, each finer one from the coarser solution
                   (the case file as it is: what `make convergence` shows);
- pressed:         the same chain, the coarsest level from the pressed start
                   (`scene.coarsest_guess = pressed`: Gamma_3 pushed 2 eps into the
                   foundation, phi = phi_f and theta = 5 K there);
- zero_each:       every level from zero;
- pressed_each:    every level from the pressed start.

For each: the finest level's max theta, phi range, max |u|, contact force, heat and charge
entering through Gamma_3 and the active length, the Newton iterations per level, the
least-squares slope of each field's error against the finest level, and the stress suite's
physical checks (harness/measure/checks.py) on every level. A start that fails on
some level is reported with the level and the reason, not left out.
Writes branches.csv, branches.md, and each study's convergence.csv / summary.json /
convergence.png under results/branches/<start>/. Exit status 1 when a start converged but
failed a physical check.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import pandas as pd

from harness.arguments import add_case, add_cluster, add_common, add_jobs, add_levels, layout_of, name_list
from harness.report.branch_starts import LEVELS, PAPER, STARTS, branch_row, same_branch, start_scene
from harness.core.errors import SceneError
from harness.study.executor import cluster, each
from harness.core.layout import results_root
from harness.measure.norm_table import error_names
from harness.study.pipeline import Guarded, Plan, run_pipeline
from harness.core.writers import cell, markdown_table, write_csv, write_text



HEADER = ("start", "branch", "Newton its per level", "max θ [K]", "φ range [V]", "max \\|u\\| [m]",
          "contact force [N/m]", "heat in Γ3 [W/m]", "charge in Γ3 [C/m]", "active length [m]",
          "slope u / φ / θ / total", "checks")


def markdown(table: pd.DataFrame) -> str:
    rows = []
    for row in table.to_dict("records"):
        if row["status"] != "converged":
            rows.append([row["start"], "failed", row["note"]])
            continue
        slopes = " / ".join(cell(row.get(f"slope_{f}")) for f in error_names())
        rows.append([row["start"], row["branch"], row["newton_iterations"], cell(row["max_theta"]),
                     f"[{cell(row['min_phi'])}, {cell(row['max_phi'])}]", cell(row["max_abs_u"]),
                     cell(row["contact_force"]), cell(row["heat_in_contact"]), cell(row["charge_in_contact"]),
                     cell(row["active_measure"]), slopes, row["checks"]])
    return markdown_table(HEADER, rows)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_case(parser, optional=True)
    add_levels(parser, default=LEVELS, what="2,...,64; the finest the reference")
    parser.add_argument("--starts", type=name_list, default=list(STARTS), help=f"starts to run ({', '.join(STARTS)})")
    add_jobs(parser, default=2)
    add_common(parser)
    # Decided once the case is known (results_for): the paper's table is not another case's.
    parser.set_defaults(results=None)
    add_cluster(parser)


def results_for(case: Path) -> Path:
    """results/branches/ for the paper's scene, results/branches_<case>/ for any other."""
    return results_root() / ("branches" if case.resolve() == PAPER.resolve() else f"branches_{case.stem}")


def run(args: argparse.Namespace) -> int:
    args.results = args.results or results_for(args.case)
    layout = layout_of(args)
    unknown = [s for s in args.starts if s not in STARTS]
    if unknown:
        raise SceneError(f"unknown start {unknown[0]!r} (known: {', '.join(STARTS)})")
    scenes = tuple(Guarded(start_scene(start, args.case, args.overrides), tuple(args.levels)) for start in args.starts)
    plan = Plan(args.results, scenes,
                scene_dirs=tuple(layout.case_dir(start) for start in args.starts), outputs=(args.results,),
                nested=True, ignore_memory=args.ignore_memory)

    def runs() -> list[dict[str, Any]]:
        with cluster(args.scheduler, args.cluster) as pool:  # each start's study a task on a Dask cluster
            return each(pool, lambda start: branch_row(start, args.levels, layout, args.jobs, args.force,
                                                       args.case, args.overrides), args.starts)

    def report(rows: list[dict[str, Any]]) -> None:
        labels = same_branch(rows)
        for row in rows:
            row["branch"] = labels.get(row["start"], "")
        table = pd.DataFrame(rows)
        write_csv(table, args.results / "branches.csv")
        write_text(markdown(table), args.results / "branches.md")
        print(markdown(table))

    def verdict(rows: list[dict[str, Any]]) -> str | None:
        """A start that converged with a failed physical check fails the study (a start that
        did not converge is a finding of the table, reported with its reason)."""
        bad = [f"{row['start']} ({row['checks']})" for row in rows
               if row["status"] == "converged" and row["checks"] != "pass"]
        return f"physical checks failed on the branch from {', '.join(bad)}" if bad else None

    run_pipeline(plan, runs, report, verdict)
    return 0
