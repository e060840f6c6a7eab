"""The solution branches of a scene, the paper's by default, the library of `make branches`
(harness/studies/branches.py): each start a convergence study, its finest level's
quantities, slopes and physical checks in one row, and which starts reached the same
solution."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Sequence

from harness.core.errors import RunError
from harness.core.layout import REPO, Layout
from harness.report.report import write_report
from harness.measure.run_checks import judge
from harness.scene.scene import Scene, load_scene
from harness.study.study import run_study

PAPER = REPO / "cases" / "paper.toml"
LEVELS = (2, 4, 8, 16, 32, 64)

STARTS: dict[str, list[str]] = {
    "zero": [],
    "pressed": ["scene.coarsest_guess=pressed"],
    "zero_each": ["scene.initial_guess=zero"],
    "pressed_each": ["scene.initial_guess=pressed"],
}

FACTS = ("max_theta", "min_phi", "max_phi", "max_abs_u", "contact_force", "heat_in_contact",
         "charge_in_contact", "active_measure")


def start_scene(start: str, case: Path = PAPER, overrides: Sequence[str] = ()) -> Scene:
    """The case (the paper's scene unless told) from `start`: the case's own overrides first,
    the start's last, and the start as the scene's name (its results folder)."""
    return load_scene(case, [*overrides, f"scene.name={start}", *STARTS[start]])


def branch_row(start: str, levels: Sequence[int], layout: Layout, jobs: int, force: bool,
               case: Path = PAPER, overrides: Sequence[str] = ()) -> dict[str, Any]:
    scene = start_scene(start, case, overrides)
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
        failed |= {k.removesuffix("_ok") for k in judge(run.record, scene).failed}
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
