"""The one level runner: `run_levels` runs a set of levels of a scene and returns each
level's outcome, `{n: LevelOutcome}`, in one of two ways:

- a chain (the default): coarsest first, each level warm-started from the converged one
  below it (when the scene starts from `coarser`), pipelined or not; it stops at its first
  failure;
- independent levels (`chain=False`): each from the case's own start, `jobs` at a time;
  every level runs.

Meshes come from a `Mapping[int, Path]` (`BackgroundMeshes` makes them in a forked worker
while the runs go on). Independent pieces of work (whole chains, whole studies) are mapped
by `harness.study.executor.each`, the seam a Dask cluster serves.
"""

from __future__ import annotations

import math
import multiprocessing
import statistics
import sys
import tempfile
import threading
import time
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Mapping, Sequence

from harness.core import freefem, signals
from harness.core.contract import Failure
from harness.core.errors import EnvironmentFault, HarnessError, MeshError, RunError
from harness.core.layout import Layout
from harness.mesh.mesh import GMSH, build_graded_mesh, build_mesh, remove_partial_meshes
from harness.run.record import RunRecord
from harness.run.run import LevelRun, RunResult, WarmStart, read_record, run_level
from harness.scene.scene import Scene
from harness.study.progress import Progress, watching


def stderr_line(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def quiet(text: str) -> None:
    """A progress sink that says nothing."""


@dataclass(frozen=True)
class LevelOutcome:
    """One level of a study: its run, or the classified reason it failed."""

    n: int
    run: RunResult | None = None
    failure: Failure | None = None
    detail: str = ""  # the harness's one-line message for a failure
    record: RunRecord | None = None  # run.json (of the failed run, when it wrote one)
    directory: Path | None = None  # the run's directory (the failed one for a failure)
    wall_s: float = math.nan

    @property
    def ok(self) -> bool:
        return self.run is not None

    @classmethod
    def of_run(cls, run: RunResult) -> LevelOutcome:
        return cls(run.n, run, None, "", run.record, run.directory, run.record.value("wall_s"))

    @classmethod
    def of_failure(cls, n: int, exc: RunError, failed: Path, wall_s: float) -> LevelOutcome:
        return cls(n, None, exc.failure, str(exc), read_record(failed), failed, wall_s)


def runs_of(outcomes: Mapping[int, LevelOutcome]) -> dict[int, RunResult]:
    """The runs of a study whose levels all converged; the first failure's RunError otherwise."""
    failed = [o for o in outcomes.values() if not o.ok]
    if failed:
        more = f" (+{len(failed) - 1} more failed levels)" if len(failed) > 1 else ""
        raise RunError(failed[0].detail + more, failed[0].failure or Failure.OTHER)
    return {n: o.run for n, o in outcomes.items() if o.run is not None}


class BackgroundMeshes(Mapping[int, Path]):
    """Every level's mesh, made by one background process, coarsest first, while the runs go
    on: the coarse levels' runs overlap the meshing of the fine ones (at n = 64 gmsh and the
    mesh checks take 0.27 s, a tenth of the sweep). A process, not a thread: a thread
    holding the GIL in numpy delays the harness's handling of the runs (measured +0.05 s at
    n = 16); one process because gmsh is not thread-safe. Forked, so it starts in
    milliseconds with the modules already imported. Looking a level up waits for its mesh
    (and raises its MeshError)."""

    def __init__(self, scene: Scene, levels: Sequence[int], layout: Layout) -> None:
        self._pool = ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("fork"),
                                         initializer=signals.in_forked_child)
        directory = self._directory = layout.meshes_dir(scene.name)
        self._futures = {n: self._pool.submit(build_mesh, scene.geometry, n, directory) for n in sorted(levels)}
        self._workers = signals.track_pool(self._pool)

    def __getitem__(self, n: int) -> Path:
        return self._futures[n].result().path

    def ready(self, n: int) -> bool:
        """Whether level n's mesh is made (looking it up will not wait)."""
        return self._futures[n].done()

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


