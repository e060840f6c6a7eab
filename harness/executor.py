"""Where a study's runs execute: the local process (default) or a Dask `distributed` cluster.

A study hands over chains: the levels of one scene, warm-started each from the one below
it when the scene starts from `coarser`, else independent. Every level is a task (its
mesh another); a warm-started level depends on the coarser level's task, so a chain is a
chain of dependencies and independent chains (scenes, stress cases, branches) run side
by side across the workers. Results land in the results directory, which the workers
must reach by the same path (a shared file system on a cluster); each level is swapped
in atomically (harness/run.py), so two workers finishing at once, or a task rerun after
its worker died, leave one complete result.

  LocalExecutor(jobs)          chains side by side in threads, each as harness/study.py
                               runs it (pipelined warm starts, meshes in the background)
  DaskExecutor(client)         chains as Dask task graphs; `connect("tcp://host:port")`
                               or `connect(cluster="local:N")` for N local worker processes

Dask is imported only here and only for a cluster (the `cluster` extra of pyproject.toml).
"""

from __future__ import annotations

import contextlib
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Protocol, Sequence, TypeVar

from harness.errors import EnvironmentFault, RunError, SceneError
from harness.layout import Layout
from harness.mesh import build_mesh
from harness.run import RunResult, run_level
from harness.scene import Scene

Progress = Callable[[str], None]
T = TypeVar("T")


@dataclass(frozen=True)
class LevelChain:
    """The levels of one scene to run, warm-started when the scene says `coarser`."""

    scene: Scene
    levels: tuple[int, ...]
    layout: Layout
    force: bool = False

    @property
    def warm(self) -> bool:
        return self.scene.initial_guess == "coarser"


@dataclass
class ChainOutcome:
    chain: LevelChain
    runs: dict[int, RunResult] = field(default_factory=dict)
    error: str | None = None  # the first failure; the levels after it in a warm chain did not run


class Executor(Protocol):
    """Both grains of work: `map` runs independent pieces (a whole chain each, the study
    engine's seam) and returns their results in order; `run` takes chains of levels and
    makes every level its own task."""

    def map(self, work: Sequence[Callable[[], T]]) -> list[T]: ...

    def run(self, chains: Sequence[LevelChain], progress: Progress) -> list[ChainOutcome]: ...


def quiet(_: str) -> None:
    pass


class LocalExecutor:
    """This machine: chains side by side (at most `jobs` at once), each run as the study
    engine runs one scene (harness/study.py's run_all: pipelined chains, level threads)."""

    def __init__(self, jobs: int) -> None:
        self.jobs = max(1, jobs)

    def map(self, work: Sequence[Callable[[], T]]) -> list[T]:
        with ThreadPoolExecutor(max_workers=min(self.jobs, max(1, len(work)))) as pool:
            return list(pool.map(lambda piece: piece(), work))

    def run(self, chains: Sequence[LevelChain], progress: Progress = quiet) -> list[ChainOutcome]:
        with ThreadPoolExecutor(max_workers=min(self.jobs, max(1, len(chains)))) as pool:
            return list(pool.map(lambda c: self._one(c, progress), chains))

    def _one(self, chain: LevelChain, progress: Progress) -> ChainOutcome:
        from harness.engine import BackgroundMeshes, study_outcomes

        outcome = ChainOutcome(chain)
        tag = f"{chain.scene.name}: "
        with BackgroundMeshes(chain.scene, chain.levels, chain.layout) as meshes:
            levels = study_outcomes(chain.scene, meshes, chain.layout, self.jobs, chain.force,
                                    lambda line: progress(tag + line))
        outcome.runs = {n: o.run for n, o in levels.items() if o.run is not None}
        failed = [o.detail for o in levels.values() if not o.ok]
        outcome.error = failed[0] if failed else None
        return outcome


# ---- Dask: module-level task functions (a worker imports them by name) ----

