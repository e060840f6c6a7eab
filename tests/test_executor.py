"""Studies on a real local Dask cluster (2 worker processes) against this machine: the same
tables for levels 2-8 of two scenes, and a worker killed mid-study still ends complete and
correct or with a clear error."""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

import pytest

from harness.study.engine import BackgroundMeshes, quiet, run_levels, runs_of
from harness.core.errors import RunError, SceneError
from harness.study.executor import cluster, each, parse_cluster
from harness.core.layout import Layout
from harness.run.run import RunResult
from harness.scene.scene import Scene, load_scene
from harness.study.study import error_table

pytest.importorskip("distributed", reason="dask/distributed missing (the 'cluster' extra; `make test` installs it)")

CASES = Path(__file__).parents[1] / "cases"
SCENES = ("paper", "elastic")
LEVELS = (2, 4, 8)


def scenes() -> list[Scene]:
    return [load_scene(CASES / f"{name}.toml") for name in SCENES]


def chain_runs(scene: Scene, layout: Layout, levels: tuple[int, ...] = LEVELS,
               force: bool = False) -> tuple[int, dict[int, RunResult]]:
    """One scene's levels as a study runs them (meshes in the background), and the pid of the
    process that ran them."""
    with BackgroundMeshes(scene, levels, layout) as meshes:
        outcomes = run_levels(scene, meshes, layout, force=force, progress=quiet,
                              chain=scene.initial_guess == "coarser")
    return os.getpid(), runs_of(outcomes)


def study(pool, results: Path) -> tuple[set[int], dict[str, dict[int, RunResult]]]:
    """Every scene's chain through `pool` (None: this process): the pids that ran them, the runs."""
    layout = Layout(results=results)
    done = each(pool, lambda scene: chain_runs(scene, layout), scenes())
    return {pid for pid, _ in done}, {name: runs for name, (_, runs) in zip(SCENES, done)}


def tables(runs: dict[str, dict[int, RunResult]]) -> dict[str, str]:
    """Each scene's study table as the study writes its CSV (report.py: 10 significant
    digits), less the wall times (which no two runs share). Full precision would compare
    round-off: a pipelined and a non-pipelined run of one level differ by ~1e-14 relative
    (measured: longcontact n = 16), presumably the sparse solver's alignment-dependent
    kernels."""
    out = {}
    for name, levels in runs.items():
        assert sorted(levels) == list(LEVELS)
        fields = tuple(levels[LEVELS[-1]].record.fields)
        out[name] = error_table(levels, fields).drop(columns=["wall_s"]).to_csv(float_format="%.10g")
    return out


@pytest.fixture(scope="module")
def dask():
    """One real local cluster (2 worker processes) for the tests that kill no worker."""
    with cluster(None, "local:2") as running:
        yield running


@pytest.fixture(scope="module")
def local_tables(tmp_path_factory) -> dict[str, str]:
    return tables(study(None, tmp_path_factory.mktemp("local"))[1])


def test_a_local_dask_cluster_gives_the_local_tables(dask, local_tables, tmp_path):
    assert len(dask.client.scheduler_info()["workers"]) == 2
    pids, runs = study(dask, tmp_path)
    assert tables(runs) == local_tables
    # Every chain ran in a worker process, into the shared results tree, nothing reused.
    assert os.getpid() not in pids
    assert not any(run.reused for levels in runs.values() for run in levels.values())
    assert all((tmp_path / s / f"n{n}" / "run.json").is_file() for s in SCENES for n in LEVELS)


def test_a_worker_killed_mid_study_ends_complete_or_with_a_clear_error(local_tables, tmp_path):
    with cluster(None, "local:2") as dask:
        pids = list(dask.client.run(os.getpid).values())
        killed = threading.Event()

        def kill_one() -> None:
            # After the first level: the rest are queued or running.
            deadline = time.monotonic() + 120
            while not list(tmp_path.glob("*/n*/run.json")) and time.monotonic() < deadline:
                time.sleep(0.02)
            killed.set()
            os.kill(pids[0], signal.SIGKILL)

        killer = threading.Thread(target=kill_one)
        killer.start()
        try:
            outcome: dict[str, str] | str = tables(study(dask, tmp_path)[1])
        except RunError as exc:
            outcome = str(exc)
        killer.join()
    assert killed.is_set()
    if isinstance(outcome, dict):  # the scheduler reran the lost tasks on the other (or restarted) worker
        assert outcome == local_tables
    else:
        assert "\n" not in outcome and "Dask task failed" in outcome, outcome


@pytest.mark.parametrize("text", ["local", "local:0", "remote:2", "local:x"])
def test_cluster_flag_must_be_local_with_a_count(text):
    with pytest.raises(SceneError, match="local:N"):
        parse_cluster(text)
    assert parse_cluster("local:3") == 3


def test_scheduler_and_cluster_exclude_each_other():
    with pytest.raises(SceneError, match="not both"):
        with cluster("tcp://127.0.0.1:1", "local:2"):
            pass


def square(k: int) -> int:
    return k * k


def test_each_runs_pieces_side_by_side_in_order_in_this_process_and_on_a_cluster(dask):
    assert each(None, square, range(5)) == [0, 1, 4, 9, 16]
    assert each(dask, square, list(range(5))) == [0, 1, 4, 9, 16]
    with pytest.raises(SceneError, match="local:N"):  # a piece's own error comes back as raised
        each(dask, parse_cluster, ["bad"])


