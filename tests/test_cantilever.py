"""The tutorial's first device (cases/cantilever.toml, docs/tutorial.md): a 20 x 1 mm PZT-5H
cantilever at 50 V whose free end presses on an earthed stop with Coulomb friction.

- it converges at a coarse level with every physical check passing and no warning;
- an open gap (a legitimate outcome) passes every check with exit 0: the checks' scales have
  a round-off floor (harness/measure/checks.py floor), where they divided round-off by round-off
  (`FAIL sigma_nu ... open_flux ... charge_flux_open_error 1`);
- Coulomb's bound is zero at an open node: |sigma_tau| of ~1e-8 N/m^2 read there is round-off,
  not friction beyond the bound;
- with Tresca and a 1 um gap the contact never closes, yet Tresca's S grips the free end:
  one warning line says so, with the friction and the contact force, and suggests Coulomb.
"""

from __future__ import annotations

import json
import math

import pytest

from harness.measure.checks import physical_checks
from harness.cli import main
from harness.run.record import RunRecord
from harness.scene.scene import load_scene
from physics_runs import CASES

CANTILEVER = CASES / "cantilever.toml"
OPEN = ("--set", "contact.gap=1e-6")   # over 3 times the free end's travel (~0.3 um)
TRESCA = ("--set", "contact.friction_law=tresca", "--set", "contact.S=1e5")


def solve(capsys, tmp_path, n: int, *overrides: str) -> tuple[int, str, list[str], dict]:
    code = main(["solve", str(CANTILEVER), "--n", str(n), "--results", str(tmp_path), *overrides])
    captured = capsys.readouterr()
    run = json.loads((tmp_path / "cantilever" / f"n{n}" / "run.json").read_text())
    return code, captured.out, captured.err.strip().splitlines(), run


def warnings(err: list[str]) -> list[str]:
    return [line for line in err if line.startswith("warning:")]


def test_the_cantilever_converges_with_coulomb_and_every_check_passing(capsys, tmp_path):
    code, out, err, run = solve(capsys, tmp_path, 4)
    assert code == 0, err
    assert "checks n=4: pass (force, sigma_nu, sigma_tau, open_flux, heat, charge)" in out
    assert warnings(err) == [] and "warnings" not in run
    # The free end, 1 mm, all closed; Coulomb keeps the friction within mu times the contact force.
    assert run["active_measure"] == pytest.approx(1e-3, rel=1e-12)
    assert 0 < run["friction_total"] <= 0.5 * run["contact_force"] * (1 + 1e-9)
    assert run["friction_open"] == 0


def test_an_open_gap_passes_every_check(capsys, tmp_path):
    code, out, err, run = solve(capsys, tmp_path, 8, *OPEN)
    assert code == 0, err
    assert "checks n=8: pass (force, sigma_nu, sigma_tau, open_flux, heat, charge)" in out
    assert run["active_measure"] == 0 and run["contact_force"] == 0
    assert warnings(err) == []   # Coulomb: no friction where nothing presses


def test_tresca_with_an_open_gap_warns_in_one_line_with_both_numbers(capsys, tmp_path):
    code, out, err, run = solve(capsys, tmp_path, 4, *OPEN, *TRESCA)
    assert code == 0, err
    assert "checks n=4: pass" in out   # the law allows it: only the warning tells
    [line] = warnings(err)
    friction, contact = run["friction_total"], run["contact_force"]
    assert contact == 0 and friction > 0 and run["friction_open"] == pytest.approx(friction, rel=1e-12)
    assert line.startswith("warning: cantilever n=4: Tresca friction ")
    assert f"friction {friction:.3g} N/m against a contact force of {contact:.3g} N/m" in line
    assert "where the contact is open" in line and 'contact.friction_law = "coulomb"' in line
    assert run["warnings"] == [line.removeprefix("warning: ")]


def test_tresca_within_the_contact_force_on_a_closed_contact_does_not_warn(capsys, tmp_path):
    """The committed strip actuator's kind: the whole free end closed, S below mu p."""
    code, out, err, run = solve(capsys, tmp_path, 2, *TRESCA)
    assert code == 0, err
    assert run["active_measure"] == pytest.approx(1e-3, rel=1e-12) and run["friction_total"] < run["contact_force"]
    assert warnings(err) == []


def record(**checks: float) -> RunRecord:
    base = {"applied_load": [0.0, 0.0], "clamp_reaction": [0.0, 0.0], "contact_force_on_body": [0.0, 0.0],
            "force_imbalance": 0.0, "force_residual_bound": 1.0, "max_sigma_nu": -1.0, "min_sigma_nu": -1.0,
            "max_abs_sigma_tau": 0.0, "S": 0.0, "traction_reading": 1e9}
    return RunRecord(n=8, checks={**base, **checks})


def test_coulomb_round_off_at_an_open_node_is_not_friction_beyond_the_bound():
    """The reported `FAIL sigma_tau sigma_tau_excess 2.79e-06`: both sides ~1e-7 N/m^2 at a
    node, against nodal readings of ~1e9 N/m^2 (the cantilever's)."""
    scene = load_scene(CANTILEVER)
    values = physical_checks(record(max_abs_sigma_tau=1.00000279e-7, S=1e-7, max_sigma_nu=-1e-7, min_sigma_nu=-1e-7),
                             scene)
    assert values["sigma_tau_ok"] and values["sigma_nu_ok"]


@pytest.mark.parametrize("checks, flag", [
    # friction 1e-3 above a bound of 1e5 N/m^2: far above round-off
    ({"max_abs_sigma_tau": 1.001e5, "S": 1e5, "max_sigma_nu": -5e5, "min_sigma_nu": -5e5}, "sigma_tau_ok"),
    # a tensile traction of 1e-11 of the readings: 45 times the floor's allowance (1000 eps)
    ({"max_sigma_nu": 1e-2}, "sigma_nu_ok"),
])
def test_the_floor_still_fails_what_round_off_cannot_explain(checks, flag):
    values = physical_checks(record(**checks), load_scene(CANTILEVER))
    assert not values[flag] and math.isfinite(values["sigma_nu_scale"])


def test_a_failing_check_names_what_to_try(tmp_path):
    from harness.run.run import RunResult
    from harness.measure.run_checks import check_run

    failing = record(max_sigma_nu=1e-2)
    checked = check_run(load_scene(CANTILEVER), RunResult(8, tmp_path, failing, reused=True))
    assert not checked.passed
    assert "FAIL sigma_nu max_sigma_nu 0.01" in checked.line and "(try: tighten newton.rtol" in checked.line


def test_a_study_records_the_tresca_warning_of_each_level_in_its_summary(capsys, tmp_path):
    code = main(["convergence", str(CANTILEVER), "--levels", "2,4,8", "--results", str(tmp_path),
                 *OPEN, *TRESCA, "--set", "study.slope_band=[-100, 100]"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 0, err
    summary = json.loads((tmp_path / "cantilever" / "summary.json").read_text())
    for n in (2, 4, 8):
        [line] = summary["runs"][str(n)]["warnings"]
        assert line.startswith(f"cantilever n={n}: Tresca friction ") and f"warning: {line}" in err


def test_the_device_picture_of_a_scene_without_heat(capsys, tmp_path):
    """The cantilever has no theta: the picture shows phi and |u| (it failed: no field 'theta')."""
    from harness.report.device_plot import render

    solve(capsys, tmp_path, 2)
    render(tmp_path / "cantilever" / "n2", tmp_path / "fields.png")
    assert (tmp_path / "fields.png").stat().st_size > 10_000
