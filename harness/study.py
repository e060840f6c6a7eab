"""A convergence study: meshes, parallel FreeFEM runs, E^h against the finest level, rates."""

from __future__ import annotations

import math
import multiprocessing
import sys
import time
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator, Mapping

import pandas as pd

from harness import signals
from harness.errors import RunError
from harness.fields import read_fields
from harness.freefem import freefem_version
from harness.layout import Layout
from harness.mesh import build_mesh, remove_partial_meshes
from harness.norms import error_norms
from harness.rates import fitted_slope, pairwise_orders
from harness.run import LevelRun, RunResult, WarmStart, check_solver_files, run_level
from harness.scene import Scene

# Fields the error measure knows, in the order docs/model.md section 7 sums them (V, W, Q).
NORMED_FIELDS = ("u", "phi", "theta")


@dataclass(frozen=True)
class Study:
    scene: Scene
    fields: tuple[str, ...]
    table: pd.DataFrame  # one row per level, the reference last with blank errors
    slopes: dict[str, dict[str, float]]  # field or "total" -> {"all": p, "window": p}
    runs: dict[int, RunResult]
    wall_s: float

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


def stderr_line(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def run_study(
    scene: Scene,
    levels: tuple[int, ...],
    layout: Layout,
    jobs: int,
    force: bool = False,
    progress: Callable[[str], None] = stderr_line,
) -> Study:
    levels = tuple(sorted(set(levels)))
    if len(levels) < 2:
        raise RunError("a convergence study needs at least two levels (the finest is the reference)")
    check_solver_files(scene, layout)
    freefem_version()  # asked once here, not by every worker thread at once
    start = time.perf_counter()
    with BackgroundMeshes(scene, levels, layout) as meshes:
        runs = run_all(scene, meshes, layout, jobs, force, progress)
    fields = tuple(f for f in NORMED_FIELDS if f in runs[levels[-1]].record.get("fields", NORMED_FIELDS))
    table = error_table(runs, fields)
    return Study(scene, fields, table, slopes(table, fields), runs, time.perf_counter() - start)


class BackgroundMeshes(Mapping[int, Path]):
    """Every level's mesh, made by one background process, coarsest first, while the runs go
    on: the coarse levels' runs overlap the meshing of the fine ones (at n = 64 gmsh and the
    mesh checks take 0.27 s, a tenth of the sweep). A process, not a thread: a thread
    holding the GIL in numpy delays the harness's handling of the runs (measured +0.05 s at
    n = 16); one process because gmsh is not thread-safe. Forked, so it starts in
    milliseconds with the modules already imported. Looking a level up waits for its mesh
    (and raises its MeshError)."""

    def __init__(self, scene: Scene, levels: tuple[int, ...], layout: Layout) -> None:
        self._pool = ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("fork"),
                                         initializer=signals.in_forked_child)
        directory = self._directory = layout.meshes_dir(scene.name)
        self._futures = {n: self._pool.submit(build_mesh, scene.geometry, n, directory) for n in sorted(levels)}
        self._workers = signals.track_pool(self._pool)

    def __getitem__(self, n: int) -> Path:
        return self._futures[n].result().path

    def __iter__(self) -> Iterator[int]:
        return iter(self._futures)

    def __len__(self) -> int:
        return len(self._futures)

    def __enter__(self) -> BackgroundMeshes:
        return self

    def __exit__(self, kind: type | None, *exc: object) -> None:
        if kind is not None:  # a failure or a signal: do not wait for meshes nobody will use
            signals.end_pool(self._workers)
        self._pool.shutdown(wait=True, cancel_futures=True)
        if kind is not None:
            remove_partial_meshes(self._directory, self._workers)
        signals.untrack_pool(self._workers)


