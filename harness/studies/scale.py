"""Past one machine, measured (`make scale`, `python -m harness scale`, into results/scale/):
one solve of the paper scene, 2D and 3D, on 1 and on 2 MPI ranks, the latter with the
one-level Schwarz and with its coarse space (`run.coarse_space`: `--coarse-spaces`) (time,
Krylov iterations, per-rank memory, agreement); the 3D paper scene with PETSc across 1, 2, 4
and 8 ranks (`--petsc-ranks`, medians of `--repeats` runs); and the stress suite in this process
against local Dask clusters of 1 and 2 workers (each started and warmed before it is timed;
median of several runs; identical summaries). `--parts` runs some of the three; scale.md
holds every table in results/scale/, those not run as they were.

Small sizes by default (CPU is shared while developing); the full sizes on an idle
machine: `make scale SCALE_FLAGS="--mpi-levels 64,256 --mpi-3d-levels 8,16 --stress-levels="`
(each stress case on its own levels). Every run is forced (no cache reuse), so the times
are the runs' own.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

from harness.arguments import add_memory_override, add_results, level_list, name_list
from harness.study.hard_cases import case_files
from harness.core.layout import REPO, Layout
from harness.study.pipeline import Guarded, Plan, run_pipeline
from harness.study.scale_out import chain_levels, mpi_table, petsc_table, stress_table
from harness.core.errors import SceneError
from harness.scene.scene import load_scene
from harness.core.writers import markdown_table, write_text

CASES = REPO / "cases"
PARTS = ("mpi", "petsc3d", "stress")
# Each table's file in results/scale/ and its heading in scale.md, in the page's order.
TABLES = {"mpi.csv": "One solve on 1 and 2 MPI ranks (paper scene)",
          "mpi3d.csv": "One 3D solve on 1 and 2 MPI ranks (paper3d)",
          "stress.csv": "The stress suite in this process and on a Dask cluster"}


def markdown(table: pd.DataFrame) -> str:
    cells = [[f"{v:.4g}" if isinstance(v, float) else str(v) for v in row] for row in table.itertuples(index=False)]
    return markdown_table(list(table.columns), cells)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--mpi-levels", type=level_list, default=(16, 32), help="levels solved on 1 and 2 ranks")
    parser.add_argument("--mpi-3d-levels", type=level_list, default=(4,),
                        help="levels of the 3D paper scene (cases/paper3d.toml) solved on 1 and 2 ranks (empty: none)")
    parser.add_argument("--stress-levels", type=level_list, default=(2, 4),
                        help="levels of every stress case (empty: each case's own)")
    parser.add_argument("--clusters", type=name_list, default=("local:1", "local:2"),
                        help="the Dask clusters the stress suite is timed on")
    parser.add_argument("--stress-repeats", type=int, default=5, help="timed runs of the stress suite per executor")
    parser.add_argument("--coarse-spaces", type=name_list, default=("none", "nested"),
                        help="the Schwarz coarse spaces (run.coarse_space) each solve on 2 ranks is timed with")
    parser.add_argument("--petsc-3d-levels", type=level_list, default=(8,),
                        help="levels of the 3D paper scene solved with PETSc on each of --petsc-ranks")
    parser.add_argument("--petsc-ranks", type=level_list, default=(1, 2, 4, 8),
                        help="rank counts of the PETSc table, the first the reference (past 2: oversubscribed here)")
    parser.add_argument("--repeats", type=int, default=3, help="runs of each PETSc configuration (medians)")
    parser.add_argument("--parts", type=name_list, default=PARTS, help=f"which tables to measure, of {', '.join(PARTS)}")
    add_results(parser)
    add_memory_override(parser)


def run(args: argparse.Namespace) -> int:
    out = args.results / "scale"
    work = Layout(results=out / "runs")
    unknown = set(args.parts) - set(PARTS)
    if unknown:
        raise SceneError(f"--parts takes {', '.join(PARTS)}, not {', '.join(sorted(unknown))}")
    on_ranks = ['run.linear_solver="mumps"']  # as mpi_table runs them
    # Each configuration mpi_table runs (an unknown coarse space fails here, before any run).
    configs = [[*on_ranks, f'run.coarse_space="{space}"'] for space in dict.fromkeys(("none", *args.coarse_spaces))]
    guarded: list[Guarded] = []
    if "mpi" in args.parts:
        guarded += [Guarded(load_scene(CASES / "paper.toml", c), chain_levels(args.mpi_levels)) for c in configs]
        if args.mpi_3d_levels:
            guarded += [Guarded(load_scene(CASES / "paper3d.toml", c), chain_levels(args.mpi_3d_levels)) for c in configs]
    if "petsc3d" in args.parts:
        guarded += [Guarded(load_scene(CASES / "paper3d.toml", ['run.linear_solver="petsc"', f"run.ranks={count}"]),
                            chain_levels(args.petsc_3d_levels)) for count in args.petsc_ranks[:1]]
    if "stress" in args.parts:
        guarded += [Guarded(load_scene(case), tuple(args.stress_levels)) for case in case_files([])]
    plan = Plan(args.results, tuple(guarded), outputs=(out,), locked=tuple(work.case_dir(g.scene.name) for g in guarded),
                ignore_memory=args.ignore_memory)

    def runs() -> dict[str, pd.DataFrame]:
        tables = {}
        if "mpi" in args.parts:
            tables["mpi.csv"] = mpi_table(CASES / "paper.toml", args.mpi_levels, (1, 2), work, args.coarse_spaces)
            if args.mpi_3d_levels:
                tables["mpi3d.csv"] = mpi_table(CASES / "paper3d.toml", args.mpi_3d_levels, (1, 2), work, args.coarse_spaces)
        if "petsc3d" in args.parts:
            name = f"petsc3d_n{max(args.petsc_3d_levels)}.csv"
            tables[name] = petsc_table(CASES / "paper3d.toml", args.petsc_3d_levels, args.petsc_ranks, work, args.repeats)
        if "stress" in args.parts:
            tables["stress.csv"] = stress_table(args.stress_levels, args.clusters, args.stress_repeats, out / "runs" / "stress")
        return tables

    def report(tables: dict[str, pd.DataFrame]) -> None:
        for name, table in tables.items():
            write_text(table.to_csv(index=False, float_format="%.6g"), out / name)
            print(markdown(table))
        # A PETSc table per finest level (each its own run: h = 1/32 on fewer ranks, under the memory lock).
        petsc = {path.name: f"One 3D solve with PETSc across MPI ranks (paper3d, {path.stem.split('_')[-1]}; "
                            "medians of the repeats)" for path in sorted(out.glob("petsc3d_n*.csv"))}
        sections = [f"## {heading}\n\n" + markdown(pd.read_csv(out / name))
                    for name, heading in {**TABLES, **petsc}.items() if (out / name).is_file()]
        write_text("\n".join(sections), out / "scale.md")
        print(f"wrote {', '.join(f'{out}/{name}' for name in tables)}, scale.md")

    run_pipeline(plan, runs, report)
    return 0
