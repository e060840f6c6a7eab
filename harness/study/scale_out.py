"""Past one machine, measured (the library of `make scale`, harness/studies/scale.py): one
solve on 1 and on N MPI ranks, and the stress suite in this process against Dask clusters,
with the comparison of their summaries to round-off."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pandas as pd

from harness.study.engine import BackgroundMeshes, quiet, run_levels, runs_of
from harness.study.executor import cluster, each
from harness.measure.fields import read_state
from harness.study.hard_cases import case_cost, case_files, run_case, summary_row
from harness.core.layout import Layout
from harness.scene.scene import load_scene

def chain_levels(levels: Sequence[int]) -> tuple[int, ...]:
    """The warm chain up to the finest of `levels`: every power of two below it, and them."""
    return tuple(sorted({*(2 ** k for k in range(1, 12) if 2 ** k <= max(levels)), *levels}))


def chain_runs(case: Path, name: str, overrides: Sequence[str], levels: tuple[int, ...], layout: Layout) -> dict[int, Any]:
    """One forced warm chain up to the finest of `levels` of `case` under `overrides`: its runs by level."""
    scene = load_scene(case, [f"scene.name={name}", *overrides])
    with BackgroundMeshes(scene, chain_levels(levels), layout) as meshes:
        return runs_of(run_levels(scene, meshes, layout, force=True, progress=quiet,
                                  chain=scene.initial_guess == "coarser"))


def rank_row(run: Any, base: Any, reference: list[np.ndarray]) -> dict[str, Any]:
    """A level's figures on its ranks against the first configuration's run `base` (state `reference`)."""
    record = run.record
    parallel = record.parallel or {}
    # Per field (state.txt holds them in the record's order): max |a - b| / max |a|.
    differences = {name: float(np.abs(a - b).max() / max(np.abs(a).max(), 1e-300))
                   for name, a, b in zip(record.fields, reference, read_state(run.directory / "state.txt"))}
    per_rank = parallel.get("peak_rss_mb_per_rank", [record.peak_rss_mb])
    wall = parallel.get("wall", {})
    return {
        "dofs": record.dofs, "newton_iterations": record.newton_iterations,
        "krylov_iterations": " ".join(str(k) for k in (record.linear_iterations or [])[1:]),
        "factorisations": record.factorisations,
        "wall_s": record.wall_s,  # a PETSc run on ranks: with the harness's cut of the mesh (cut_s)
        "cut_s": parallel.get("cut_s", 0.0),
        "solve_wall_s": wall.get("total_s", record.wall_s),
        "factorisation_s": wall.get("factorisation_s", record.factorisation_s),
        "krylov_s": wall.get("krylov_s", record.solve_s),
        "peak_rss_mb_max_rank": max(per_rank),
        "peak_rss_mb_per_rank": " ".join(f"{m:.1f}" for m in per_rank),
        "memory_vs_1_rank": max(per_rank) / max(base.record.peak_rss_mb or 1.0, 1e-9),
        # The sequential pass that writes the outputs (launcher.py): assembly, no factorisation.
        "post_pass_peak_rss_mb": record.post_pass_peak_rss_mb if record.ranks else None,
        "max_rel_diff_vs_1_rank": max(differences.values()),
        **{f"rel_diff_{name}": value for name, value in differences.items()},
        "linear_solver": record.linear_solver,
    }


def mpi_table(case: Path, levels: tuple[int, ...], ranks: Sequence[int], layout: Layout,
              coarse_spaces: Sequence[str] = ("none",)) -> pd.DataFrame:
    """Each configuration's warm chain up to the finest level: one rank, then each rank count
    of `ranks` past the first with each Schwarz coarse space of `coarse_spaces`
    (run.coarse_space); one row per (level, configuration), compared with the first."""
    configs = [(count, space) for count in ranks for space in (("none",) if count == 1 else coarse_spaces)]
    runs: dict[tuple[int, str], Any] = {}
    for count, space in configs:
        # Ranks factorise their subdomains (MUMPS_seq), whatever the case solves one rank with.
        name = f"scale_{case.stem}_ranks{count}" + ("" if space == "none" else f"_{space}")
        runs[count, space] = chain_runs(case, name, [f"run.ranks={count}", 'run.linear_solver="mumps"',
                                                     f'run.coarse_space="{space}"'], levels, layout)
    rows = []
    for n in levels:
        base = runs[configs[0]][n]
        reference = read_state(base.directory / "state.txt")
        for count, space in configs:
            rows.append({"n": n, "ranks": count, "coarse_space": space, **rank_row(runs[count, space][n], base, reference)})
    return pd.DataFrame(rows)


def petsc_table(case: Path, levels: tuple[int, ...], ranks: Sequence[int], layout: Layout, repeats: int) -> pd.DataFrame:
    """PETSc on each rank count of `ranks` (the first the reference; run.petsc_options the
    scene's or the ranks' default, freefem/petsc_ranks.idp), each warm chain run `repeats`
    times: the medians of each level's wall time and largest per-rank peak, the rest (Krylov
    iterations, agreement) of the last run, which the others repeat."""
    runs: dict[int, list[dict[int, Any]]] = {}
    for count in ranks:
        runs[count] = [chain_runs(case, f"scale_petsc_{case.stem}_ranks{count}",
                                  [f"run.ranks={count}", 'run.linear_solver="petsc"'], levels, layout)
                       for _ in range(repeats)]
    rows = []
    for n in levels:
        base = runs[ranks[0]][-1][n]
        reference = read_state(base.directory / "state.txt")
        for count in ranks:
            row = rank_row(runs[count][-1][n], base, reference)
            walls = [chain[n].record.wall_s for chain in runs[count]]
            peaks = [max((chain[n].record.parallel or {}).get("peak_rss_mb_per_rank", [chain[n].record.peak_rss_mb]))
                     for chain in runs[count]]
            row.update(repeats=repeats, wall_s=float(np.median(walls)), wall_s_all=" ".join(f"{w:.3g}" for w in walls),
                       peak_rss_mb_max_rank=float(np.median(peaks)))
            rows.append({"n": n, "ranks": count, **row})
    table = pd.DataFrame(rows)
    one = table[table["ranks"] == ranks[0]].set_index("n")
    table["wall_vs_1_rank"] = [w / one.loc[n, "wall_s"] for n, w in zip(table["n"], table["wall_s"])]
    table["memory_vs_1_rank"] = [m / one.loc[n, "peak_rss_mb_max_rank"]
                                 for n, m in zip(table["n"], table["peak_rss_mb_max_rank"])]
    return table


# Columns near zero whose round-off is judged against the row's own scale (the one its
# physical check uses, harness/measure/checks.py): max sigma_nu is -1e-7 N/m^2 where the contact
# pressure is 100, and moves by 2e-12 between two runs of the 3D unstructured case.
ROW_SCALES = {"max_sigma_nu": "sigma_nu_scale"}


def same_summary(a: pd.DataFrame, b: pd.DataFrame, rtol: float = 1e-5, atol: float = 1e-12) -> bool:
    """Equal stress summaries: text columns exactly, numbers to rtol/atol (ROW_SCALES' columns
    to 1e-9 of their row's scale). Not bit for bit: the unstructured cases are not
    bit-reproducible across processes (gmsh's 2D mesh), nor is a level pipelined or not
    (round-off of the sparse solver's kernels), which moves near-zero figures."""
    if list(a.columns) != list(b.columns) or len(a) != len(b):
        return False
    for column in a.columns:
        x, y = a[column], b[column]
        if pd.api.types.is_numeric_dtype(x) and pd.api.types.is_numeric_dtype(y):
            u, v = x.to_numpy(float), y.to_numpy(float)
            scale = ROW_SCALES.get(column)
            floor = np.maximum(atol, 1e-9 * np.abs(a[scale].to_numpy(float))) if scale in a.columns else atol
            same = (np.abs(u - v) <= floor + rtol * np.abs(v)) | (np.isnan(u) & np.isnan(v))
            if not same.all():
                return False
        elif not x.astype(str).equals(y.astype(str)):
            return False
    return True


def stress_table(levels: tuple[int, ...], clusters: Sequence[str], repeats: int, root: Path) -> pd.DataFrame:
    """The stress suite (cases/hard/, each case a chain, every run forced) in this process as
    by default, and on each Dask cluster of `clusters`, `repeats` times each: medians of the
    wall time, the cluster's start-up (scheduler, workers, their imports) timed apart, and
    whether every summary equals the default's but for the machine's measurements."""
    rows, summaries = [], {}
    for how in (None, *clusters):
        label = f"dask {how}" if how else "default (this process)"
        layout = Layout(results=root / (how or "default").replace(":", "-"))
        start = time.perf_counter()
        with cluster(None, how) as pool:
            if pool is not None:
                pool.warm(["harness.study.hard_cases"])  # what the stress tasks run
            startup = time.perf_counter() - start
            walls, tables = [], []
            for _ in range(repeats):
                start = time.perf_counter()
                results = each(pool, lambda case: run_case(case, layout, True, levels or None),
                                         case_files([]), cost=lambda case: case_cost(case, levels or None))
                walls.append(time.perf_counter() - start)
                table = pd.DataFrame([summary_row(result) for result in results])
                measured = [c for c in table.columns if "wall" in c or "rss" in c]
                tables.append(table.drop(columns=measured).replace(str(layout.results), "<results>", regex=True))
        summaries[label] = tables
        rows.append({"executor": label, "cases": len(results), "levels": " ".join(map(str, levels)) or "the cases'",
                     "repeats": repeats, "startup_s": startup, "wall_s_median": float(np.median(walls)),
                     "wall_s_min": min(walls), "wall_s_max": max(walls),
                     "whole_s": startup + float(np.median(walls))})
    table = pd.DataFrame(rows)
    first = summaries["default (this process)"][0]
    table["summary_equal_to_default"] = [all(same_summary(first, t) for t in tables) for tables in summaries.values()]
    table["median_vs_default"] = table["wall_s_median"] / table["wall_s_median"].iloc[0]
    single = table[table["executor"] == "dask local:1"]
    if len(single):  # the single-worker time: the same cluster machinery with one worker
        table["median_vs_local_1"] = table["wall_s_median"] / single["wall_s_median"].iloc[0]
        table["whole_vs_local_1"] = table["whole_s"] / single["whole_s"].iloc[0]
    return table


