"""The solver table: every linear solver on the same levels, medians of repeats.

    python -m harness solvers [--points paper:64,paper3d:16] [--repeats 3]
        [--only mumps,umfpack,petsc-fieldsplit,petsc-mumps-blr,petsc-mg] [--results results/solvers]
        [--rank-point paper:64 --ranks 1,2,4,8 --coarse-spaces none,nested]

Each point is a scene of cases/ and a level. The chain below the level is solved once per
solver (and cached); the level itself is then rerun `--repeats` times from it, alone, as a
study's last level runs. Per run, from run.json: the bulk assembly, the linear solver's
set-up (a factorisation, or a preconditioner's set-up) and solve times, Newton's time, the
peak memory (FreeFEM's VmHWM), Newton's iterations and the Krylov iterations of each step.
A solver that fails at a point (UMFPACK's 32-bit indices, a Krylov method that stalls) is a
row with its reason, not an error of the table.

With --ranks, the rank table (ranks.csv, ranks.md): the rank point solved from zero on each
number of MPI ranks (run.ranks: restricted additive Schwarz with a MUMPS_seq factorisation
per subdomain, freefem/parallel_newton.idp) and each run.coarse_space of --coarse-spaces
(none: one level; nested: with the coarse-grid correction of freefem/coarse_space.idp),
its Newton iterations and the GMRES iterations of each step. Ranks past the cores are
oversubscribed: the iteration counts are what such a run measures, not its time.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
from pathlib import Path
from typing import Any, Callable

import pandas as pd

from harness.arguments import add_memory_override, add_results, name_list, positive_int
from harness.study.engine import quiet, run_levels, runs_of, timed_meshes
from harness.core.errors import RunError
from harness.core.layout import REPO, Layout
from harness.scene.petsc_options import MULTIGRID, MUMPS_LU, field_split_options
from harness.report.plot import plot_rank_iterations
from harness.study.pipeline import Guarded, Plan, run_pipeline
from harness.run.run import run_level
from harness.scene.scene import Scene, load_scene
from harness.scene.unknowns import Unknowns
from harness.core.writers import markdown_table, write_csv, write_text

CASES = REPO / "cases"
# Each solver: run.linear_solver and, for PETSc, run.petsc_options of the scene's Newton fields.
SOLVERS: dict[str, tuple[str, Callable[[tuple[str, ...]], str]]] = {
    "mumps": ("mumps", lambda fields: ""),
    "umfpack": ("umfpack64", lambda fields: ""),
    "petsc-fieldsplit": ("petsc", field_split_options),
    "petsc-mumps": ("petsc", lambda fields: MUMPS_LU),
    "petsc-mumps-blr": ("petsc", lambda fields: MUMPS_LU + " -mat_mumps_icntl_35 2 -mat_mumps_cntl_7 1e-8"),
    "petsc-mg": ("petsc", lambda fields: MULTIGRID),
}
COARSE_SPACES = ("none", "nested")  # run.coarse_space (harness/scene/schema.py)
KEYS = ("wall_s", "bulk_assembly_s", "factorisation_s", "solve_s", "newton_s", "peak_rss_mb")


def point(text: str) -> tuple[str, int]:
    case, _, level = text.partition(":")
    if not (CASES / f"{case}.toml").is_file() or not level.isdigit():
        raise argparse.ArgumentTypeError(f"{text!r}: want CASE:N with cases/CASE.toml, e.g. paper3d:16")
    return case, int(level)


def solver_list(text: str) -> list[str]:
    names = name_list(text)
    unknown = [name for name in names if name not in SOLVERS]
    if unknown:
        raise argparse.ArgumentTypeError(f"unknown solver(s) {', '.join(unknown)}; known: {', '.join(SOLVERS)}")
    return names


def solver_scene(case: str, name: str) -> Scene:
    """The case solved with the table's solver `name`."""
    solver, options_of = SOLVERS[name]
    plain = load_scene(CASES / f"{case}.toml")
    options = options_of(tuple(f.name for f in Unknowns(plain.effects, plain.dimension).newton))
    overrides = [f'run.linear_solver="{solver}"', f'scene.name="solvers-{case}-{name}"', "run.timeout_s=3600"]
    if options:
        overrides.append(f'run.petsc_options="{options}"')
    return load_scene(CASES / f"{case}.toml", overrides)


