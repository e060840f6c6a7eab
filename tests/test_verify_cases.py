"""`python -m harness verify --cases` takes a path to a user's own manufactured case file
beside the built-in names: it runs on its own [study] levels under its scene name, and a
file that cannot be one ends with one line and exit code 2."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from harness.cli import main
from harness.core.contract import ExitCode
from harness.core.layout import REPO

BULK = REPO / "cases" / "mms" / "bulk.toml"


def errors(capsys) -> list[str]:
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return [line for line in err.splitlines() if line.startswith("error:")]


def own_case(tmp_path: Path, **replace: str) -> Path:
    """cases/mms/bulk.toml as a user's file elsewhere: its name mine, its levels 4 and 8."""
    text = BULK.read_text().replace('name = "mms_bulk"', 'name = "mine"').replace(
        "levels = [4, 8, 16, 32]", "levels = [4, 8]")
    for old, new in replace.items():
        text = text.replace(old, new)
    path = tmp_path / "cases" / "mine.toml"
    path.parent.mkdir(exist_ok=True)
    path.write_text(text)
    return path


def test_a_users_own_manufactured_case_runs_beside_a_built_in_name_on_its_own_levels(tmp_path, capsys):
    case = own_case(tmp_path)
    results = tmp_path / "results"
    assert main(["verify", "--cases", f"{case},bulk", "--levels", "4,8", "--skip-gci", "--results", str(results)]) == 0
    rates = pd.read_csv(results / "verification" / "mms.csv")
    assert set(rates["case"]) == {"mine", "bulk"}
    mine, bulk = (rates[rates["case"] == c].set_index(["field", "norm"]) for c in ("mine", "bulk"))
    # The same fields on the same levels: the same slopes.
    pd.testing.assert_series_equal(mine["slope"], bulk["slope"], rtol=1e-12)
    assert (mine["n_finest"] == 8).all() and mine["within_band"].all()


def test_a_case_file_without_exact_fields_or_with_a_taken_name_is_refused_in_one_line(tmp_path, capsys):
    paper = tmp_path / "paper.toml"
    paper.write_text((REPO / "cases" / "paper.toml").read_text())
    taken = own_case(tmp_path, **{'name = "mine"': 'name = "bulk"'})
    for case, words in ((paper, "no [manufactured] section"), (taken, "already a case")):
        assert main(["verify", "--cases", f"bulk,{case}", "--skip-gci", "--results", str(tmp_path / "r")]) \
            == ExitCode.INPUT
        (line,) = errors(capsys)
        assert str(case) in line and words in line
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("given, words", [("nosuch", "give a case file's path"), ("nosuch/case.toml", "not found")])
def test_an_unknown_name_or_a_missing_file_is_refused_in_one_line(tmp_path, capsys, given, words):
    assert main(["verify", "--cases", given, "--skip-gci", "--results", str(tmp_path)]) == ExitCode.INPUT
    (line,) = errors(capsys)
    assert given in line and words in line