class InlineMeshes(Mapping[int, Path]):
    """Meshes made in this process when first looked up (a chain that may stop early does not
    mesh the levels it never reaches), graded with `grading` (mesh.build_graded_mesh); the
    seconds each took (gmsh and the checks) in `seconds`. gmsh is one library state per process
    and not thread-safe: meshes of chains run side by side in threads are made one at a time."""

    _gmsh = GMSH  # per process, as gmsh's own state is

    def __init__(self, scene: Scene, levels: Sequence[int], layout: Layout, grading: float = 1.0) -> None:
        self._scene, self._levels, self._layout, self._grading = scene, sorted(set(levels)), layout, grading
        self._made: dict[int, Path] = {}
        self.seconds: dict[int, float] = {}

    def __getitem__(self, n: int) -> Path:
        if n not in self._levels:
            raise KeyError(n)
        if n not in self._made:
            with self._gmsh:
                start = time.perf_counter()
                directory = self._layout.meshes_dir(self._scene.name)
                self._made[n] = build_graded_mesh(self._scene.geometry, n, directory, self._grading)
                self.seconds[n] = time.perf_counter() - start
        return self._made[n]

    def __iter__(self) -> Iterator[int]:
        return iter(self._levels)

    def __len__(self) -> int:
        return len(self._levels)

    def made(self) -> InlineMeshes:
        """Every level meshed now (its time measured alone, not inside a run)."""
        for n in self._levels:
            self[n]
        return self


def run_levels(
    scene: Scene,
    meshes: Mapping[int, Path],
    layout: Layout,
    *,
    force: bool = False,
    progress: Progress = stderr_line,
    chain: bool = True,
    pipelined: bool = True,
    warm: WarmStart | None = None,
    jobs: int = 1,
) -> dict[int, LevelOutcome]:
    """Every level of `meshes`: a chain (`warm` its first level's start, `pipelined` as
    `_chain` says), or with `chain=False` independent levels, `jobs` at a time."""
    if chain:
        return _chain(scene, meshes, layout, force, progress, pipelined, warm)
    return _independent(scene, meshes, layout, jobs, force, progress)


def _independent(
    scene: Scene,
    meshes: Mapping[int, Path],
    layout: Layout,
    jobs: int,
    force: bool,
    progress: Progress,
) -> dict[int, LevelOutcome]:
    """Every level from the case's own start, `jobs` at a time, largest first (the finest
    level dominates the wall time). Every level runs; failures are outcomes."""
    outcomes: dict[int, LevelOutcome] = {}
    freefem.warm_import("meshio")  # read after each run (solution.vtu)
    with ThreadPoolExecutor(max_workers=max(1, jobs)) as pool:
        # The mesh is looked up in the worker, which waits for it there.
        futures = {pool.submit(_attempt, scene, meshes, n, layout, force): n
                   for n in sorted(meshes, reverse=True)}
        for count, future in enumerate(as_completed(futures), start=1):
            outcome = future.result()
            outcomes[outcome.n] = outcome
            progress(f"[{count}/{len(meshes)}] n={outcome.n} {_describe(outcome)}")
    return dict(sorted(outcomes.items()))


def _attempt(scene: Scene, meshes: Mapping[int, Path], n: int, layout: Layout, force: bool) -> LevelOutcome:
    """One level run alone from the case's own start, its failure classified."""
    start = time.perf_counter()
    try:
        return LevelOutcome.of_run(run_level(scene, meshes[n], n, layout, force))
    except RunError as exc:
        return LevelOutcome.of_failure(n, exc, layout.failed_dir(scene.name, n), time.perf_counter() - start)


