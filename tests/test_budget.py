"""The error budget (`python -m harness budget`, harness/measure/budget.py, docs/cost.md): each
quantity's error at a level in its mesh, penalty and Newton parts, beside each part's wall time,
on known answers: a block pressed uniformly onto the foundation carries its load whatever c_nu
(the contact force's penalty part is round-off) and enters it by load/c_nu (the penetration's
part is 1/10 - 1 and 1/100 - 1 of it); a linear problem's Newton part is zero."""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd
import pytest

from harness.cli import main
from harness.measure.budget import BudgetRuns, budget_table
from harness.run.record import RunRecord

ROOT = Path(__file__).parents[1]
BLOCK = ROOT / "tests" / "data" / "block.toml"
LINEAR = ROOT / "tests" / "data" / "linear_probes.toml"
COLUMNS = ["quantity", "unit", "value", "discretisation", "discretisation_status", "penalty_x10", "penalty_x100",
           "penalty_limit", "penalty_limit_status", "newton", "value_wall_s", "discretisation_wall_s", "penalty_wall_s", "newton_wall_s"]
# The block's bottom, where u_y = -s = -load/c_nu (a probe: no built-in quantity is the penetration).
BOTTOM = 'quantities.probes=[{name = "bottom_uy", field = "u_y", at = [1.0, 0.0]}]'


def budget(results: Path, case: Path, n: int, *extra: str) -> int:
    return main(["budget", str(case), "--n", str(n), "--results", str(results), *extra])


def test_the_budget_of_a_pressed_block_has_its_columns_and_the_penalty_answers_known(tmp_path, capsys):
    assert budget(tmp_path, BLOCK, 8, "--set", BOTTOM) == 0
    out = tmp_path / "budget" / "block"
    table = pd.read_csv(out / "budget.csv")
    assert list(table.columns) == COLUMNS
    printed = capsys.readouterr().out.splitlines()
    for name in table["quantity"]:  # one line per quantity
        assert sum(line.startswith(f"{name} = ") for line in printed) == 1
    assert "augmented-Lagrangian" in (out / "budget.md").read_text()
    # its runs in their own folders, none a convergence study's
    assert {p.name for p in out.iterdir() if p.is_dir()} >= {"levels", "c_nu_x10", "c_nu_x100", "newton_rtol_1e-6"}
    assert (out / "levels" / "n2" / "run.json").is_file() and (out / "c_nu_x100" / "n8" / "run.json").is_file()
    assert not (tmp_path / "budget" / "block" / "n8").exists()
    row = table.set_index("quantity")
    # Equilibrium: the contact carries the load, 200 N/m, at every c_nu (measured 1.3e-11)
    assert row.loc["contact_force_normal", "value"] == pytest.approx(200.0, rel=1e-9)
    assert abs(row.loc["contact_force_normal", "penalty_x10"]) < 1e-9
    assert abs(row.loc["contact_force_normal", "penalty_x100"]) < 1e-9
    # The penetration load/c_nu: (-s/10 + s)/s = 0.9 and (-s/100 + s)/s = 0.99
    assert row.loc["bottom_uy", "value"] == pytest.approx(-100.0 / 1e7, rel=1e-6)
    assert row.loc["bottom_uy", "penalty_x10"] == pytest.approx(0.9, abs=1e-6)
    assert row.loc["bottom_uy", "penalty_x100"] == pytest.approx(0.99, abs=1e-6)
    for part in ("value_wall_s", "discretisation_wall_s", "penalty_wall_s", "newton_wall_s"):
        assert (table[part] > 0).all()
    # Again: every run reused (its inputs unchanged), the same table
    capsys.readouterr()
    assert budget(tmp_path, BLOCK, 8, "--set", BOTTOM) == 0
    assert capsys.readouterr().err.count("reused") == 6
    pd.testing.assert_frame_equal(pd.read_csv(out / "budget.csv"), table)


