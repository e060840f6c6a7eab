"""Past one machine, measured (`make scale`, `python -m harness scale`, into results/scale/): one solve on 1 and on 2
MPI ranks (time, Krylov iterations, per-rank memory, agreement), and a study on this
machine (one worker) against a local Dask cluster (time, identical tables).

Small sizes by default (CPU is shared while developing); the issue's sizes on an idle
machine: `make scale SCALE_FLAGS="--mpi-levels 64,256 --study-levels 2,4,8,16,32"`.
Every run is forced (no cache reuse), so the times are the runs' own.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pandas as pd

from harness.arguments import level_list
from harness.atomic import write_atomic
from harness.errors import RunError
from harness.executor import LevelChain, LocalExecutor, executor
from harness.layout import Layout
from harness.scene import load_scene
from harness.study import error_table

CASES = Path(__file__).resolve().parents[1] / "cases"


def read_state(path: Path) -> list[np.ndarray]:
    """state.txt (output.idp): per field, a count then the values."""
    tokens = path.read_text().split()
    fields, i = [], 0
    while i < len(tokens):
        count = int(tokens[i])
        fields.append(np.array(tokens[i + 1:i + 1 + count], dtype=float))
        i += 1 + count
    return fields


def mpi_table(case: Path, levels: tuple[int, ...], ranks: Sequence[int], layout: Layout) -> pd.DataFrame:
    """Each rank count's warm chain up to the finest level; one row per (level, ranks)."""
    chain_levels = tuple(sorted({*(2 ** k for k in range(1, 12) if 2 ** k <= max(levels)), *levels}))
    runs: dict[int, Any] = {}
    for count in ranks:
        scene = load_scene(case, [f"scene.name=scale_ranks{count}", f"run.ranks={count}"])
        outcome = LocalExecutor(1).run([LevelChain(scene, chain_levels, layout, force=True)])[0]
        if outcome.error:
            raise RunError(outcome.error)
        runs[count] = outcome.runs
    rows = []
    for n in levels:
        base = runs[ranks[0]][n]
        reference = read_state(base.directory / "state.txt")
        for count in ranks:
            run = runs[count][n]
            record = run.record
            parallel = record.parallel or {}
            differences = [float(np.abs(a - b).max() / max(np.abs(a).max(), 1e-300))
                           for a, b in zip(reference, read_state(run.directory / "state.txt"))]
            per_rank = parallel.get("peak_rss_mb_per_rank", [record.peak_rss_mb])
            wall = parallel.get("wall", {})
            rows.append({
                "n": n, "ranks": count, "dofs": record.dofs,
                "newton_iterations": record.newton_iterations,
                "krylov_iterations": " ".join(str(k) for k in (record.linear_iterations or [])[1:]),
                "factorisations": record.factorisations,
                "wall_s": record.wall_s,
                "solve_wall_s": wall.get("total_s", record.wall_s),
                "factorisation_s": wall.get("factorisation_s", record.factorisation_s),
                "krylov_s": wall.get("krylov_s", record.solve_s),
                "peak_rss_mb_max_rank": max(per_rank),
                "peak_rss_mb_per_rank": " ".join(f"{m:.1f}" for m in per_rank),
                "memory_vs_1_rank": max(per_rank) / max(base.record.peak_rss_mb or 1.0, 1e-9),
                "max_rel_diff_vs_1_rank": max(differences),
                "linear_solver": record.linear_solver,
            })
    return pd.DataFrame(rows)


def study_table(levels: tuple[int, ...], cluster: str, layout_root: Path) -> pd.DataFrame:
    """Every scene of cases/*.toml as a chain: one local worker against the Dask cluster;
    the tables compared as the study's CSV writes them (10 digits: full precision would
    compare round-off, ~1e-14, between a pipelined and a plain run of one level)."""
    rows, tables = [], {}
    for label, how in (("local, 1 worker", None), (f"dask {cluster}", cluster)):
        layout = Layout(results=layout_root / label.split(",")[0].split()[0])
        chains = [LevelChain(load_scene(case), levels, layout, force=True) for case in sorted(CASES.glob("*.toml"))]
        start = time.perf_counter()
        with executor(1, cluster=how) as runner:
            outcomes = runner.run(chains)
        wall = time.perf_counter() - start
        errors = [o.error for o in outcomes if o.error]
        if errors:
            raise RunError(errors[0])
        tables[label] = {o.chain.scene.name: error_table(o.runs, tuple(o.runs[max(levels)].record.fields or ()))
                         .drop(columns=["wall_s"]).to_csv(float_format="%.10g") for o in outcomes}
        rows.append({"executor": label, "scenes": len(chains), "levels": " ".join(map(str, levels)),
                     "runs": sum(len(o.runs) for o in outcomes), "wall_s": wall})
    table = pd.DataFrame(rows)
    first = next(iter(tables.values()))
    table["tables_equal_to_local"] = [t == first for t in tables.values()]
    table["time_vs_local"] = table["wall_s"] / table["wall_s"].iloc[0]
    return table


def markdown(table: pd.DataFrame) -> str:
    cells = [[f"{v:.4g}" if isinstance(v, float) else str(v) for v in row] for row in table.itertuples(index=False)]
    lines = ["| " + " | ".join(table.columns) + " |", "|" + "---|" * len(table.columns)]
    return "\n".join(lines + ["| " + " | ".join(row) + " |" for row in cells]) + "\n"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--mpi-levels", type=level_list, default=(16, 32), help="levels solved on 1 and 2 ranks")
    parser.add_argument("--study-levels", type=level_list, default=(2, 4, 8, 16), help="levels of the study")
    parser.add_argument("--cluster", default="local:2", help="the Dask cluster of the study")
    parser.add_argument("--results", type=Path, default=Layout().results, help="results root")


def run(args: argparse.Namespace) -> int:
    out = args.results / "scale"
    out.mkdir(parents=True, exist_ok=True)
    work = Layout(results=out / "runs")
    mpi = mpi_table(CASES / "paper.toml", args.mpi_levels, (1, 2), work)
    study = study_table(args.study_levels, args.cluster, out / "runs" / "study")
    write_atomic(out / "mpi.csv", mpi.to_csv(index=False, float_format="%.6g"))
    write_atomic(out / "study.csv", study.to_csv(index=False, float_format="%.6g"))
    write_atomic(out / "scale.md", "## One solve on 1 and 2 MPI ranks (paper scene)\n\n" + markdown(mpi)
                 + "\n## A study on one local worker and on a Dask cluster\n\n" + markdown(study))
    print(markdown(mpi))
    print(markdown(study))
    print(f"wrote {out}/mpi.csv, study.csv, scale.md")
    return 0
