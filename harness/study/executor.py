"""Where a study's independent pieces of work run: one after another in this process
(default), or side by side on a Dask `distributed` cluster.

`each(pool, fn, items)` is the one independent-work map: a study hands it whole pieces (a
scene's study, a stress case's chain, a branch's start), each run by the one level runner
(harness/study/engine.py) where it lands. Results land in the results directory, which the
workers must reach by the same path (a shared file system on a cluster); each level is
swapped in atomically (harness/run/run.py), so two workers finishing at once, or a task rerun
after its worker died, leave one complete result.

  cluster(scheduler, local)    None (this process) without either; else a DaskExecutor on
                               the scheduler at tcp://host:port, or on a local cluster of
                               N worker processes ("local:N")

Dask is imported only here and only for a cluster (the `cluster` extra of pyproject.toml).
"""

from __future__ import annotations

import contextlib
import importlib
from typing import Any, Callable, Iterator, Protocol, Sequence, TypeVar

from harness.core.errors import EnvironmentFault, RunError, SceneError

T = TypeVar("T")


class Pool(Protocol):
    """What `each` needs of a pool: concurrent.futures' submit (a DaskExecutor, a thread pool)."""

    def submit(self, fn: Callable[..., Any], *args: Any) -> Any: ...


def preload(modules: Sequence[str]) -> None:
    """Import `modules` by name (run on every worker by DaskExecutor.warm)."""
    for name in modules:
        importlib.import_module(name)


class DaskExecutor:
    """A Dask `distributed` client; `submit` is concurrent.futures' (each's seam). A task whose
    worker dies is rerun elsewhere by the scheduler (up to its `allowed-failures`); past that
    `each` fails with a clear line."""

    def __init__(self, client: Any) -> None:
        self.client = client

    def warm(self, modules: Sequence[str]) -> None:
        """Every worker imports `modules` now (the caller names what its tasks need), so that
        a timed study does not pay a fresh worker's imports (about a second each) in its
        first tasks."""
        self.client.run(preload, list(modules))

    def submit(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> Any:
        """A Dask future, whose result() raises the task's own exception."""
        return self.client.submit(fn, *args, pure=False, **kwargs)


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
    if scheduler is not None:
        try:
            client = Client(scheduler_address(scheduler), timeout="20s")
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


# distributed.comm's address schemes that reach a scheduler in another process ("inproc"
# is one process's own).
SCHEDULER_SCHEMES = ("tcp", "tls", "ucx", "ws", "wss")


def scheduler_address(text: str) -> str:
    """A Dask scheduler's SCHEME://HOST:PORT, checked before anything runs: Dask itself
    raised a ValueError deep in a study for one without a scheme or port."""
    scheme, sep, rest = text.strip().partition("://")
    host, colon, port = rest.rpartition(":")
    if not (sep and scheme in SCHEDULER_SCHEMES and host and colon and port.isdigit() and 0 < int(port) < 65536):
        raise SceneError(f"{text!r} is not a Dask scheduler's address: expected SCHEME://HOST:PORT with SCHEME "
                         f"one of {', '.join(SCHEDULER_SCHEMES)} (e.g. tcp://10.0.0.5:8786)")
    return text.strip()


def parse_cluster(text: str) -> int:
    kind, _, count = text.partition(":")
    if kind != "local" or not count.isdigit() or int(count) < 1:
        raise SceneError(f"{text!r} is not a local cluster: expected local:N with N >= 1 worker processes")
    return int(count)


@contextlib.contextmanager
def cluster(scheduler: str | None = None, local: str | None = None) -> Iterator[DaskExecutor | None]:
    """The pool a study's --scheduler / --cluster ask for; None (this process) when neither
    is given."""
    if scheduler is not None and local is not None:
        raise SceneError("give --scheduler or --cluster, not both")
    if scheduler is None and local is None:
        yield None
        return
    if scheduler is not None:  # an empty one is refused, not taken for "no cluster"
        scheduler = scheduler_address(scheduler)
    with connect(scheduler, local) as dask:
        yield dask


def each(pool: Pool | None, fn: Callable[..., T], items: Sequence[Any],
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