def measure(case: str, n: int, name: str, repeats: int, layout: Layout,
            say: Callable[[str], None]) -> dict[str, Any]:
    scene = solver_scene(case, name)
    solver = scene.linear_solver
    levels = [m for m in scene.levels if m < n] + [n]
    row: dict[str, Any] = {"scene": case, "n": n, "solver": name, "linear_solver": solver,
                           "options": scene.solver_options}
    try:
        meshes, _ = timed_meshes(scene, levels, layout)
        below = {m: p for m, p in meshes.items() if m < n}
        runs = runs_of(run_levels(scene, below, layout, progress=quiet)) if below else {}
        warm = runs[max(below)].warm_start(meshes[max(below)]) if below else None
        records = []
        for i in range(repeats):
            records.append(run_level(scene, meshes[n], n, layout, force=True, warm=warm).record)
            say(f"{case} n={n} {name} #{i + 1}: {records[-1].wall_s:.2f} s")
    except RunError as exc:
        say(f"{case} n={n} {name}: failed: {exc}")
        return {**row, "status": f"failed: {exc.failure.text}"}
    last = records[-1]
    linear = list(last.linear_iterations or [])[1:]
    return {**row, "status": "ok", "repeats": repeats, "dofs": last.dofs,
            **{k: statistics.median(float(getattr(r, k)) for r in records) for k in KEYS},
            "newton_iterations": last.newton_iterations, "linear_iterations": " ".join(map(str, linear)),
            "linear_per_newton_step": sum(linear) / max(len(linear), 1)}


def rank_row(case: str, n: int, ranks: int, coarse: str, layout: Layout,
             say: Callable[[str], None]) -> dict[str, Any]:
    overrides = [f'scene.name="ranks-{case}-{ranks}-{coarse}"', f"run.ranks={ranks}", 'scene.initial_guess="zero"',
                 "run.timeout_s=3600", f'run.coarse_space="{coarse}"']
    scene = load_scene(CASES / f"{case}.toml", overrides)
    # One rank solves sequentially: no Schwarz, so no coarse space.
    row: dict[str, Any] = {"scene": case, "n": n, "ranks": ranks, "coarse_space": coarse if ranks > 1 else "-"}
    try:
        meshes, _ = timed_meshes(scene, [n], layout)
        record = run_level(scene, meshes[n], n, layout, force=True).record
    except RunError as exc:
        return {**row, "status": f"failed: {exc.failure.text}"}
    linear = list(record.linear_iterations or [])[1:]
    say(f"{case} n={n} on {ranks} rank(s), coarse space {row['coarse_space']}: Krylov iterations {linear}")
    return {**row, "status": "ok", "dofs": record.dofs, "newton_iterations": record.newton_iterations,
            "krylov_iterations": " ".join(map(str, linear)), "max_krylov_per_step": max(linear, default=0),
            "wall_s": record.wall_s}


def rank_markdown(table: pd.DataFrame) -> str:
    lines = ["# Krylov iterations against MPI ranks (python -m harness solvers --ranks)", "",
             "RAS, MUMPS_seq per subdomain, from zero; coarse space none: one level, nested: with the coarse-grid "
             "correction (run.coarse_levels halvings below n, freefem/coarse_space.idp); 1 rank: the sequential "
             "scheme (a full factorisation as GMRES's preconditioner). Oversubscribed past 2 ranks (times not "
             "comparable).", ""]
    rows = []
    for _, r in table.iterrows():
        its = r.get("krylov_iterations", "") if r["status"] == "ok" else ""
        top = int(r["max_krylov_per_step"]) if r["status"] == "ok" else ""
        newton = int(r["newton_iterations"]) if r["status"] == "ok" else ""
        rows.append([r["scene"], r["n"], r["ranks"], r["coarse_space"], r["status"], newton, its, top])
    return "\n".join(lines) + "\n" + markdown_table(
        ("scene", "n", "ranks", "coarse space", "status", "Newton its", "Krylov its per step", "max per step"), rows)


