"""`python -m harness stress` (`make stress`): the stress suite, into results/stress/.

Every case file in cases/hard/ is the paper's scene with one thing made hard; its [expect]
section says what (`hard_because`), what the case must show (`requirement`), the outcome
expected (`status`: converged, or known_failure with its `failure` and `why`) and the
tolerance of its test, with why (harness/scene/schema.py). Each case runs its levels as a chain (each level from
the one below, as `make convergence` does; the coarsest from the case's `coarsest_guess`)
and is reported at its finest level, or at the level where it failed:

- status: `converged`, or the classified reason of the failure (`diverged`, `max_iterations`,
  `nan` from FreeFEM's exit code and run.json; `timeout` when the harness killed it;
  `freefem_error` for anything else; harness/core/contract.py's Failure), or `known_failure`
  for a case whose [expect] says so and that failed with the reason it names;
- Newton's work: iterations (per level too), final relative residual per field, damped
  steps, active-set changes, wall time;
- the physical checks of every converged run (`physical_checks`, tolerances in harness/measure/checks.py).

- cold starts: every level again on its own from the case's own start (zero, or pressed for
  the *_pressed cases), no coarser solution: Newton's iterations per level, its restart or
  move onto the foundation (freefem/newton.idp), and its solution's largest difference from
  the chain's at that level, node by node (round-off: the same solution; large: another
  branch).

Writes summary.csv (one row per case), summary.md (the same, short), cold_starts.csv (one
row per case and level) and paper_iterations.csv: Newton iterations per level of the
paper's scene with each level started from the coarser one, and with each level started
from zero.
Exit status 1 when a case fails unexpectedly, fails a check, or a known failure converges
(so that a fix is noticed and the case's expectation is flipped).
"""

from __future__ import annotations

import argparse
import time

import pandas as pd

from harness.arguments import add_cluster, add_common, add_levels, layout_of, level_list, name_list
from harness.measure.checks import CHECK_FLAGS
from harness.study.executor import cluster, each
from harness.core.freefem import freefem_version
from harness.study.hard_cases import (PAPER_LEVELS, PAPER_STARTS, case_cost, case_files, cold_start_scene,
                                      cold_starts, paper_iterations, paper_scene, passed, summary_row, timed_case)
from harness.measure.norm_table import FIELD_NAMES
from harness.study.pipeline import Guarded, Plan, run_pipeline
from harness.scene.scene import load_scene
from harness.core.writers import cell, markdown_table, write_csv, write_text

# ---- output ------------------------------------------------------------------------------

HEADER = ("case", "status", "n", "its per level", "cold its per level", "res u / φ / θ", "damped", "Δactive",
          "active / slip / Γ3 nodes", "contact force N/m", "wall s", "checks")


def cold_counts(rows: list[dict]) -> str:
    """A case's cold-start iterations per level, r<k> marking a restart from the pressed state
    after step k and f a move onto the foundation (freefem/newton.idp)."""
    marks = []
    for row in rows:
        if row["status"] != "converged":
            marks.append(row["status"])
            continue
        mark = f"{row['newton_iterations']}"
        mark += f"r{row['restarted_at']}" if row.get("restarted_at") else ""
        mark += "f" if row.get("moved_onto_foundation_at") else ""
        marks.append(mark)
    return " ".join(marks)


