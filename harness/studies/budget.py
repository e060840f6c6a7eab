"""`python -m harness budget CASE --n N`: each quantity's error at level N in three parts, each
beside the wall time it costs (docs/cost.md), into results/budget/<case>/:

- the mesh's (discretisation): Richardson's from levels N/4, N/2, N, and the goal-oriented
  estimate beside it when level N's run.json has one;
- the penalty's: level N again at contact.c_nu x10 and x100, and from the three Richardson's
  limit in 1/c_nu where the answer has one (exact, augmented-Lagrangian contact, which would
  remove this part, is not yet in the harness);
- Newton's: level N solved to newton.rtol = 1e-6 against the case's own rtol.

Each part is the other run's (or the extrapolated) value minus level N's, relative to level N's. Writes budget.csv (a row per quantity: its value, each part, each
part's wall time) and budget.md, and prints one line per quantity. Its runs are its own:
levels/ (n<N/4>, n<N/2>, n<N>), c_nu_x10/, c_nu_x100/ and newton_rtol_1e-6/ (each n<N>), so
none meets a convergence study's levels. Level N's variants start where level N did: from
level N/2's state when the case starts each level from the coarser one, else from the case's
own start (so a case's branch, `scene.coarsest_guess = "pressed"`, is kept). Every run passes
its physical checks or the verdict fails (exit 1).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import pandas as pd

from harness.arguments import add_case, add_common, positive_int
from harness.core.errors import SceneError
from harness.core.layout import Layout
from harness.core.writers import PRECISE_CSV_FORMAT, cell, markdown_table, write_csv, write_text
from harness.measure.budget import LOOSE_RTOL, PENALTY_FACTORS, BudgetRuns, budget_line, budget_table
from harness.measure.run_checks import failed_checks, print_checks
from harness.run.run import RunResult, WarmStart, check_solver_files, run_level
from harness.scene.scene import Scene
from harness.study.engine import InlineMeshes, run_levels, runs_of, stderr_line
from harness.study.pipeline import Guarded, Plan, run_pipeline, scene_of

LOOSE_NAME = "newton_rtol_1e-6"
AUGMENTED_LAGRANGIAN = ("exact (augmented-Lagrangian) contact, against which the penalty's part would be "
                        "measured, is not yet in the harness: the penalty's part here is how far the answer "
                        "moves as c_nu grows")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_case(parser)
    parser.add_argument("--n", type=positive_int, required=True,
                        help="the level whose error is budgeted (a multiple of 4: Richardson's estimate uses "
                             "levels N/4 and N/2 beside it)")
    add_common(parser)


def budget_levels(n: int) -> tuple[int, int, int]:
    if n % 4:
        raise SceneError(f"--n {n}: the budget's mesh part is Richardson's from levels N/4, N/2 and N, "
                         f"so N must be a multiple of 4")
    return n // 4, n // 2, n


def study_layout(results: Path, freefem: Path, name: str) -> Layout:
    """results/budget/<case>/: the report, and each run's scene directory under it."""
    out = results / name
    return Layout(results=results, freefem=freefem, placed=(
        (name, out / "levels"), *((f"{name}_c_nu_x{k}", out / f"c_nu_x{k}") for k in PENALTY_FACTORS),
        (f"{name}_{LOOSE_NAME}", out / LOOSE_NAME)))


