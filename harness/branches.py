"""`python -m harness.branches` (`make branches`): the solution branches of the paper's scene
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
physical checks (harness/stress.py) on every level. A start that fails on
some level is reported with the level and the reason, not left out.
Writes branches.csv, branches.md, and each study's convergence.csv / summary.json /
convergence.png under results/branches/<start>/.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any, Sequence

import pandas as pd

from harness.atomic import write_atomic
from harness.errors import HarnessError, RunError
from harness.cli import level_list
from harness.layout import REPO, Layout
from harness.report import write_report
from harness.scene import load_scene
from harness.stress import CHECK_FLAGS, cell, physical_checks, write_table
from harness.study import run_study

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
         "charge_in_contact", "active_length")


def branch_row(start: str, levels: Sequence[int], layout: Layout, jobs: int, force: bool) -> dict[str, Any]:
    scene = load_scene(PAPER, [f"scene.name={start}", *STARTS[start]])
    row: dict[str, Any] = {"start": start, "initial_guess": scene.initial_guess,
                           "coarsest_guess": scene.table["scene"]["coarsest_guess"]}
    try:
        study = run_study(scene, tuple(levels), layout, jobs, force)
    except RunError as exc:
        return {**row, "status": "failed", "note": str(exc)}
    write_report(study, layout)
    finest = study.runs[study.reference].record
    row.update({"status": "converged", "note": "", "n_finest": study.reference})
    row.update({key: finest.get(key, math.nan) for key in FACTS})
    row["newton_iterations"] = " ".join(str(study.runs[n].record.get("newton_iterations")) for n in sorted(study.runs))
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
                     f"{cell(row['heat_in_contact'])} | {cell(row['charge_in_contact'])} | {cell(row['active_length'])} | {slopes} | "
                     f"{row['checks']} |")
    return "\n".join(lines) + "\n"


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m harness.branches", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--levels", default=",".join(map(str, LEVELS)), help="levels n = 1/h, the finest the reference")
    p.add_argument("--starts", default=",".join(STARTS), help=f"starts to run ({', '.join(STARTS)})")
    p.add_argument("--jobs", type=int, default=2, help="parallel runs (the chains run level by level)")
    p.add_argument("--force", action="store_true", help="rerun even if inputs are unchanged")
    p.add_argument("--results", type=Path, default=RESULTS, help="where the studies and the table go")
    p.add_argument("--freefem", type=Path, default=Layout().freefem, help="solver scripts")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = parser().parse_args(argv)
    layout = Layout(results=args.results, freefem=args.freefem)
    try:
        levels = list(level_list(args.levels))
        starts = [s.strip() for s in args.starts.split(",") if s.strip()]
        unknown = [s for s in starts if s not in STARTS]
        if unknown:
            raise HarnessError(f"unknown start {unknown[0]!r} (known: {', '.join(STARTS)})")
        rows = [branch_row(start, levels, layout, args.jobs, args.force) for start in starts]
    except HarnessError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    labels = same_branch(rows)
    for row in rows:
        row["branch"] = labels.get(row["start"], "")
    table = pd.DataFrame(rows)
    args.results.mkdir(parents=True, exist_ok=True)
    write_table(table, args.results / "branches.csv")
    write_atomic(args.results / "branches.md", markdown(table))
    print(markdown(table))
    return 0


if __name__ == "__main__":
    from harness.faults import guarded  # signals, exit codes, one error line

    sys.exit(guarded(main))
