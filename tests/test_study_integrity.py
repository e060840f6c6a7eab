"""A study's results directory holds one study at a time: levels that cannot give a slope
are refused before anything runs, two studies into one directory never interleave, an
interrupted cross-check restores as a convergence study does, and the temp dirs of dead
runs are swept. Stand-in solver (tests/data/stub_freefem) throughout."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from harness.core import atomic

from harness.run import cache
from harness.cli import main
from harness.core.contract import ExitCode
from harness.core.layout import REPO

STUB = REPO / "tests" / "data" / "stub_freefem"
STUB_CASE = REPO / "tests" / "data" / "paper.toml"


def run(capsys, results, *argv: str) -> tuple[int, list[str]]:
    """The exit code and stderr lines of a command (a bad command line exits from argparse)."""
    try:
        code = main([*argv, "--results", str(results), "--freefem", str(STUB)])
    except SystemExit as exc:
        code = int(exc.code or 0)
    return code, capsys.readouterr().err.strip().splitlines()


def one_error(err: list[str], *words: str) -> str:
    errors = [line for line in err if line.startswith("error:")]
    assert len(errors) == 1 and not any("Traceback" in line for line in err), err
    assert all(word in errors[0] for word in words), errors
    return errors[0]


# ---- levels that cannot give a slope ---------------------------------------------------------

@pytest.mark.parametrize("levels, words", [("4", ("levels 4 cannot give a slope", "3 distinct levels")),
                                           ("2,4", ("levels 2,4 cannot give a slope",)),
                                           ("2,2,4", ("levels 2,4 cannot give a slope",)),
                                           ("2,,4", ("'2,,4' has an empty level",)),
                                           ("", ("no levels given",))])
def test_levels_that_cannot_give_a_slope_are_refused_before_anything_runs(capsys, tmp_path, levels, words):
    """A convergence study needs its reference and two compared levels: refused with exit 2
    and one line, the earlier study untouched (it used to run, replace the report and fail
    "total slope nan", or run the case's own levels for '')."""
    assert run(capsys, tmp_path, "convergence", str(STUB_CASE), "--levels", "2,4,8")[0] == 0
    summary = (tmp_path / "paper" / "summary.json").read_text()
    code, err = run(capsys, tmp_path, "convergence", str(STUB_CASE), "--levels", levels,
                    "--set", "loads.traction_y=-7")
    assert code == ExitCode.INPUT
    one_error(err, *words)
    assert (tmp_path / "paper" / "summary.json").read_text() == summary
    assert not any(line.startswith("[") for line in err)  # no level ran


@pytest.mark.parametrize("argv, needs", [(["verify", "--cases", "bulk", "--skip-gci", "--levels", "4"], 2),
                                         (["scenes", "--cases", str(STUB_CASE.parent), "--levels", "2,4"], 3)])
def test_every_study_with_a_slope_refuses_too_few_levels_before_making_anything(capsys, tmp_path, argv, needs):
    code, err = run(capsys, tmp_path / "results", *argv)
    assert code == ExitCode.INPUT
    one_error(err, f"needs {needs} distinct levels")
    assert not (tmp_path / "results").exists()


def test_a_manufactured_study_needs_two_levels_and_the_rule_is_one_table():
    from harness.core.guards import Slope, check_slope_levels
    from harness.core.errors import SceneError

    check_slope_levels((4, 8), Slope.AGAINST_EXACT)
    check_slope_levels((2, 4, 8), Slope.AGAINST_FINEST)
    check_slope_levels((8,), Slope.NONE)
    with pytest.raises(SceneError, match="needs 2 distinct levels"):
        check_slope_levels((8, 8), Slope.AGAINST_EXACT)
    with pytest.raises(SceneError, match="needs 3 distinct levels"):
        check_slope_levels((4, 8), Slope.AGAINST_FINEST)


# ---- one writer per study directory --------------------------------------------------------

def harness_process(results: Path, *argv: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "harness", *argv, "--results", str(results),
                             "--freefem", str(STUB)], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def wait_for(condition, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out waiting"
        time.sleep(0.05)


def hung_study(results: Path, *extra: str) -> subprocess.Popen:
    """A convergence study whose n = 4 hangs in FreeFEM's child (its n = 2 done), under way."""
    proc = harness_process(results, "convergence", str(STUB_CASE), "--levels", "2,4,8",
                           "--set", "scene.material=HangFine", "--set", "scene.initial_guess=coarser", *extra)
    wait_for(lambda: any((results / "paper").glob(".tmp-n4-*/child.pid")))
    return proc


def end_hung_children(results: Path) -> None:
    """The stub's `sleep 60` (a child of FreeFEM, in FreeFEM's group) outlives a SIGKILLed harness."""
    for pid_file in (results / "paper").glob(".tmp-n4-*/child.pid"):
        with contextlib.suppress(ProcessLookupError, ValueError):
            os.killpg(os.getpgid(int(pid_file.read_text())), signal.SIGKILL)


def test_a_second_study_into_the_same_directory_is_refused_and_the_first_ends_consistent(capsys, tmp_path):
    """Two convergence studies of one scene into one --results at once (loads -100 and -300)
    used to mix their levels: summary.json from one, n2 and n4 from the other. The second
    is refused with one line and exit 7 (BUSY) before touching anything; the first, when
    interrupted, restores the earlier study; afterwards a study runs normally."""
    assert run(capsys, tmp_path, "convergence", str(STUB_CASE), "--levels", "2,4,8")[0] == 0
    case = tmp_path / "paper"
    keys = {n: cache.stored_key(case / f"n{n}") for n in (2, 4, 8)}
    first = hung_study(tmp_path, "--set", "loads.traction_y=-100")
    try:
        code, err = run(capsys, tmp_path, "convergence", str(STUB_CASE), "--levels", "2,4,8",
                        "--set", "loads.traction_y=-300")
        assert code == ExitCode.BUSY == 7
        one_error(err, str(case), f"pid {first.pid}", "another study")
        assert not any(line.startswith("[") for line in err)  # nothing of it ran
        assert list(case.glob(".tmp-n4-*"))  # the first study's run, untouched
    finally:
        first.send_signal(signal.SIGINT)
        first.communicate(timeout=30)
    assert first.returncode == 130
    assert {n: cache.stored_key(case / f"n{n}") for n in (2, 4, 8)} == keys
    assert atomic.mixed_levels(case) == []
    code, _ = run(capsys, tmp_path, "convergence", str(STUB_CASE), "--levels", "2,4,8", "--set", "loads.traction_y=-300")
    assert code == 0 and atomic.mixed_levels(case) == []
    assert not list(case.glob(".tmp-*")) and not list(case.glob(".backup-*"))


def test_two_studies_started_together_never_interleave(tmp_path):
    """Both launched at once, each a full study: each ends 0 or 7 (at least one 0), and the
    directory holds one complete study, by its keys."""
    procs = [harness_process(tmp_path, "convergence", str(STUB_CASE), "--levels", "2,4,8",
                             "--set", f"loads.traction_y={load}") for load in (-100, -300)]
    codes = []
    for proc in procs:
        _, err = proc.communicate(timeout=120)
        codes.append(proc.returncode)
        assert proc.returncode in (0, 7), err.decode()
    assert 0 in codes
    case = tmp_path / "paper"
    assert atomic.mixed_levels(case) == [] and (case / "summary.json").is_file()


def test_a_lock_left_by_a_killed_study_does_not_block_and_its_temp_dirs_are_swept(capsys, tmp_path):
    """kill -9 of a study mid-run: the kernel drops its lock; the next study runs, removes the
    dead run's .tmp-n4-* (which used to stay forever) and restores the earlier study's dirs."""
    assert run(capsys, tmp_path, "convergence", str(STUB_CASE), "--levels", "2,4,8")[0] == 0
    case = tmp_path / "paper"
    first = hung_study(tmp_path, "--set", "loads.traction_y=-100")
    first.kill()
    first.communicate(timeout=30)
    end_hung_children(tmp_path)
    assert list(case.glob(".tmp-n4-*")) and list(case.glob(".backup-*"))  # what a kill -9 leaves
    code, err = run(capsys, tmp_path, "convergence", str(STUB_CASE), "--levels", "2,4,8")
    assert code == 0, err
    assert not list(case.glob(".tmp-*")) and not list(case.glob(".backup-*")) and not list(case.glob(".old-*"))
    assert atomic.mixed_levels(case) == []


def test_solve_holds_the_scene_directory_too(capsys, tmp_path):
    """`solve` writes the scene's level dirs: it is refused while a study of the scene runs."""
    first = hung_study(tmp_path)
    try:
        code, err = run(capsys, tmp_path, "solve", str(STUB_CASE), "--n", "2", "--set", "loads.traction_y=-7")
        assert code == ExitCode.BUSY
        one_error(err, str(tmp_path / "paper"))
    finally:
        first.send_signal(signal.SIGINT)
        first.communicate(timeout=30)


def test_a_run_whose_process_died_during_the_study_is_reported_and_swept(capsys, tmp_path, monkeypatch):
    """A Dask worker killed mid-task leaves its run's .tmp-n8-* in the scene's directory
    while the scheduler reruns the task elsewhere: the study used to exit 0 silently with the
    temp dir left. Here the dead worker's temp dir appears while the study runs."""
    import harness.studies.convergence as study

    real = study.run_study

    def with_a_dead_worker(scene, levels, layout, *args):  # noqa: ANN001, ANN202
        (layout.case_dir(scene.name) / ".tmp-n8-deadbeef").mkdir(parents=True)
        return real(scene, levels, layout, *args)

    monkeypatch.setattr(study, "run_study", with_a_dead_worker)
    code, err = run(capsys, tmp_path, "convergence", str(STUB_CASE), "--levels", "2,4,8")
    assert code == 0
    warnings = [line for line in err if line.startswith("warning:") and ".tmp-n8-deadbeef" in line]
    assert len(warnings) == 1 and "died" in warnings[0]
    assert not list((tmp_path / "paper").glob(".tmp-*"))


# ---- an interrupted cross-check --------------------------------------------------------------

def test_an_interrupted_crosscheck_keeps_the_earlier_crosscheck_whole(tmp_path):
    """SIGINT to a cross-check (--set loads.traction_y=-300, the stand-in solver hung at
    n = 4) over an earlier one (-100, real FreeFEM and the GetFEM peer) used to leave
    runs/paper/n2 from the new one and n4 and crosscheck.csv from the old. It runs in
    convergence's transaction now: every level dir and the table are the earlier ones."""
    from harness.run.peer import SYSTEM_PYTHON

    if subprocess.run([SYSTEM_PYTHON, "-I", "-c", "import getfem"], capture_output=True, cwd="/").returncode:
        pytest.skip("GetFEM (python3-getfem) is not installed")
    argv = ["crosscheck", str(REPO / "cases" / "paper.toml"), "--levels", "2,4", "--branches", "zero",
            "--results", str(tmp_path)]
    earlier = subprocess.run([sys.executable, "-m", "harness", *argv, "--set", "loads.traction_y=-100"],
                             cwd=REPO, capture_output=True, text=True, timeout=300)
    assert earlier.returncode == 0, earlier.stderr
    out = tmp_path / "crosscheck"
    runs = out / "runs" / "paper"  # zero is the paper's own start (its coarsest level's)
    keys = {n: cache.stored_key(runs / f"n{n}") for n in (2, 4)}
    table = (out / "crosscheck.csv").read_text()
    proc = subprocess.Popen([sys.executable, "-m", "harness", *argv, "--set", "loads.traction_y=-300",
                             "--set", "scene.material=HangFine", "--freefem", str(STUB)],
                            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    wait_for(lambda: any(runs.glob(".tmp-n4-*/child.pid")))
    assert cache.stored_key(runs / "n2") != keys[2]  # the new n = 2 is in place: the mix to be undone
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 130, err.decode()
    one_error(err.decode().strip().splitlines(), "interrupted by SIGINT")
    assert {n: cache.stored_key(runs / f"n{n}") for n in (2, 4)} == keys
    assert (out / "crosscheck.csv").read_text() == table
    assert not list(runs.glob(".tmp-*")) and not list(runs.glob(".backup-*")) and not list(out.glob(".backup-*"))


def test_a_study_whose_dask_worker_died_reports_it_and_leaves_no_temp_dir(tmp_path):
    """A real local Dask cluster: the worker running n = 4 is killed (SIGKILL) mid-run; the
    scheduler reruns the scene's task on a worker, and the study ends complete (exit 0),
    as before, but no longer with the dead run's .tmp-n4-* left and nothing said."""
    pytest.importorskip("distributed", reason="dask/distributed missing (the 'cluster' extra)")
    cases = tmp_path / "cases"
    cases.mkdir()
    (cases / "paper.toml").write_text(STUB_CASE.read_text().replace('material = "BaTiO3"',
                                                                   'material = "HangBriefly"', 1))
    results = tmp_path / "results"
    proc = subprocess.Popen([sys.executable, "-m", "harness", "scenes", "--cases", str(cases), "--levels", "2,4,8",
                             "--cluster", "local:2", "--results", str(results), "--freefem", str(STUB)],
                            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    case = results / "paper"
    try:
        wait_for(lambda: any(case.glob(".tmp-n4-*/child.pid")), timeout=120)
        (pid_file,) = case.glob(".tmp-n4-*/child.pid")
        dead_run = pid_file.parent
        worker = int(pid_file.read_text())  # the stub's sleep, below FreeFEM (and a shell or two)
        while "python" not in Path(f"/proc/{worker}/cmdline").read_text(errors="replace"):
            worker = int(Path(f"/proc/{worker}/stat").read_text().split(")")[-1].split()[1])
        assert worker not in (1, proc.pid)  # a Dask worker process, not the harness
        os.kill(worker, signal.SIGKILL)
        _, err = proc.communicate(timeout=180)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    lines = err.decode().strip().splitlines()
    assert proc.returncode == 0, lines
    warnings = [line for line in lines if line.startswith("warning:") and dead_run.name in line]
    assert len(warnings) == 1 and "died" in warnings[0], lines
    assert not list(case.glob(".tmp-*")) and not list(case.glob(".old-*"))
    assert all((case / f"n{n}" / "run.json").is_file() for n in (2, 4, 8))
