"""Tolerances as verdicts (harness/measure/tolerances.py, docs/quantities.md): a case's
`[quantities] tolerances` names quantities the scene has (anything else refused, exit 2), and a
convergence study's verdict says whether the finest level meets each by its estimate
(Richardson's, or the goal estimate when the run wrote one), exit 1 when one does not; a
quantity that is not extrapolable cannot meet one. A case without tolerances writes what it did."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from harness.cli import main
from harness.measure.quantity_study import converge
from harness.measure.tolerances import GOAL, RICHARDSON, failure, judge
from harness.run.record import RunRecord

ROOT = Path(__file__).parents[1]
PAPER = ROOT / "cases" / "paper.toml"
BLOCK = ROOT / "tests" / "data" / "block.toml"


def one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:"), err
    return err[0]


@pytest.mark.parametrize("table, key", [
    ("{nonsense = 0.01}", "quantities.tolerances.nonsense"),
    # the block's scene has electric contact but no piezoelectric electrode
    ("{'electrode_charge.electrode' = 0.01}", "quantities.tolerances.electrode_charge.electrode"),
    ("{max_abs_u = -0.01}", "quantities.tolerances.max_abs_u"),
    ("{max_abs_u = 'tight'}", "quantities.tolerances.max_abs_u"),
    ("0.01", "quantities.tolerances"),
])
def test_a_tolerance_on_no_quantity_of_the_scene_or_not_a_positive_number_is_refused(tmp_path, capsys, table, key):
    code = main(["convergence", str(BLOCK), "--levels", "2,4,8", "--results", str(tmp_path),
                 "--set", f"quantities.tolerances={table}"])
    line = one_error_line(capsys)
    assert code == 2
    assert str(BLOCK) in line and key in line
    assert not (tmp_path / "block").exists()  # refused before anything ran


def record(n: int, quantities: dict[str, float], goals: dict[str, float] | None = None) -> RunRecord:
    r = RunRecord(n=n, converged=True, quantities=quantities)
    if goals is not None:  # a run.json with goal-oriented estimates (written by the dual solve)
        object.__setattr__(r, "goal_estimates", goals)
    return r


def test_richardsons_estimate_meets_or_misses_and_a_goal_estimate_is_preferred():
    # f = 1 + h: Richardson's value 1, the finest level (h = 1/16) 1/16 off it
    studied = {"q": converge("q", "m", {4: 1.25, 8: 1.125, 16: 1.0625}),
               "osc": converge("osc", "m", {4: 1.0, 8: 1.1, 16: 1.05})}
    finest = record(16, {"q": 1.0625, "osc": 1.05})
    verdicts = judge({"q": 0.1, "osc": 0.5}, studied, finest)
    assert verdicts["q"].by == RICHARDSON and verdicts["q"].estimate == pytest.approx(0.0625)
    assert verdicts["q"].met
    assert not verdicts["osc"].met and verdicts["osc"].by == "" and math.isnan(verdicts["osc"].estimate)
    assert "not extrapolable" in verdicts["osc"].why
    assert not judge({"q": 0.01}, studied, finest)["q"].met
    message = failure(judge({"q": 0.01, "osc": 0.5}, studied, finest), "case")
    assert "q 0.0625 (Richardson) > 0.01" in message and "osc has no error estimate" in message
    assert failure(judge({"q": 0.1}, studied, finest), "case") is None
    # the goal estimate, when the finest run has one, is the estimate (|Q_exact - Q_h| / |Q_h|),
    # also for a quantity Richardson cannot extrapolate
    goal = record(16, {"q": 1.0625, "osc": 1.05}, {"q": -0.010625, "osc": 0.0021})
    verdicts = judge({"q": 0.02, "osc": 0.01}, studied, goal)
    assert verdicts["q"].by == GOAL and verdicts["q"].estimate == pytest.approx(0.01) and verdicts["q"].met
    assert verdicts["osc"].by == GOAL and verdicts["osc"].estimate == pytest.approx(0.002) and verdicts["osc"].met


def the_error(capsys) -> str:
    """A study's one error line (its progress and warnings are on stderr too)."""
    errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert len(errors) == 1, errors
    return errors[0]


def summary(results: Path) -> dict:
    return json.loads((results / "paper" / "summary.json").read_text())


def test_a_convergence_study_judges_its_tolerances_on_the_finest_level(tmp_path, capsys):
    # The total slope over n = 2 ... 16 is 1.35, above the case's band (n = 64 is its finest):
    # the band widened so that the verdict is the tolerances'.
    study = ["convergence", str(PAPER), "--levels", "2,4,8,16", "--results", str(tmp_path),
             "--set", "study.slope_band=[0.8, 1.6]"]
    # Without tolerances: no tolerance in summary.json, the verdict the slope's.
    assert main(study) == 0
    assert "tolerances" not in summary(tmp_path)
    capsys.readouterr()
    # At n = 16 Richardson puts the charge through the contact 2.4 % off and max |u| 3.1 %
    # (docs/quantities.md): 0.5 is met by far, 1e-4 missed by far, whatever the round-off.
    assert main([*study, "--set", "quantities.tolerances={charge_through_contact = 0.5}"]) == 0
    judged = summary(tmp_path)["tolerances"]["charge_through_contact"]
    assert judged["met"] and judged["by"] == RICHARDSON and 0.01 < judged["estimate"] < 0.05
    assert "tolerance charge_through_contact: met" in capsys.readouterr().out
    assert main([*study, "--set", "quantities.tolerances={charge_through_contact = 0.5, max_abs_u = 1e-4}"]) == 1
    line = the_error(capsys)
    assert "max_abs_u" in line and "(Richardson) > 0.0001" in line and "charge_through" not in line
    assert summary(tmp_path)["tolerances"]["max_abs_u"]["met"] is False  # the report written before the verdict
    # the friction force's levels oscillate: no estimate, so no tolerance is met
    assert main([*study, "--set", "quantities.tolerances={contact_force_tangential = 0.5}"]) == 1
    line = the_error(capsys)
    assert "contact_force_tangential has no error estimate" in line and "not extrapolable" in line
    assert summary(tmp_path)["tolerances"]["contact_force_tangential"]["estimate"] is None
