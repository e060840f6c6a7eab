"""Bad input ends with one clear line and a non-zero exit, and leaves earlier results intact."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from harness.cli import main
from harness.core.contract import ExitCode

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


def symlink_loop(folder: Path, name: str) -> Path:
    """`name` in `folder`, a symbolic link to a link that points back to it."""
    (folder / f"{name}.other").symlink_to(name)
    (folder / name).symlink_to(f"{name}.other")
    return folder / name


def case_beside(tmp: Path, source: Path, old: str, new: str) -> Path:
    """`source` copied into `tmp` with `old` replaced by `new`."""
    text = source.read_text()
    assert old in text
    case = tmp / source.name
    case.write_text(text.replace(old, new, 1))
    return case


@pytest.mark.parametrize("key", ["scene.material", "scene.materials.lower", "geometry.file"])
def test_a_loop_of_symbolic_links_in_a_case_files_path_is_one_line_and_exit_2(tmp_path, capsys, key):
    """A path of the case file that is a loop of links (Python 3.11's pathlib raises RuntimeError
    for it): one line naming the case file and the key, exit 2. Before, a traceback, exit 1."""
    loop = symlink_loop(tmp_path, "loop.idp" if key != "geometry.file" else "loop.geo")
    if key == "scene.material":
        case = case_beside(tmp_path, PAPER, 'material = "BaTiO3"', 'material = "loop.idp"')
    elif key == "scene.materials.lower":
        case = case_beside(tmp_path, ROOT / "tests" / "data" / "bilayer_rect.toml",
                           'lower = "Brass"', 'lower = "loop.idp"')
    else:
        case = case_beside(tmp_path, ROOT / "cases" / "paper_gmsh.toml",
                           'file = "geo/paper.geo"', f'file = "{loop.name}"')
    code = main(["solve", str(case), "--n", "2", "--results", str(tmp_path / "results")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == ExitCode.INPUT == 2
    assert len(err) == 1 and err[0].startswith(f"error: {case}: {key} = ") and "loop of symbolic links" in err[0], err
    assert not (tmp_path / "results").exists()


def test_a_loop_of_symbolic_links_as_the_results_folder_is_one_line(tmp_path, capsys):
    loop = symlink_loop(tmp_path, "results")
    code = main(["solve", str(PAPER), "--n", "2", "--results", str(loop / "sub")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == ExitCode.ENVIRONMENT == 4
    assert len(err) == 1 and err[0].startswith("error:") and "loop of symbolic links" in err[0], err