def mesh_task(scene: Scene, n: int, layout: Layout) -> Path:
    return build_mesh(scene.geometry, n, layout.meshes_dir(scene.name)).path


def level_task(scene: Scene, mesh: Path, n: int, layout: Layout, force: bool,
               coarser: RunResult | None = None, coarser_mesh: Path | None = None) -> RunResult:
    warm = coarser.warm_start(coarser_mesh) if coarser is not None and coarser_mesh is not None else None
    return run_level(scene, mesh, n, layout, force, warm)


def import_harness() -> None:
    """What a study task needs loaded (the stress study pulls in the whole harness)."""
    import harness.studies.stress  # noqa: F401


class DaskExecutor:
    """A Dask `distributed` client: one task per mesh and per level, a warm-started level
    depending on its coarser level. A task whose worker dies is rerun elsewhere by the
    scheduler (up to its `allowed-failures`); past that the level fails with a clear line."""

    def __init__(self, client: Any) -> None:
        self.client = client

    def warm(self) -> None:
        """Every worker imports the harness now, so that a timed study does not pay a fresh
        worker's imports (about a second each) in its first tasks."""
        self.client.run(import_harness)

    def submit(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> Any:
        """concurrent.futures' submit (engine.run_chains' seam): a Dask future, whose
        result() raises the task's own exception."""
        return self.client.submit(fn, *args, pure=False, **kwargs)

    def map(self, work: Sequence[Callable[[], T]]) -> list[T]:
        """Each piece a task (cloudpickled closures; what they name must import on a worker).
        A piece's own HarnessError comes back as raised; a worker lost for good is a RunError."""
        futures = [self.client.submit(piece, pure=False) for piece in work]
        try:
            return list(self.client.gather(futures))
        except (RunError, SceneError, EnvironmentFault):
            raise
        except Exception as exc:  # KilledWorker, a cancelled task: the cluster's, not the run's
            raise RunError(f"a Dask task failed: {type(exc).__name__}: {exc}") from None

    def run(self, chains: Sequence[LevelChain], progress: Progress = quiet) -> list[ChainOutcome]:
        from distributed import as_completed

        submitted: dict[Any, tuple[int, int]] = {}  # run future -> (chain index, level)
        for index, chain in enumerate(chains):
            coarser: Any = None
            coarser_mesh: Any = None
            for n in sorted(set(chain.levels)):
                mesh = self.client.submit(mesh_task, chain.scene, n, chain.layout, pure=False,
                                          key=f"mesh-{chain.scene.name}-n{n}-{index}")
                run = self.client.submit(level_task, chain.scene, mesh, n, chain.layout, chain.force,
                                         coarser if chain.warm else None, coarser_mesh if chain.warm else None,
                                         pure=False, key=f"level-{chain.scene.name}-n{n}-{index}")
                submitted[run] = (index, n)
                coarser, coarser_mesh = run, mesh
        outcomes = [ChainOutcome(chain) for chain in chains]
        total = len(submitted)
        for count, future in enumerate(as_completed(list(submitted)), start=1):
            index, n = submitted[future]
            outcome = outcomes[index]
            try:
                result: RunResult = future.result()
            except (RunError, SceneError, EnvironmentFault) as exc:
                outcome.error = outcome.error or str(exc)
                progress(f"[{count}/{total}] {outcome.chain.scene.name} n={n} FAILED")
                continue
            except Exception as exc:  # a worker lost for good (KilledWorker), a cancelled task
                outcome.error = outcome.error or f"{outcome.chain.scene.name} n={n}: the Dask task failed: " \
                                                 f"{type(exc).__name__}: {exc}"
                progress(f"[{count}/{total}] {outcome.chain.scene.name} n={n} FAILED")
                continue
            outcome.runs[n] = result
            state = "reused" if result.reused else f"done in {result.record.value('wall_s'):.1f} s"
            progress(f"[{count}/{total}] {outcome.chain.scene.name} n={n} {state} (Dask)")
        return outcomes


@contextlib.contextmanager
def connect(scheduler: str | None = None, cluster: str | None = None) -> Iterator[DaskExecutor]:
    """A DaskExecutor on the scheduler at `scheduler` (tcp://host:port) or on a local cluster
    `cluster` = "local:N" (a real scheduler with N single-threaded worker processes)."""
    try:
        import dask
        from distributed import Client, LocalCluster
    except ImportError:
        raise EnvironmentFault("a Dask cluster needs dask and distributed (pip install -e '.[cluster]'; "
                               "`make test` installs them)") from None
    if scheduler:
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as exc:
            raise EnvironmentFault(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
        with client:
            yield DaskExecutor(client)
        return
    workers = parse_cluster(cluster or "")
    # Non-daemonic worker processes: a study task makes its meshes in a forked process
    # (engine.BackgroundMeshes), which a daemonic process may not start. Workers of another
    # scheduler need the same (DASK_DISTRIBUTED__WORKER__DAEMON=False, see docs/scale-out.md).
    # The workers' statistical profiler off: it samples every thread's stack every 10 ms,
    # CPU taken from the FreeFEM runs on a machine whose cores the workers already fill.
    with dask.config.set({"distributed.worker.daemon": False, "distributed.worker.profile.enabled": False}), \
            LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                         dashboard_address=":0") as local, Client(local) as client:  # any free port
        yield DaskExecutor(client)


def parse_cluster(text: str) -> int:
    kind, _, count = text.partition(":")
    if kind != "local" or not count.isdigit() or int(count) < 1:
        raise SceneError(f"--cluster {text!r}: expected local:N with N >= 1 worker processes")
    return int(count)


@contextlib.contextmanager
def executor(jobs: int, scheduler: str | None = None, cluster: str | None = None) -> Iterator[Executor]:
    """The executor a study's flags choose: --scheduler or --cluster, else this machine."""
    if scheduler and cluster:
        raise SceneError("give --scheduler or --cluster, not both")
    if scheduler or cluster:
        with connect(scheduler, cluster) as dask:
            yield dask
    else:
        yield LocalExecutor(jobs)


def add_arguments(parser: Any) -> None:
    """--scheduler / --cluster for a study whose independent chains can run on a cluster."""
    parser.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                        help="run the study's chains on this Dask scheduler (workers share the results path)")
    parser.add_argument("--cluster", metavar="local:N",
                        help="run them on a local Dask cluster of N worker processes")


