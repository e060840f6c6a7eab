"""The one study pipeline (harness/study/pipeline.py): every study is guarded before it meshes or
runs anything, and its writes are all or nothing; shown on `cost` and `branches`, which
had neither before (issue 23, item 2)."""

from __future__ import annotations


import pytest

from harness.core.atomic import BACKUP_PREFIX, StudyTransaction
from harness.cli import main
from harness.core.contract import ExitCode
from harness.core.layout import REPO
from harness.core.writers import write_text

STUB = REPO / "tests" / "data" / "stub_freefem"
PAPER = REPO / "cases" / "paper.toml"
# A level no machine holds: the paper's block at h = 1/65536 is ~1.7e10 dofs, ~1e14 bytes
# by the guard's measured bytes per dof.
HUGE = "65536"


def errors(capsys) -> list[str]:
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return [line for line in err.splitlines() if line.startswith("error:")]


@pytest.mark.parametrize("argv", [
    ["cost", str(PAPER), "--levels", "2,4", "--scaling-levels", HUGE, "--discretisations", "P1"],
    ["branches", "--levels", f"2,{HUGE}", "--starts", "zero"],
    ["stress", "--cases", "coarsest", "--levels", HUGE, "--paper-levels", ""],
    ["verify", "--cases", "bulk", "--levels", f"4,{HUGE}", "--skip-gci"],
])
def test_a_study_refuses_a_level_that_cannot_fit_before_meshing_anything(argv, capsys, tmp_path):
    assert main([*argv, "--results", str(tmp_path)]) == ExitCode.ENVIRONMENT
    (line,) = errors(capsys)
    assert f"n={HUGE}" in line and "--ignore-memory-guard" in line
    assert not list(tmp_path.rglob("*.msh")) and not list(tmp_path.rglob("run.json"))


def test_a_study_refuses_a_results_path_that_is_a_file(capsys, tmp_path):
    target = tmp_path / "file"
    target.write_text("")
    assert main(["branches", "--levels", "2,4", "--starts", "zero", "--results", str(target / "sub")]) \
        == ExitCode.ENVIRONMENT
    (line,) = errors(capsys)
    assert "is a file" in line


def test_branches_refuses_levels_that_are_not_nested(capsys, tmp_path):
    assert main(["branches", "--levels", "2,3", "--starts", "zero", "--results", str(tmp_path)]) == ExitCode.INPUT
    (line,) = errors(capsys)
    assert "not nested" in line


def test_a_branches_report_that_fails_half_written_leaves_the_earlier_study_whole(capsys, tmp_path):
    """The second study writes its start's report and branches.csv, then cannot write
    branches.md: the earlier table and report are put back, not a mix of both studies."""
    argv = ["branches", "--starts", "zero", "--results", str(tmp_path), "--freefem", str(STUB)]
    assert main([*argv, "--levels", "2,4"]) == 0
    before = {name: (tmp_path / name).read_text() for name in ("branches.csv", "zero/summary.json",
                                                                "zero/convergence.csv")}
    (tmp_path / "branches.md").unlink()
    (tmp_path / "branches.md").mkdir()  # the last file of the report cannot be written
    capsys.readouterr()
    assert main([*argv, "--levels", "2,4,8"]) == ExitCode.ENVIRONMENT
    assert len(errors(capsys)) == 1
    assert (tmp_path / "zero" / "n8" / "run.json").is_file()  # the new study did run
    for name, text in before.items():
        assert (tmp_path / name).read_text() == text, name
    assert not list(tmp_path.rglob(f"{BACKUP_PREFIX}*"))


def test_the_transaction_owns_every_file_of_an_output_directory(tmp_path):
    """Written as the studies write (harness/core/writers.py: a new file moved over the old, which
    the backup's hard link keeps)."""
    out = tmp_path / "cost"
    out.mkdir()
    (out / "cost.csv").write_text("old")
    (out / "frontier.md").write_text("old")
    with pytest.raises(RuntimeError):
        with StudyTransaction(outputs=(out,)):
            write_text("new", out / "cost.csv")
            raise RuntimeError("the plot failed")
    assert (out / "cost.csv").read_text() == "old" and (out / "frontier.md").read_text() == "old"
    with StudyTransaction(outputs=(out,)):
        write_text("new", out / "cost.csv")
    assert (out / "cost.csv").read_text() == "new" and not list(out.glob(f"{BACKUP_PREFIX}*"))


def test_a_study_on_fewer_levels_refuses_to_replace_a_finer_one(capsys, tmp_path):
    """`scenes` runs each scene on its case's levels; a study run by hand to a finer level in the
    same folder must not be replaced by a shallower one without a word."""
    argv = ["convergence", str(PAPER), "--results", str(tmp_path), "--freefem", str(STUB)]
    assert main([*argv, "--levels", "2,4,8,16"]) == 0
    summary = tmp_path / "paper" / "summary.json"
    before = summary.read_text()
    capsys.readouterr()
    assert main([*argv, "--levels", "2,4,8"]) == ExitCode.INPUT
    (line,) = errors(capsys)
    assert "n = 16" in line and "n = 8" in line and "2,4,8,16" in line
    assert summary.read_text() == before and not (tmp_path / "paper" / "n2.failed").exists()
    assert main([*argv, "--levels", "4,8,16"]) == 0  # the same finest level replaces it
