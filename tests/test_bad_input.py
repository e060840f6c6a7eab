"""Bad input ends with one clear line and a non-zero exit, and leaves earlier results intact."""

from __future__ import annotations

import shutil
from pathlib import Path

from harness.cli import main

ROOT = Path(__file__).parents[1]
PAPER = ROOT / "cases" / "paper.toml"


def solve(tmp: Path, *extra: str) -> int:
    return main(["solve", str(PAPER), "--n", "4", "--results", str(tmp), *extra])


def test_newton_non_convergence_is_reported_and_keeps_the_good_run(tmp_path, capsys):
    assert solve(tmp_path) == 0
    good = (tmp_path / "paper" / "n4" / "run.json").read_text()
    capsys.readouterr()  # the good run's own lines (the paper's Tresca warning, harness/run/tresca.py)
    assert solve(tmp_path, "--set", "newton.max_iterations=2", "--force") != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "maximum number of iterations" in err[0]
    assert (tmp_path / "paper" / "n4" / "run.json").read_text() == good


def test_freefem_script_error_is_reported_with_its_reason(tmp_path, capsys):
    scripts = tmp_path / "freefem"
    shutil.copytree(ROOT / "freefem", scripts)
    with (scripts / "newton.idp").open("a") as f:
        f.write("\nthis is not FreeFEM;\n")
    assert solve(tmp_path, "--freefem", str(scripts)) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "compile error" in err[0].lower()
    assert not (tmp_path / "paper" / "n4" / "run.json").exists()


def test_missing_mesh_is_a_clear_solver_failure(tmp_path):
    """The solver run by hand on a mesh that does not exist fails with a readable reason."""
    from harness.core.freefem import command, error_detail, failure_reason, invoke

    out = tmp_path / "run"
    out.mkdir()
    script = out / "main.edp"
    script.write_text(f'include "{ROOT / "freefem" / "materials" / "BaTiO3.idp"}"\n'
                      f'include "{ROOT / "freefem" / "scheme.idp"}"\n')
    outcome = invoke(command(script, ["-mesh", str(tmp_path / "nope.msh"), "-out", str(out)]), out, 60)
    assert outcome.returncode not in (0, None)
    log = (out / "stdout.txt").read_text() + (out / "stderr.txt").read_text()
    reason = failure_reason(outcome, 60, error_detail(log))
    assert "nope.msh" in reason or "error" in reason.lower(), reason
