"""A convergence study: the levels (harness/study/engine.py), E^h against the finest level, rates."""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, field
from typing import Mapping

import pandas as pd

from harness.scene.cell_size import h_max, thin_warnings
from harness.study.engine import BackgroundMeshes, Progress, run_levels, runs_of, stderr_line
from harness.measure.fields import Fields, read_fields
from harness.core.freefem import freefem_version
from harness.core.layout import Layout
from harness.measure.norm_table import FIELD_NAMES, TOTAL, error_column, error_names
from harness.measure.norms import error_norms
from harness.measure.rates import fitted_slope, pairwise_orders
from harness.run.run import RunResult, check_solver_files
from harness.scene.scene import Scene


@dataclass(frozen=True)
class Study:
    scene: Scene
    fields: tuple[str, ...]
    table: pd.DataFrame  # one row per level, the reference last with blank errors
    slopes: dict[str, dict[str, float]]  # field or "total" -> {"all": p, "window": p}
    runs: dict[int, RunResult]
    wall_s: float
    # Each level's solution.vtu, parsed once for the errors and reused by the checks.
    solutions: dict[int, Fields] = field(default_factory=dict, repr=False, compare=False)
    # Levels too coarse for a body's thinnest section (harness/scene/cell_size.py), one line each.
    warnings: tuple[str, ...] = ()

    @property
    def reference(self) -> int:
        return max(self.runs)

    @property
    def total_slope(self) -> float:
        """The slope the verdict is about: E_total fitted over every non-reference level."""
        return self.slopes["total"]["all"]

    @property
    def passed(self) -> bool:
        low, high = self.scene.slope_band
        return low <= self.total_slope <= high


def run_study(
    scene: Scene,
    levels: tuple[int, ...],
    layout: Layout,
    jobs: int,
    force: bool = False,
    progress: Progress = stderr_line,
) -> Study:
    """Every level (engine.run_levels: a chain when the case starts from `coarser`, else
    independent levels), then the errors against the finest and the
    slopes; a RunError naming the first failed level if any failed."""
    levels = tuple(sorted(set(levels)))
    check_solver_files(scene, layout)
    freefem_version()  # asked once here, not by every worker thread at once
    start = time.perf_counter()
    with BackgroundMeshes(scene, levels, layout) as meshes:
        runs = runs_of(run_levels(scene, meshes, layout, force=force, progress=progress,
                                  chain=scene.initial_guess == "coarser", jobs=jobs))
    fields = tuple(f for f in FIELD_NAMES if f in (runs[levels[-1]].record.fields or FIELD_NAMES))
    solutions = {n: read_fields(run.solution) for n, run in runs.items()}
    table = error_table(runs, fields, solutions)
    warnings = tuple(line for n, f in sorted(solutions.items())
                     for line in thin_warnings(scene.geometry.body_parts(), n, f.points, f.cells))
    for line in warnings:
        print(f"warning: {line}", file=sys.stderr, flush=True)
    return Study(scene, fields, table, slopes(table, fields), runs, time.perf_counter() - start, solutions, warnings)


def error_table(runs: dict[int, RunResult], fields: tuple[str, ...],
                solutions: Mapping[int, Fields] | None = None) -> pd.DataFrame:
    """Each level's errors against the finest (`solutions`: the levels' parsed fields, read
    from their solution.vtu when not given)."""
    levels = sorted(runs)
    parsed = solutions or {n: read_fields(runs[n].solution) for n in levels}
    reference = parsed[levels[-1]]
    rows = []
    for n in levels:
        record = runs[n].record
        errors = (
            error_norms(parsed[n], reference, list(fields))
            if n != levels[-1]
            else dict.fromkeys(fields, math.nan)
        )
        row = {
            "n": n,
            "h": 1.0 / n,
            "h_max": h_max(parsed[n].points, parsed[n].cells),  # the real largest cell, in model units
            "dofs": record.dofs,
            "newton_iterations": record.newton_iterations,
            "wall_s": record.wall_s,
        }
        row.update({error_column(f): errors[f] for f in fields})
        row[error_column(TOTAL)] = sum(errors.values())
        rows.append(row)
    table = pd.DataFrame(rows)
    for name in error_names(fields):
        table[f"order_{name}"] = pairwise_orders(table["h"], table[error_column(name)])
    return table


def slopes(table: pd.DataFrame, fields: tuple[str, ...]) -> dict[str, dict[str, float]]:
    """Fits over every non-reference level, and over a window that also leaves out the level
    next to the reference (whose error is polluted by the reference's own error)."""
    graded = table.iloc[:-1]
    window = graded.iloc[:-1]
    return {
        name: {
            "all": fitted_slope(graded["h"], graded[error_column(name)]),
            "window": fitted_slope(window["h"], window[error_column(name)]),
        }
        for name in error_names(fields)
    }