def _chain(
    scene: Scene,
    meshes: Mapping[int, Path],
    layout: Layout,
    force: bool,
    progress: Progress,
    pipelined: bool,
    warm: WarmStart | None,
) -> dict[int, LevelOutcome]:
    """Coarsest first, each level started from the one below it (from `warm` for the first,
    or the case's own start); it stops at the first failure, which is the last outcome.
    A scene that does not start from `coarser` runs the same levels one by one, each from
    its own start.

    Pipelined (the default): while a level runs, the next one is already started (its
    compilation, meshes and bulk assembly, freefem/bulk.idp) and waits for this level's
    state: on two cores that setup leaves the critical path. The finest level, the one
    that costs most to set up, is started with the coarsest (issue 13, item 6: its setup
    overlaps the whole chain below it, not only the level next to it). Off for timing a
    level alone."""
    outcomes: dict[int, LevelOutcome] = {}
    levels = sorted(meshes)
    chained = scene.initial_guess == "coarser"  # any other start ignores the level below
    current: LevelRun | None = None
    following: LevelRun | None = None
    finest: LevelRun | None = None
    try:
        # Not when the finest level has a result already: it is most likely reused, and a
        # FreeFEM started for nothing costs a start-up.
        top = levels[-1]
        early = pipelined and chained and len(levels) > 2 and (force or not layout.level_dir(scene.name, top).exists())
        for count, n in enumerate(levels, start=1):
            began = time.perf_counter()
            current = current or LevelRun(scene, meshes[n], n, layout, force)
            try:
                cached = current.start(warm if chained else None)
                if early and finest is None and count < len(levels) - 1 and _mesh_ready(meshes, top):
                    finest = _launched_early(scene, meshes, top, levels[-2], layout, force)
                    early = finest is not None
                if count == len(levels):
                    freefem.warm_import("meshio")  # read after the run (solution.vtu)
                ahead: HarnessError | None = None
                if count < len(levels):
                    try:
                        if count == len(levels) - 1 and finest is not None:
                            following, finest = finest, None  # launched with the coarsest
                        else:
                            following = LevelRun(scene, meshes[levels[count]], levels[count], layout, force)
                            if pipelined and chained and cached is None:
                                following.launch_early(meshes[n])
                    except (MeshError, EnvironmentFault) as exc:
                        # The next level's mesh or launch failed while this level runs: this
                        # level's own failure, if any, comes first (failures in level order).
                        ahead = exc
                run = cached or _waited(current, f"[{count}/{len(levels)}] n={n}", progress)
                if ahead is not None:
                    raise ahead
            except RunError as exc:
                outcomes[n] = LevelOutcome.of_failure(n, exc, layout.failed_dir(scene.name, n),
                                                      time.perf_counter() - began)
                progress(f"[{count}/{len(levels)}] n={n} FAILED")
                break
            outcomes[n] = LevelOutcome.of_run(run)
            progress(f"[{count}/{len(levels)}] n={n} {_describe(outcomes[n])}")
            warm = run.warm_start(meshes[n])
            current, following = following, None
    finally:
        for level in (current, following, finest):
            if level is not None:
                level.abandon()
    return outcomes


def _waited(level: LevelRun, label: str, progress: Progress) -> RunResult:
    """The level's run, waited for; while it is long, its Newton steps and its process's CPU
    time and memory are said (harness/study/progress.py): 3D h = 1/64 runs for many minutes."""
    launched = level.launched
    stdout = level.work / "stdout.txt" if level.work is not None else None
    with watching(stdout, launched.proc.pid if launched is not None else None, label, progress):
        return level.wait()


def _mesh_ready(meshes: Mapping[int, Path], n: int) -> bool:
    """Whether looking level n's mesh up would not wait (a background mesher may still run)."""
    ready = getattr(meshes, "ready", None)
    return ready(n) if callable(ready) else True


def _launched_early(scene: Scene, meshes: Mapping[int, Path], n: int, coarser: int, layout: Layout,
                   force: bool) -> LevelRun | None:
    """Level n's FreeFEM, started now to wait for the state of level `coarser`; None when its
    mesh or launch fails (the chain meets that failure again in its turn, in level order)."""
    try:
        level = LevelRun(scene, meshes[n], n, layout, force)
    except (MeshError, EnvironmentFault):
        return None
    try:
        level.launch_early(meshes[coarser])
    except (MeshError, EnvironmentFault):
        level.abandon()
        return None
    return level


def _describe(outcome: LevelOutcome) -> str:
    if not outcome.ok:
        return "FAILED"
    run = outcome.run
    assert run is not None
    its = run.record.newton_iterations
    if run.reused:
        return f"reused (inputs unchanged), {its} Newton its"
    return f"done in {run.record.value('wall_s'):.1f} s, {its} Newton its"


def timed_meshes(scene: Scene, levels: Sequence[int], layout: Layout,
                 grading: float = 1.0) -> tuple[dict[int, Path], dict[int, float]]:
    """Each level's mesh, made here now, and the seconds it took (gmsh and the checks)."""
    meshes = InlineMeshes(scene, levels, layout, grading).made()
    return dict(meshes.items()), dict(meshes.seconds)


def freefem_startup_s(repeats: int = 5) -> float:
    """Median wall time of FreeFEM running an empty script, as the harness invokes it."""
    times = []
    with tempfile.TemporaryDirectory(prefix="ff-startup-") as tmp:
        script = Path(tmp) / "empty.edp"
        script.write_text("real nothing = 0;\n")
        for _ in range(repeats):
            outcome = freefem.invoke(freefem.command(script, []), Path(tmp), timeout_s=60)
            if outcome.returncode != 0:
                raise RunError(f"FreeFEM does not run an empty script (exit code {outcome.returncode})")
            times.append(outcome.wall_s)
    return statistics.median(times)
