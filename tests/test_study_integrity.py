"""A study's results directory holds one study at a time: levels that cannot give a slope
are refused before anything runs, two studies into one directory never interleave, an
interrupted cross-check restores as a convergence study does, and the temp dirs of dead
runs are swept. Stand-in solver (tests/data/stub_freefem) throughout."""

from __future__ import annotations

import pytest

from harness.cli import main
from harness.contract import ExitCode
from harness.layout import REPO

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


def test_a_manufactured_study_needs_two_levels_and_the_rule_is_one_table():
    from harness.guards import Slope, check_slope_levels
    from harness.errors import SceneError

    check_slope_levels((4, 8), Slope.AGAINST_EXACT)
    check_slope_levels((2, 4, 8), Slope.AGAINST_FINEST)
    check_slope_levels((8,), Slope.NONE)
    with pytest.raises(SceneError, match="needs 2 distinct levels"):
        check_slope_levels((8, 8), Slope.AGAINST_EXACT)
    with pytest.raises(SceneError, match="needs 3 distinct levels"):
        check_slope_levels((4, 8), Slope.AGAINST_FINEST)
