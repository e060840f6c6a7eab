"""A rank that dies while its MPI launcher lives on (harness/core/rank_watch.py): the harness ends
the run itself within seconds, with the rank's signal, instead of waiting for the timeout."""

from __future__ import annotations

import shutil
import sys
import time
from pathlib import Path

from harness.core import freefem
from harness.core.rank_watch import dead_rank


def fake_rank(tmp_path: Path) -> Path:
    """A process named like a FreeFEM rank: a copy of sleep."""
    rank = tmp_path / "FreeFem++-mpi"
    shutil.copy(shutil.which("sleep"), rank)
    return rank


def test_a_dead_rank_its_launcher_never_reaps_ends_the_run_with_its_signal(tmp_path):
    # The "launcher" starts a rank, which is killed, then becomes a process that never reaps it
    # (a hung mpiexec, as seen once under load): the rank stays a zombie and the launcher lives.
    fake_rank(tmp_path)
    launcher = ("import os, subprocess, time; rank = subprocess.Popen(['./FreeFem++-mpi', '100']); "
                "os.kill(rank.pid, 9); time.sleep(100)")
    argv = [sys.executable, "-c", launcher]
    start = time.perf_counter()
    outcome = freefem.invoke(argv, tmp_path, timeout_s=60)
    took = time.perf_counter() - start
    assert outcome.returncode == 137 and took < freefem.RANK_GRACE_S + 5, (outcome, took)
    assert freefem.failure_reason(outcome, 60, "").startswith("killed by signal SIGKILL")


def test_live_ranks_and_a_rank_the_launcher_reaps_are_left_alone(tmp_path):
    fake_rank(tmp_path)
    # A rank that ends normally and is reaped (bash waits for it): the run's own code.
    outcome = freefem.invoke(["bash", "-c", "./FreeFem++-mpi 0.2; exit 3"], tmp_path, timeout_s=60)
    assert outcome.returncode == 3
    # A live rank is no dead one.
    outcome = freefem.invoke(["bash", "-c", "./FreeFem++-mpi 0.5 & wait"], tmp_path, timeout_s=60)
    assert outcome.returncode == 0


def test_a_dead_rank_is_found_with_its_signal_until_it_is_reaped(tmp_path):
    import os
    import signal
    import subprocess

    rank = subprocess.Popen([str(fake_rank(tmp_path)), "100"])  # this test's process is its launcher
    try:
        assert dead_rank(os.getpid()) is None   # alive
        os.kill(rank.pid, signal.SIGKILL)
        deadline = time.time() + 10
        while (found := dead_rank(os.getpid())) is None and time.time() < deadline:
            time.sleep(0.05)
        assert found is not None and found.pid == rank.pid and found.returncode == 128 + signal.SIGKILL
    finally:
        rank.kill()
        rank.wait()
    assert dead_rank(os.getpid()) is None   # reaped