def run(args: argparse.Namespace) -> int:
    levels = budget_levels(args.n)
    scene = scene_of(args.case, args.overrides)
    name = scene.name
    contact = "contact" in scene.effects
    c_nu = scene.sections.contact.c_nu if contact else None
    penalised = {k: scene_of(args.case, [*args.overrides, f"contact.c_nu={float(c_nu) * k!r}",
                                         f'scene.name="{name}_c_nu_x{k}"']) for k in PENALTY_FACTORS} if contact else {}
    loose = scene_of(args.case, [*args.overrides, f"newton.rtol={LOOSE_RTOL!r}", f'scene.name="{name}_{LOOSE_NAME}"'])
    layout = study_layout(args.results / "budget", args.freefem, name)
    out = layout.results / name
    n = args.n
    plan = Plan(layout.results, (Guarded(scene, levels), *(Guarded(s, (n,)) for s in (*penalised.values(), loose))),
                whole=(out,), ignore_memory=args.ignore_memory,
                scene_dirs=tuple(layout.case_dir(s.name) for s in (scene, *penalised.values(), loose)))
    print(f"budget {name} at n={n}: levels {', '.join(map(str, levels))}"
          + (f"; c_nu {c_nu:g} x{' and x'.join(map(str, PENALTY_FACTORS))}" if contact else "; no contact")
          + f"; newton.rtol {LOOSE_RTOL:g} against {scene.sections.newton.rtol:g}; into {out}", file=sys.stderr)

    def runs() -> tuple[dict[int, RunResult], dict[int, RunResult], RunResult]:
        check_solver_files(scene, layout)
        meshes = InlineMeshes(scene, levels, layout)
        ladder = runs_of(run_levels(scene, meshes, layout, force=args.force, progress=stderr_line))
        # Level N's variants on level N's own mesh, from where level N started.
        warm: WarmStart | None = ladder[levels[1]].warm_start(meshes[levels[1]]) \
            if scene.initial_guess == "coarser" else None

        def variant(other: Scene, label: str) -> RunResult:
            result = run_level(other, meshes[n], n, layout, args.force, warm)
            print(f"n={n} {label}: {'reused' if result.reused else 'done'} "
                  f"in {result.record.value('wall_s'):.1f} s, {result.record.newton_iterations} Newton its",
                  file=sys.stderr, flush=True)
            return result

        penalty = {k: variant(s, f"c_nu x{k}") for k, s in penalised.items()}
        return ladder, penalty, variant(loose, f"newton.rtol {LOOSE_RTOL:g}")

    def report(result: tuple[dict[int, RunResult], dict[int, RunResult], RunResult]) -> None:
        ladder, penalty, newton = result
        records = BudgetRuns({k: r.record for k, r in ladder.items()}, {k: r.record for k, r in penalty.items()},
                             newton.record)
        table = budget_table([(q.name, q.unit(scene.dimension)) for q in scene.quantities], records)
        write_csv(table, out / "budget.csv", PRECISE_CSV_FORMAT)
        write_text(budget_markdown(scene, n, levels, table, contact), out / "budget.md")
        for row in table.to_dict("records"):
            print(budget_line(row))
        if contact:
            print(f"note: {AUGMENTED_LAGRANGIAN}")
        print(f"wrote {out / 'budget.csv'}, {out / 'budget.md'}")

    def verdict(result: tuple[dict[int, RunResult], dict[int, RunResult], RunResult]) -> str | None:
        ladder, penalty, newton = result
        failed = failed_checks(print_checks(scene, [ladder[k] for k in sorted(ladder)]))
        for other, run_ in [*((penalised[k], r) for k, r in penalty.items()), (loose, newton)]:
            print(f"{other.name}:")
            failed = failed or failed_checks(print_checks(other, [run_]))
        return f"{name}: {failed}" if failed else None

    run_pipeline(plan, runs, report, verdict)
    return 0


def budget_markdown(scene: Scene, n: int, levels: tuple[int, ...], table: pd.DataFrame, contact: bool) -> str:
    """budget.md: the table, with what each column is."""
    goal = "goal_estimate" in table.columns
    header = ["quantity", "unit", f"value at n = {n}", "mesh (Richardson)", *(["mesh (goal)"] if goal else []),
              "penalty c_nu x10", "penalty c_nu x100", "penalty's limit", "Newton rtol 1e-6"]
    rows = []
    for row in table.to_dict("records"):
        mesh = signed(row["discretisation"]) if math.isfinite(row["discretisation"]) else \
            str(row["discretisation_status"])
        rows.append([row["quantity"], row["unit"], f"{row['value']:.6g}", mesh,
                     *([signed(row["goal_estimate"])] if goal else []),
                     signed(row["penalty_x10"]), signed(row["penalty_x100"]),
                     signed(row["penalty_limit"]) if math.isfinite(row["penalty_limit"]) else
                     str(row["penalty_limit_status"]).split(":")[0], signed(row["newton"])])
    first = table.iloc[0]
    times = markdown_table(["part", "runs", "wall time [s]"], [
        ["the value", f"level {n}", cell(float(first["value_wall_s"]))],
        ["mesh (Richardson)", f"levels {levels[0]}, {levels[1]}", cell(float(first["discretisation_wall_s"]))],
        ["penalty", f"level {n} at c_nu x10 and x100", cell(float(first["penalty_wall_s"])) if contact else "–"],
        ["Newton", f"level {n} at rtol 1e-6", cell(float(first["newton_wall_s"]))]])
    contact_line = (f"contact.c_nu = {scene.sections.contact.c_nu:g}; {AUGMENTED_LAGRANGIAN}." if contact
                    else "The scene has no contact: no penalty part.")
    return (f"# Error budget: {scene.name} at n = {n}\n\n"
            f"Case {scene.source.name}; `python -m harness budget` (harness/studies/budget.py). Each part is "
            f"signed and relative to the value at n = {n}: mesh, Richardson's (f_ext - f_{n}) / |f_{n}| from "
            f"levels {', '.join(map(str, levels))} (or, where the quantity is not extrapolable, why); "
            f"penalty, (Q(k c_nu) - Q) / |Q|, and its limit (Q_inf - Q) / |Q|, Richardson's in 1/c_nu from "
            f"c_nu x1, x10, x100 (or why there is none: divergent, the answer grows with c_nu); Newton, (Q(rtol 1e-6) - Q) / |Q| against newton.rtol = "
            f"{scene.sections.newton.rtol:g}. {contact_line}\n\n"
            + markdown_table(header, rows) + "\nWhat each part's runs cost (this machine):\n\n" + times)


def signed(value: float) -> str:
    return "–" if not math.isfinite(value) else f"{value:+.2e}" if value else "0"