def test_a_linear_problems_newton_part_is_zero_and_it_has_no_penalty_part(tmp_path):
    assert budget(tmp_path, LINEAR, 8) == 0
    table = pd.read_csv(tmp_path / "budget" / "linear_probes" / "budget.csv").set_index("quantity")
    # One Newton step solves a linear problem; the step that sees the increment vanish follows at
    # either rtol, so both runs stop at the same state (the increment below 1e-6 and below 1e-9).
    assert (table["newton"].abs() < 1e-12).all()
    assert table["penalty_x10"].isna().all() and table["penalty_x100"].isna().all()
    # the probe of a linear field is exact on every level: converged, no mesh error
    assert table.loc["tip_uy", "discretisation"] == 0


def test_a_level_that_is_not_a_multiple_of_4_is_refused(tmp_path, capsys):
    assert budget(tmp_path, BLOCK, 6) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and "--n 6" in err[0]
    assert not (tmp_path / "budget").exists()


def record(n: int, values: dict[str, float], **more: object) -> RunRecord:
    r = RunRecord(n=n, converged=True, quantities=values, wall_s=1.0)
    for key, value in more.items():  # goal estimates: a key of the dual solve's run.json
        object.__setattr__(r, key, value)
    return r


def test_the_goal_estimate_is_shown_beside_richardsons_when_the_run_has_one():
    # f = 1 + h: Richardson's value is 1, level 16 is 1/16 above it
    levels = {4: record(4, {"q": 1.25}), 8: record(8, {"q": 1.125}), 16: record(16, {"q": 1.0625})}
    runs = BudgetRuns(levels, {10: record(16, {"q": 1.1}), 100: record(16, {"q": 1.2})}, record(16, {"q": 1.0625}))
    row = budget_table([("q", "m")], runs).iloc[0]
    assert "goal_estimate" not in row.index
    assert row["discretisation"] == pytest.approx(-0.0625 / 1.0625)
    assert row["penalty_x10"] == pytest.approx(0.0375 / 1.0625) and row["newton"] == 0
    assert row["discretisation_wall_s"] == 2.0 and row["penalty_wall_s"] == 2.0
    levels[16] = record(16, {"q": 1.0625}, goal_estimates={"q": -0.05})
    row = budget_table([("q", "m")], BudgetRuns(levels, {}, record(16, {"q": 1.0625}))).iloc[0]
    assert row["goal_estimate"] == pytest.approx(-0.05 / 1.0625)
    assert math.isnan(row["penalty_x10"])


def test_the_penalty_limit_is_richardsons_in_one_over_c_nu_and_none_when_the_penalty_sets_the_answer():
    levels = {4: record(4, {"q": 1.25, "f": 1.0}), 8: record(8, {"q": 1.125, "f": 1.0}),
              16: record(16, {"q": 1.0, "f": 1.0})}
    # q = 2 - 1/k at c_nu x k: its limit 2, twice level 16's value; f = k, set by the penalty
    penalty = {10: record(16, {"q": 1.9, "f": 10.0}), 100: record(16, {"q": 1.99, "f": 100.0})}
    table = budget_table([("q", "N/m"), ("f", "N/m")], BudgetRuns(levels, penalty, record(16, {"q": 1.0, "f": 1.0})))
    row = table.set_index("quantity")
    assert row.loc["q", "penalty_limit"] == pytest.approx(1.0, rel=1e-9)
    assert row.loc["q", "penalty_limit_status"] == "extrapolated"
    assert math.isnan(row.loc["f", "penalty_limit"]) and row.loc["f", "penalty_limit_status"].startswith("not extrapolable")
    assert "divergent" in row.loc["f", "penalty_limit_status"]


def test_a_difference_within_round_off_is_no_difference_to_the_penalty_limit():
    # max theta at c_nu x1, x10, x100 on the strip actuator: x1 and x10 equal, or 1.2e-16 apart
    # by the last bits of the solve; either way one difference is zero: divergent, not oscillatory
    levels = {4: record(4, {"t": 14.0}), 8: record(8, {"t": 14.2}), 16: record(16, {"t": 14.23356})}
    for x10 in (14.23356, 14.23356 * (1 + 1.2e-16), 14.23356 * (1 - 1.2e-16)):
        penalty = {10: record(16, {"t": x10}), 100: record(16, {"t": 13.88})}
        row = budget_table([("t", "K")], BudgetRuns(levels, penalty, record(16, {"t": 14.23356}))).iloc[0]
        assert "divergent" in row["penalty_limit_status"] and "R = e21/e32 = inf" in row["penalty_limit_status"]