def markdown(table: pd.DataFrame) -> str:
    """The summary, short: one line per case."""
    rows = []
    for row in table.to_dict("records"):
        if row["status"] == "converged":
            failed = [k.removesuffix("_ok") for k in CHECK_FLAGS if not row.get(k)]
            checks = "pass" if not failed else "FAIL " + ", ".join(failed)
        else:
            checks = row["note"].split(":")[0]
        res = " / ".join(cell(row.get(f"residual_{f}")) or "–" for f in FIELD_NAMES)
        nodes = " / ".join(cell(row.get(k)) or "–" for k in ("active_nodes", "slip_nodes", "gamma3_nodes"))
        rows.append([row["case"], row["status"], row["n"], row["iterations_per_level"],
                     row.get("cold_iterations_per_level", ""), res,
                     cell(row.get("damping_steps")), cell(row.get("active_set_changes")), nodes,
                     cell(row.get("contact_force")), cell(row.get("wall_s")), checks])
    return markdown_table(HEADER, rows)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--cases", type=name_list, default=[], help="comma-separated case names of cases/hard/ (default: all)")
    add_levels(parser, what="each case's")
    parser.add_argument("--paper-levels", type=level_list, default=PAPER_LEVELS,
                        help="levels of the paper's iteration table (empty: skip it)")
    add_common(parser, under="stress")
    add_cluster(parser)


def run(args: argparse.Namespace) -> int:
    layout = layout_of(args)
    cases = case_files(args.cases)
    scenes = [load_scene(case) for case in cases]
    starts = list(PAPER_STARTS) if args.paper_levels else []
    guarded = [Guarded(scene, tuple(args.levels or ())) for scene in scenes]
    guarded += [Guarded(cold_start_scene(case), tuple(args.levels or ())) for case in cases]
    guarded += [Guarded(paper_scene(start), tuple(args.paper_levels)) for start in starts]
    plan = Plan(args.results, tuple(guarded), scene_dirs=tuple(layout.case_dir(g.scene.name) for g in guarded),
                outputs=(args.results,), ignore_memory=args.ignore_memory)

    def runs() -> tuple[list[dict], pd.DataFrame, pd.DataFrame | None]:
        freefem_version()
        rows = []
        began = time.perf_counter()
        with cluster(args.scheduler, args.cluster) as pool:  # each case a task, side by side, on a Dask cluster
            results = each(pool, lambda case: timed_case(case, layout, args.force, args.levels),
                           cases, cost=lambda case: case_cost(case, args.levels))
            colds = each(pool, lambda done: cold_starts(done[0], layout, args.force), results,
                         cost=lambda done: case_cost(done[0].scene.source, args.levels))
        cold_rows = []
        for (result, seconds), cold in zip(results, colds):
            row = summary_row(result)
            row["cold_iterations_per_level"] = cold_counts(cold)
            rows.append(row)
            cold_rows += cold
            print(f"{row['case']:<30} {row['status']:<15} n={row['n']:<3} its {row['iterations_per_level']:<14}"
                  f" checks {'pass' if row.get('checks_ok') else '-'}  ({seconds:.1f} s)"
                  + (f"  {row['note'][:100]}" if row["note"] else ""), flush=True)
            print(f"{'':<30} cold starts, its {row['cold_iterations_per_level']}", flush=True)
        print(f"{len(rows)} cases in {time.perf_counter() - began:.1f} s")
        its = paper_iterations(layout, args.paper_levels, args.force) if args.paper_levels else None
        return rows, pd.DataFrame(cold_rows), its

    def report(done: tuple[list[dict], pd.DataFrame, pd.DataFrame | None]) -> None:
        rows, cold, its = done
        table = pd.DataFrame(rows)
        if not args.cases and not args.levels:
            write_csv(table, args.results / "summary.csv")
            write_text(markdown(table), args.results / "summary.md")
            write_csv(cold, args.results / "cold_starts.csv")
        if its is not None:
            write_csv(its, args.results / "paper_iterations.csv")
            print(its[["start", "n", "status", "newton_iterations", "damping_steps", "active_set_changes"]]
                  .to_string(index=False))

    def verdict(done: tuple[list[dict], pd.DataFrame, pd.DataFrame | None]) -> str | None:
        rows = done[0]
        bad = [row["case"] for row in rows if not passed(row)]
        if bad:
            return f"{len(bad)} case(s) failed unexpectedly or failed a check: {', '.join(bad)}"
        print(f"{len(rows)} cases: every one converged with its checks passing, or is a known failure")
        return None

    run_pipeline(plan, runs, report, verdict)
    return 0