def run_all(
    scene: Scene,
    meshes: Mapping[int, Path],
    layout: Layout,
    jobs: int,
    force: bool,
    progress: Callable[[str], None],
) -> dict[int, RunResult]:
    if scene.initial_guess == "coarser":
        return run_chain(scene, meshes, layout, force, progress)
    runs: dict[int, RunResult] = {}
    failures: list[str] = []
    with ThreadPoolExecutor(max_workers=max(1, jobs)) as pool:
        # Largest first: the finest level dominates the sweep's wall time.
        futures = {
            # The mesh is looked up in the worker, which waits for it there.
            pool.submit(lambda n=n: run_level(scene, meshes[n], n, layout, force)): n
            for n in sorted(meshes, reverse=True)
        }
        for count, future in enumerate(as_completed(futures), start=1):
            n = futures[future]
            try:
                runs[n] = future.result()
            except RunError as exc:
                failures.append(str(exc))
                progress(f"[{count}/{len(meshes)}] n={n} FAILED")
                continue
            progress(f"[{count}/{len(meshes)}] n={n} {describe(runs[n])}")
    if failures:
        more = f" (+{len(failures) - 1} more failed levels)" if len(failures) > 1 else ""
        raise RunError(failures[0] + more)
    return runs


def run_chain(
    scene: Scene,
    meshes: Mapping[int, Path],
    layout: Layout,
    force: bool,
    progress: Callable[[str], None],
    pipelined: bool = True,
) -> dict[int, RunResult]:
    """Coarsest first, each level started from the one below it: one branch, few iterations.

    Pipelined (the default): while a level runs, the next one is already started (its
    compilation, meshes and bulk assembly, freefem/bulk.idp) and waits for this level's
    state: on two cores that setup leaves the critical path. Off for timing a level alone."""
    runs: dict[int, RunResult] = {}
    levels = sorted(meshes)
    warm: WarmStart | None = None
    current = LevelRun(scene, meshes[levels[0]], levels[0], layout, force)
    following: LevelRun | None = None
    try:
        for count, n in enumerate(levels, start=1):
            cached = current.start(warm)
            if count < len(levels):
                following = LevelRun(scene, meshes[levels[count]], levels[count], layout, force)
                if pipelined and cached is None:
                    following.launch_early(meshes[n])
            try:
                runs[n] = cached or current.wait()
            except RunError:
                progress(f"[{count}/{len(levels)}] n={n} FAILED")
                raise
            progress(f"[{count}/{len(levels)}] n={n} {describe(runs[n])}")
            warm = runs[n].warm_start(meshes[n])
            current, following = following, None  # type: ignore[assignment]
    finally:
        for level in (current, following):
            if level is not None:
                level.abandon()
    return runs


def describe(run: RunResult) -> str:
    its = run.record.get("newton_iterations", "?")
    if run.reused:
        return f"reused (inputs unchanged), {its} Newton its"
    return f"done in {run.record.get('wall_s', math.nan):.1f} s, {its} Newton its"


def error_table(runs: dict[int, RunResult], fields: tuple[str, ...]) -> pd.DataFrame:
    levels = sorted(runs)
    reference = read_fields(runs[levels[-1]].solution)
    rows = []
    for n in levels:
        record = runs[n].record
        errors = (
            error_norms(read_fields(runs[n].solution), reference, list(fields))
            if n != levels[-1]
            else dict.fromkeys(fields, math.nan)
        )
        row = {
            "n": n,
            "h": 1.0 / n,
            "dofs": record.get("dofs"),
            "newton_iterations": record.get("newton_iterations"),
            "wall_s": record.get("wall_s"),
        }
        row.update({f"err_{f}": errors[f] for f in fields})
        row["err_total"] = sum(errors.values())
        rows.append(row)
    table = pd.DataFrame(rows)
    for name in (*fields, "total"):
        table[f"order_{name}"] = pairwise_orders(table["h"], table[f"err_{name}"])
    return table


def slopes(table: pd.DataFrame, fields: tuple[str, ...]) -> dict[str, dict[str, float]]:
    """Fits over every non-reference level, and over a window that also leaves out the level
    next to the reference (whose error is polluted by the reference's own error)."""
    graded = table.iloc[:-1]
    window = graded.iloc[:-1]
    return {
        name: {
            "all": fitted_slope(graded["h"], graded[f"err_{name}"]),
            "window": fitted_slope(window["h"], window[f"err_{name}"]),
        }
        for name in (*fields, "total")
    }