@contextlib.contextmanager
def from_args(args: Any) -> Iterator[DaskExecutor | None]:
    """The cluster a study's --scheduler / --cluster ask for; None (this process, as
    without them) when neither is given."""
    scheduler, cluster = getattr(args, "scheduler", None), getattr(args, "cluster", None)
    if scheduler and cluster:
        raise SceneError("give --scheduler or --cluster, not both")
    if not (scheduler or cluster):
        yield None
        return
    with connect(scheduler, cluster) as dask:
        yield dask


def each(pool: DaskExecutor | None, fn: Callable[..., T], items: Sequence[Any],
         cost: Callable[[Any], float] | None = None) -> list[T]:
    """fn(item) for every item, results in order: side by side on the cluster, else one after
    another. With `cost` (an estimate of an item's work) the cluster gets the costliest first
    (longest processing time first), so that no long task starts last and runs alone."""
    if pool is None:
        return [fn(item) for item in items]
    order = sorted(range(len(items)), key=lambda i: -cost(items[i])) if cost else range(len(items))
    submitted = {i: pool.submit(fn, items[i]) for i in order}
    futures = [submitted[i] for i in range(len(items))]
    try:
        return [future.result() for future in futures]
    except (RunError, SceneError, EnvironmentFault):
        raise
    except Exception as exc:  # KilledWorker, a cancelled task: the cluster's, not the run's
        raise RunError(f"a Dask task failed: {type(exc).__name__}: {exc}") from None
