"""The goals' effectivity (the library of `python -m harness goals`, `make goals`): each case of
`CASES` solved on its levels with its goals (freefem/goals.idp), and each level's goal estimate
divided by the true error Q_ref - Q_h, Q_ref the exact value of a manufactured solution
(harness/measure/goal_exact.py) or Richardson's value from the three finest levels
(harness/measure/gci.py; none when they are not monotone). docs/goals.md reads the table."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from harness.core.layout import REPO, Layout
from harness.core.writers import write_csv, write_text
from harness.measure.gci import three_grid
from harness.measure.goal_exact import exact_goal
from harness.run.record import RunRecord
from harness.scene.scene import Scene, load_scene
from harness.study.engine import InlineMeshes, quiet, run_levels, runs_of


@dataclass(frozen=True)
class GoalCase:
    label: str
    case: str                   # relative to the repository
    overrides: tuple[str, ...]
    goals: tuple[str, ...]
    levels: tuple[int, ...]
    reference: str              # "exact" (a manufactured solution) or "richardson"


GOALS_2D = ("heat_through_contact", "charge_through_contact")
CASES: tuple[GoalCase, ...] = (
    GoalCase("mms_contact (2D)", "cases/mms/contact.toml", (), GOALS_2D, (4, 8, 16, 32), "exact"),
    GoalCase("mms_contact3d (3D)", "cases/mms/contact3d.toml", (), GOALS_2D, (2, 4, 8), "exact"),
    GoalCase("paper, zero branch", "cases/paper.toml", ("scene.name=paper_zero",), GOALS_2D, (4, 8, 16, 32),
             "richardson"),
    GoalCase("paper, pressed branch", "cases/paper.toml",
             ("scene.name=paper_pressed", "scene.coarsest_guess=pressed"), GOALS_2D, (4, 8, 16, 32), "richardson"),
    GoalCase("strip actuator", "cases/strip_actuator.toml", (), ("electrode_charge.electrode",), (2, 4, 8, 16),
             "richardson"),
)
COLUMNS = ["case", "goal", "n", "dofs", "goal_dofs", "wall_s", "goal_s", "value", "reference", "reference_value",
           "error", "estimate", "effectivity"]


def goal_scene(case: GoalCase) -> Scene:
    goals = "[" + ", ".join(f'"{g}"' for g in case.goals) + "]"
    return load_scene(REPO / case.case, [*case.overrides, f"quantities.goals={goals}"])


def solve_levels(scene: Scene, levels: tuple[int, ...], layout: Layout) -> dict[int, RunRecord]:
    """Every level of the case (a chain, as a convergence study runs them; cached when unchanged)."""
    results = runs_of(run_levels(scene, InlineMeshes(scene, list(levels), layout), layout, progress=quiet))
    return {n: results[n].record for n in levels}


def references(case: GoalCase, scene: Scene, records: dict[int, RunRecord]) -> dict[str, tuple[str, float]]:
    """Each goal's reference value and what it is."""
    out = {}
    for goal in case.goals:
        if case.reference == "exact":
            out[goal] = ("exact", exact_goal(scene, goal))
            continue
        finest = sorted(records, reverse=True)[:3]
        grid = three_grid(tuple(1 / n for n in finest), tuple(records[n].quantities[goal] for n in finest))
        usable = grid.behaviour == "monotone" and math.isfinite(grid.f_ext)
        out[goal] = (f"richardson n={','.join(map(str, sorted(finest)))} (p = {grid.p:.2f})" if usable
                     else f"not extrapolable ({grid.behaviour})", grid.f_ext if usable else math.nan)
    return out


def effectivity_rows(case: GoalCase, layout: Layout) -> list[dict[str, object]]:
    scene = goal_scene(case)
    records = solve_levels(scene, case.levels, layout)
    rows = []
    for goal, (what, ref) in references(case, scene, records).items():
        for n, r in records.items():
            value = r.quantities[goal]
            estimate = (r.goal_estimates or {}).get(goal, math.nan)
            error = ref - value
            rows.append({"case": case.label, "goal": goal, "n": n, "dofs": r.dofs, "goal_dofs": r.goal_dofs,
                         "wall_s": r.wall_s, "goal_s": r.goal_s, "value": value, "reference": what,
                         "reference_value": ref, "error": error, "estimate": estimate,
                         "effectivity": estimate / error if error else math.nan})
    return rows


def effectivity_table(cases: tuple[GoalCase, ...], layout: Layout) -> pd.DataFrame:
    rows = [row for case in cases for row in effectivity_rows(case, layout)]
    return pd.DataFrame(rows, columns=COLUMNS)


def markdown(table: pd.DataFrame) -> str:
    """The table as docs/goals.md shows it."""
    lines = ["| case | goal | n | dofs | P2 dual unknowns | wall [s] | goal [s] | Q_h | Q_ref - Q_h | estimate | effectivity |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for _, r in table.iterrows():
        lines.append(f"| {r.case} | {r.goal} | {r.n} | {r.dofs:,} | {r.goal_dofs:,} | {r.wall_s:.2f} | {r.goal_s:.2f} | "
                     f"{r.value:.6g} | {r.error:.3g} | {r.estimate:.3g} | {r.effectivity:.2f} |")
    references = table.drop_duplicates(["case", "goal"])
    lines += ["", "References: " + "; ".join(f"{r.case} {r.goal}: {r.reference} = {r.reference_value:.10g}"
                                             for _, r in references.iterrows())]
    return "\n".join(lines) + "\n"


def write_tables(table: pd.DataFrame, out: Path) -> None:
    write_csv(table, out / "effectivity.csv")
    write_text(markdown(table), out / "effectivity.md")
