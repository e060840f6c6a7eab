"""The goals' effectivity (the library of `python -m harness goals`, `make goals`): each case of
`CASES` solved on its levels with its goals (freefem/goals.idp), and each level's goal estimate
divided by the true error Q_ref - Q_h, Q_ref the exact value of a manufactured solution
(harness/measure/goal_exact.py) or Richardson's value from the three finest levels
(harness/measure/gci.py; none when they are not monotone); and the adaptive loop marked by a
goal's dual-weighted indicators (`adapt --goal`), beside uniform levels (`goals --adapt`).
docs/goals.md reads both tables."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
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


# ---- marking for a goal (`adapt --goal NAME`, `python -m harness goals --adapt`) ----
@dataclass(frozen=True)
class GoalAdaptCase:
    label: str
    case: str
    overrides: tuple[str, ...]
    goal: str
    uniform: tuple[int, ...]    # the uniform levels; Richardson's value from the three finest
    max_dofs: int               # the adaptive loop stops after the first step with this many unknowns


ADAPT_CASES: tuple[GoalAdaptCase, ...] = (
    GoalAdaptCase("paper, zero branch", "cases/paper.toml", ("scene.name=paper_zero",), "heat_through_contact",
                  (4, 8, 16, 32, 64), 20000),
    GoalAdaptCase("strip actuator", "cases/strip_actuator.toml", (), "electrode_charge.electrode", (2, 4, 8, 16, 32),
                  30000),
)


def adapt_for_goal(scene: Scene, goal: str, layout: Layout, steps: int, bulk: float, max_dofs: int | None,
                   announce: Callable[[str], None] = lambda line: None) -> pd.DataFrame:
    """The adaptive loop of harness/study/adapt.py marked by the goal's dual-weighted cell
    indicators (Dörfler on |eta_K|: its squared argument is |eta_K|, the indicators being
    signed terms of the estimate, not squares): per step its unknowns, the goal's value and
    estimate, and the times."""
    from harness.mesh import bisection
    from harness.mesh.mesh import build_mesh
    from harness.run.goals import vtk_name
    from harness.study.adapt import REFINERS, check_adaptable, indicator_on, read_start, solve_on, write_step

    check_adaptable(scene)
    if goal not in scene.goals:
        raise ValueError(f"{goal} is not a goal of {scene.name}")
    start = build_mesh(scene.geometry, scene.levels[0], layout.meshes_dir(scene.name)).path
    mesh = read_start(start, scene.dimension)
    refiner = REFINERS[scene.dimension]
    warm = None
    rows = []
    for index in range(1, steps + 1):
        path = layout.meshes_dir(scene.name) / f"goal_{index}.msh"
        write_step(mesh, path)
        run = solve_on(scene, path, index, layout, warm, False, quiet)
        r = run.record
        rows.append({"step": index, "dofs": r.dofs, "cells": len(mesh.cells), "wall_s": r.wall_s, "goal_s": r.goal_s,
                     "value": r.quantities[goal], "estimate": (r.goal_estimates or {})[goal]})
        announce(f"step {index}: {r.dofs} dofs, {goal} {rows[-1]['value']:.6g}, estimate {rows[-1]['estimate']:.3g}")
        if index == steps or (max_dofs is not None and (r.dofs or 0) >= max_dofs):
            break
        eta = np.abs(indicator_on(mesh, run.solution, vtk_name(goal)))
        warm = run.warm_start(path)
        mesh = refiner.refine(mesh, bisection.dorfler(np.sqrt(eta), bulk))
    return pd.DataFrame(rows)


def goal_adapt_rows(case: GoalAdaptCase, layout: Layout, bulk: float) -> pd.DataFrame:
    """The case's adaptive steps and uniform levels side by side, each with its error against
    Richardson's value of the three finest uniform levels."""
    base = load_scene(REPO / case.case, list(case.overrides))
    uniform_scene = load_scene(REPO / case.case, [*case.overrides, f'scene.name="{base.name}_uniform"'])
    uniform = solve_levels(uniform_scene, case.uniform, layout)
    finest = sorted(uniform, reverse=True)[:3]
    grid = three_grid(tuple(1 / n for n in finest), tuple(uniform[n].quantities[case.goal] for n in finest))
    reference = grid.f_ext if grid.behaviour == "monotone" else math.nan
    scene = load_scene(REPO / case.case, [*case.overrides, f'scene.name="{base.name}_goal"',
                                          f'quantities.goals=["{case.goal}"]'])
    steps = adapt_for_goal(scene, case.goal, layout, 40, bulk, case.max_dofs)
    rows = [{"case": case.label, "goal": case.goal, "mesh": f"uniform n={n}", "dofs": r.dofs, "wall_s": r.wall_s,
             "value": r.quantities[case.goal], "estimate": math.nan} for n, r in uniform.items()]
    rows += [{"case": case.label, "goal": case.goal, "mesh": f"adaptive step {s.step}", "dofs": s.dofs,
              "wall_s": s.wall_s, "value": s.value, "estimate": s.estimate} for s in steps.itertuples()]
    table = pd.DataFrame(rows)
    table["reference"] = reference
    table["error"] = reference - table["value"]
    table["relative_error"] = (table["error"] / reference).abs()
    return table


def adapt_markdown(table: pd.DataFrame) -> str:
    lines = ["| case | goal | mesh | dofs | wall [s] | Q_h | Q_ref - Q_h | estimate | relative error |",
             "|---|---|---|---|---|---|---|---|---|"]
    for _, r in table.iterrows():
        estimate = "" if math.isnan(r.estimate) else f"{r.estimate:.3g}"
        lines.append(f"| {r.case} | {r.goal} | {r.mesh} | {r.dofs:,} | {r.wall_s:.2f} | {r.value:.7g} | "
                     f"{r.error:.3g} | {estimate} | {r.relative_error:.2e} |")
    refs = table.drop_duplicates(["case", "goal"])
    lines += ["", "References (Richardson, the three finest uniform levels): "
              + "; ".join(f"{r.case} {r.goal} = {r.reference:.10g}" for _, r in refs.iterrows())]
    return "\n".join(lines) + "\n"


def write_adapt_tables(table: pd.DataFrame, out: Path) -> None:
    write_csv(table, out / "adapt.csv")
    write_text(adapt_markdown(table), out / "adapt.md")