def markdown(table: pd.DataFrame) -> str:
    lines = ["# Solver table (python -m harness solvers)", "",
             "Medians of the repeats of each level, run alone from the chain below it. Times in seconds,",
             "memory in MiB (FreeFEM's VmHWM). set-up: factorisation or preconditioner set-up.", ""]
    rows = []
    for _, r in table.iterrows():
        if r["status"] != "ok":
            rows.append([r["scene"], r["n"], "", r["solver"], r["status"], *[""] * 8])
            continue
        rows.append([r["scene"], r["n"], f"{int(r['dofs']):,}", r["solver"], "ok", f"{r['wall_s']:.2f}",
                     f"{r['bulk_assembly_s']:.2f}", f"{r['factorisation_s']:.2f}", f"{r['solve_s']:.2f}",
                     f"{r['newton_s']:.2f}", f"{r['peak_rss_mb']:,.0f}", int(r["newton_iterations"]),
                     r["linear_iterations"]])
    lines.append(markdown_table(("scene", "n", "dofs", "solver", "status", "wall", "bulk assembly", "set-up", "solve",
                                 "Newton", "peak MiB", "Newton its", "Krylov its per step"), rows).rstrip("\n"))
    options = {r["solver"]: r["options"] for _, r in table.iterrows() if r["options"]}
    lines += ["", "PETSc options (run.petsc_options):", ""]
    lines += [f"- `{name}`: `{text}`" for name, text in options.items()]
    return "\n".join(lines) + "\n"


def coarse_space_list(text: str) -> list[str]:
    names = name_list(text)
    unknown = [name for name in names if name not in COARSE_SPACES]
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"want some of {', '.join(COARSE_SPACES)}, not {text!r}")
    return names


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--points", type=lambda s: [point(p) for p in s.split(",")],
                        default=[("paper", 64), ("paper3d", 16)],
                        help="the scenes of cases/ and levels to time, as CASE:N,... (default: "
                        "paper:64,paper3d:16)")
    parser.add_argument("--repeats", type=positive_int, default=3,
                        help="how many times each level is rerun and timed per solver (default: 3)")
    parser.add_argument("--only", type=solver_list, default=list(SOLVERS),
                        help=f"comma-separated solvers ({', '.join(SOLVERS)})")
    parser.add_argument("--rank-point", type=point, default=("paper", 64),
                        help="the scene of cases/ and level of the rank table, as CASE:N (default: paper:64)")
    parser.add_argument("--ranks", type=lambda t: [positive_int(x) for x in t.split(",")], default=None,
                        help="comma-separated rank counts: the rank table alone (e.g. 1,2,4,8)")
    parser.add_argument("--coarse-spaces", type=coarse_space_list, default=["none", "nested"],
                        help="run.coarse_space values of the rank table (default none,nested)")
    add_results(parser, under="solvers")
    add_memory_override(parser)


def run(args: argparse.Namespace) -> int:
    def say(text: str) -> None:
        print(text, file=sys.stderr, flush=True)

    layout = Layout(results=args.results / "runs")
    # Each point guarded with the solvers it is measured with (a factorisation's fill, or not).
    points = ([(load_scene(CASES / f"{case}.toml"), n) for case, n in [args.rank_point]] if args.ranks
              else [(solver_scene(case, name), n) for case, n in args.points for name in args.only])
    guarded = tuple(Guarded(scene, tuple(m for m in scene.levels if m < n) + (n,)) for scene, n in points)
    plan = Plan(args.results, guarded, outputs=(args.results,),
                locked=tuple(layout.case_dir(g.scene.name) for g in guarded), ignore_memory=args.ignore_memory)
    if args.ranks:
        # More ranks than cores: OpenMPI refuses them unless told (the counts are what is measured).
        os.environ.setdefault("OMPI_MCA_rmaps_base_oversubscribe", "1")
        case, n = args.rank_point
        spaces = {count: args.coarse_spaces if count > 1 else args.coarse_spaces[:1] for count in args.ranks}

        def rank_report(ranks: pd.DataFrame) -> None:
            write_csv(ranks, args.results / "ranks.csv")
            write_text(rank_markdown(ranks), args.results / "ranks.md")
            plot_rank_iterations(ranks, args.results / "ranks.png")
            print(rank_markdown(ranks))

        run_pipeline(plan, lambda: pd.DataFrame([rank_row(case, n, count, coarse, layout, say)
                                                for count in args.ranks for coarse in spaces[count]]),
                     rank_report)
        return 0

    def report(table: pd.DataFrame) -> None:
        write_csv(table, args.results / "solvers.csv")
        write_text(markdown(table), args.results / "solvers.md")
        print(markdown(table))

    run_pipeline(plan, lambda: pd.DataFrame([measure(case, n, name, args.repeats, layout, say)
                                             for case, n in args.points for name in args.only]), report)
    return 0
