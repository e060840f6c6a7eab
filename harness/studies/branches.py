"""`python -m harness branches` (`make branches`): the solution branches of the paper's scene
(issue 4), into results/branches/.

The benchmark's data break the paper's uniqueness condition, and Newton reaches different
solutions from different starts. Each start below is a convergence study of
cases/paper.toml (levels 2 ... 64):

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
physical checks (harness/checks.py) on every level. A start that fails on
some level is reported with the level and the reason, not left out.
Writes branches.csv, branches.md, and each study's convergence.csv / summary.json /
convergence.png under results/branches/<start>/.
"""

from __future__ import annotations

import argparse
import math
from typing import Any, Sequence

import pandas as pd

from harness import executor
from harness.arguments import add_common, add_jobs, add_levels, layout_of, name_list
from harness.checks import CHECK_FLAGS, physical_checks
from harness.errors import RunError, SceneError
from harness.layout import REPO, Layout
from harness.report import write_report
from harness.scene import load_scene
from harness.study import run_study
from harness.writers import cell, write_csv, write_text

PAPER = REPO / "cases" / "paper.toml"
RESULTS = REPO / "results" / "branches"
LEVELS = (2, 4, 8, 16, 32, 64)

STARTS: dict[str, list[str]] = {
    "zero": [],
    "pressed": ["scene.coarsest_guess=pressed"],
    "zero_each": ["scene.initial_guess=zero"],
    "pressed_each": ["scene.initial_guess=pressed"],
}

FACTS = ("max_theta", "min_phi", "max_phi", "max_abs_u", "contact_force", "heat_in_contact",
         "charge_in_contact", "active_measure")


def branch_row(start: str, levels: Sequence[int], layout: Layout, jobs: int, force: bool) -> dict[str, Any]:
    scene = load_scene(PAPER, [f"scene.name={start}", *STARTS[start]])
    row: dict[str, Any] = {"start": start, "initial_guess": scene.initial_guess,
                           "coarsest_guess": scene.sections.scene.coarsest_guess}
    try:
        study = run_study(scene, tuple(levels), layout, jobs, force)
    except RunError as exc:
        return {**row, "status": "failed", "note": str(exc)}
    write_report(study, layout)
    finest = study.runs[study.reference].record
    row.update({"status": "converged", "note": "", "n_finest": study.reference})
    row.update({key: finest.value(key) for key in FACTS})
    row["newton_iterations"] = " ".join(str(study.runs[n].record.newton_iterations) for n in sorted(study.runs))
    for name, fits in study.slopes.items():
        row[f"slope_{name}"] = fits["all"]
    # The stress suite's physical checks on every level of the branch.
    failed = set()
    for run in study.runs.values():
        checks = physical_checks(run.record, scene)
        failed |= {k.removesuffix("_ok") for k in CHECK_FLAGS if not checks[k]}
    row["checks"] = "pass" if not failed else "FAIL " + " ".join(sorted(failed))
    return row


def same_branch(rows: list[dict[str, Any]]) -> dict[str, str]:
    """Which starts reached the same solution: contact forces within 1 % (they differ by
    eight orders of magnitude between the branches found here)."""
    labels: dict[str, str] = {}
    found: list[tuple[str, float]] = []
    for row in rows:
        force = row.get("contact_force", math.nan)
        if row["status"] != "converged" or not math.isfinite(force):
            continue
        match = next((name for name, f in found if abs(force - f) <= 0.01 * max(abs(f), 1e-300)), None)
        if match is None:
            match = row["start"]
            found.append((match, force))
        labels[row["start"]] = match
    return labels


def markdown(table: pd.DataFrame) -> str:
    lines = ["| start | branch | Newton its per level | max θ [K] | φ range [V] | max \\|u\\| [m] | contact force [N/m] "
             "| heat in Γ3 [W/m] | charge in Γ3 [C/m] | active length [m] | slope u / φ / θ / total | checks |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in table.to_dict("records"):
        if row["status"] != "converged":
            lines.append(f"| {row['start']} | failed | {row['note']} |||||||||")
            continue
        slopes = " / ".join(cell(row.get(f"slope_{f}")) for f in ("u", "phi", "theta", "total"))
        lines.append(f"| {row['start']} | {row['branch']} | {row['newton_iterations']} | {cell(row['max_theta'])} | "
                     f"[{cell(row['min_phi'])}, {cell(row['max_phi'])}] | {cell(row['max_abs_u'])} | {cell(row['contact_force'])} | "
                     f"{cell(row['heat_in_contact'])} | {cell(row['charge_in_contact'])} | {cell(row['active_measure'])} | {slopes} | "
                     f"{row['checks']} |")
    return "\n".join(lines) + "\n"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_levels(parser, default=LEVELS, what="2,...,64; the finest the reference")
    parser.add_argument("--starts", type=name_list, default=list(STARTS), help=f"starts to run ({', '.join(STARTS)})")
    add_jobs(parser, default=2)
    add_common(parser, results=RESULTS)
    executor.add_arguments(parser)


def run(args: argparse.Namespace) -> int:
    layout = layout_of(args)
    unknown = [s for s in args.starts if s not in STARTS]
    if unknown:
        raise SceneError(f"unknown start {unknown[0]!r} (known: {', '.join(STARTS)})")
    with executor.from_args(args) as pool:  # each start's study a task on a Dask cluster
        rows = executor.each(pool, lambda start: branch_row(start, args.levels, layout, args.jobs, args.force),
                             args.starts)
    labels = same_branch(rows)
    for row in rows:
        row["branch"] = labels.get(row["start"], "")
    table = pd.DataFrame(rows)
    write_csv(table, args.results / "branches.csv")
    write_text(markdown(table), args.results / "branches.md")
    print(markdown(table))
    return 0