def test_two_workers_running_the_same_levels_at_once_leave_one_complete_result(dask, tmp_path):
    """Both workers run (forced) the same chain into one results tree: each level is swapped
    in whole, so the survivor is complete, passes its checksums and is reused afterwards."""
    from harness.run.cache import corrupted

    layout = Layout(results=tmp_path)
    scene = load_scene(CASES / "paper.toml")
    outcomes = each(dask, lambda _: chain_runs(scene, layout, (2, 4), force=True), [0, 1])
    assert all(sorted(runs) == [2, 4] for _, runs in outcomes)
    for n in (2, 4):
        assert corrupted(tmp_path / "paper" / f"n{n}") is None
    assert not list((tmp_path / "paper").glob(".tmp-*")) and not list((tmp_path / "paper").glob(".old-*"))
    again = chain_runs(scene, layout, (2, 4))[1]
    assert sorted(again) == [2, 4] and all(run.reused for run in again.values())


@pytest.mark.heavy  # 13 s: `make test-heavy`
def test_scenes_study_on_a_local_cluster_writes_the_local_csvs(tmp_path):
    """`python -m harness scenes --cluster local:2` on two scenes, levels 2-8: each scene's
    convergence.csv and the summary equal the local run's but for the measurements of the
    machine (wall times, peak memory)."""
    import pandas as pd

    from harness.cli import main

    cases = tmp_path / "cases"
    cases.mkdir()
    for name in SCENES:
        (cases / f"{name}.toml").write_text((CASES / f"{name}.toml").read_text())
    common = ["scenes", "--cases", str(cases), "--levels", "2,4,8"]
    assert main([*common, "--results", str(tmp_path / "local")]) == 0
    assert main([*common, "--results", str(tmp_path / "dask"), "--cluster", "local:2"]) == 0

    def csv(path: Path) -> str:
        table = pd.read_csv(path)
        measured = [c for c in table.columns if "wall" in c or "rss" in c]
        return table.drop(columns=measured).to_csv(float_format="%.10g")

    for name in SCENES:
        assert csv(tmp_path / "dask" / name / "convergence.csv") == csv(tmp_path / "local" / name / "convergence.csv")
    assert csv(tmp_path / "dask" / "scenes" / "summary.csv") == csv(tmp_path / "local" / "scenes" / "summary.csv")


def test_stress_on_an_existing_scheduler_by_address(tmp_path, capsys):
    """--scheduler tcp://...: a scheduler someone else started (here a local one)."""
    import dask
    from distributed import LocalCluster

    from harness.cli import main

    argv = ["stress", "--cases", "coarsest,gap_open", "--levels", "2", "--paper-levels", "", "--force"]
    with dask.config.set({"distributed.worker.daemon": False}), \
            LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=":0") as cluster:
        assert main([*argv, "--results", str(tmp_path / "dask"), "--scheduler", cluster.scheduler_address]) == 0
    dask_out = capsys.readouterr().out
    assert main([*argv, "--results", str(tmp_path / "local")]) == 0
    local_out = capsys.readouterr().out
    lines = lambda out: sorted(line.split("(")[0].strip() for line in out.splitlines() if " n=" in line)  # noqa: E731
    assert lines(dask_out) == lines(local_out) and len(lines(local_out)) == 2


def modules_and_profiler() -> tuple[bool, bool]:
    import sys

    import dask as dask_module

    return "harness.study.hard_cases" in sys.modules, dask_module.config.get("distributed.worker.profile.enabled")


def test_a_warmed_local_cluster_has_the_harness_imported_and_no_profiler(dask):
    """What make scale times on a cluster is the study, not the workers' imports (the modules
    its caller names); and the workers' statistical profiler (a thread sampling every 10 ms)
    is off."""
    dask.warm(["harness.study.hard_cases"])
    assert set(dask.client.run(modules_and_profiler).values()) == {(True, False)}


def test_stress_summaries_are_compared_to_round_off_not_bit_for_bit():
    import pandas as pd

    from harness.study.scale_out import same_summary

    table = pd.DataFrame({"case": ["a", "b"], "status": ["converged", "diverged"], "newton": [3, 7],
                          "force": [1.0, 2.5e-6]})
    moved = table.copy()
    moved["force"] = [1.0 + 1e-9, 2.5e-6 * (1 + 1e-9)]   # the unstructured mesh's round-off
    assert same_summary(table, table) and same_summary(table, moved)
    worse = table.copy()
    worse["force"] = [1.0, 2.6e-6]
    other = table.copy()
    other["status"] = ["converged", "converged"]
    assert not same_summary(table, worse) and not same_summary(table, other)
    assert not same_summary(table, table.iloc[:1]) and not same_summary(table, table.drop(columns=["newton"]))
    # max sigma_nu near zero: its round-off judged against the row's pressure scale.
    sigma = pd.DataFrame({"max_sigma_nu": [-8.2032e-08, float("nan")], "sigma_nu_scale": [100.0, 100.0]})
    moved = sigma.assign(max_sigma_nu=[-8.2034e-08, float("nan")])
    assert same_summary(sigma, moved) and not same_summary(sigma, sigma.assign(max_sigma_nu=[-1e-6, float("nan")]))


def test_each_gives_a_cluster_the_costliest_items_first_and_returns_them_in_order():
    """Longest processing time first: a long case submitted last would run alone at the end."""
    from harness.study.executor import each

    class Recorder:  # DaskExecutor's submit, run at once, remembering the order
        def __init__(self) -> None:
            self.order: list[int] = []

        def submit(self, fn, item):
            self.order.append(item)
            done = fn(item)
            return type("Done", (), {"result": lambda self: done})()

    pool = Recorder()
    items = [3, 1, 4, 1, 5, 9, 2, 6]
    assert each(pool, lambda x: 10 * x, items, cost=lambda x: x) == [10 * x for x in items]
    assert pool.order == sorted(items, reverse=True)
    assert each(None, lambda x: 10 * x, items, cost=lambda x: x) == [10 * x for x in items]
