"""A verdict must not depend on the machine: FreeFEM runs single-threaded whatever the shell sets.
The threads of OpenBLAS (under MUMPS and UMFPACK) and of OpenMP sum in an order that depends on
their count, which changes the last bits of a factorisation; the harness pins both to one for
every FreeFEM process (harness/core/freefem.py environment), so a shell's OMP_NUM_THREADS=2 or
OPENBLAS_NUM_THREADS=2 changes no run: the same Newton path, the same digits."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from harness.cli import main
from harness.core import freefem
from harness.core.contract import ExitCode

PAPER = Path(__file__).parents[1] / "cases" / "paper.toml"


@pytest.mark.parametrize("threads", ["2", "4"])
def test_freefem_runs_on_one_thread_whatever_the_shell_asks(monkeypatch, threads):
    monkeypatch.setenv("OMP_NUM_THREADS", threads)
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", threads)
    env = freefem.environment()
    assert env["OMP_NUM_THREADS"] == "1" and env["OPENBLAS_NUM_THREADS"] == "1"


def test_a_run_is_the_same_to_the_last_digit_with_the_shells_threads_at_one_and_two(tmp_path, monkeypatch):
    """The paper's scene at n = 8 (its Newton path, residuals and resultants) with the shell's
    thread counts at 1 and at 2."""
    records = {}
    for threads in ("1", "2"):
        monkeypatch.setenv("OMP_NUM_THREADS", threads)
        monkeypatch.setenv("OPENBLAS_NUM_THREADS", threads)
        assert main(["solve", str(PAPER), "--n", "8", "--results", str(tmp_path / threads), "--force"]) == ExitCode.OK
        records[threads] = json.loads((tmp_path / threads / "paper" / "n8" / "run.json").read_text())
    keys = ("newton_iterations", "residuals", "increments", "contact_force", "heat_in_contact", "charge_in_contact",
            "max_abs_u", "max_theta")
    assert {k: records["1"][k] for k in keys} == {k: records["2"][k] for k in keys}
