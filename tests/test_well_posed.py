"""A scene whose data cannot fix u (a rigid motion), phi or theta (a constant) is refused when
it loads, with one line and exit code 2, by one rule for the rectangle, the box and gmsh
scenes (harness/scene/well_posed.py). Before the rule only gmsh scenes were checked: a rectangle
with both ends free ran into Newton's maximum (exit 3), the box into a Krylov stall."""

from __future__ import annotations

from pathlib import Path

import pytest

from harness.cli import main
from harness.core.contract import ExitCode
from harness.core.errors import SceneError
from harness.scene.scene import load_scene

ROOT = Path(__file__).parents[1]
PAPER = ROOT / "cases" / "paper.toml"
PAPER3D = ROOT / "cases" / "paper3d.toml"
DATA = ROOT / "tests" / "data"

FREE_ENDS = ['geometry.left="free"', 'geometry.right="free"']
FREE_X_FACES = ['geometry.x0="free"', 'geometry.x1="free"']
# A box held by rollers on its x and y faces, the foundation under z0, and rollers on z1:
# no part where theta = 0 or phi = 0.
ROLLER_BOX = ['geometry.x0="roller_x"', 'geometry.x1="roller_x"', 'geometry.y0="roller_y"', 'geometry.y1="roller_y"',
              'geometry.z0="contact"', 'geometry.z1="roller_z"']

REFUSED = {
    "rectangle, both ends free, plain elasticity": (PAPER, [*FREE_ENDS, "scene.effects=[]"], "u is not fixed"),
    "rectangle, both ends free, contact without friction": (PAPER, [*FREE_ENDS, 'scene.effects=["contact"]'],
                                                           "u is not fixed"),
    "rectangle, both ends free, Tresca friction with S = 0": (
        PAPER, [*FREE_ENDS, 'scene.effects=["contact", "friction"]', "contact.S=0"], "u is not fixed"),
    "rectangle, both ends free, Coulomb friction with mu = 0": (
        PAPER, [*FREE_ENDS, 'scene.effects=["contact", "friction"]', 'contact.friction_law="coulomb"'],
        "u is not fixed"),
    "rectangle, rollers along y only": (PAPER, ['geometry.left="roller_y"', 'geometry.right="roller_y"',
                                               "scene.effects=[]"], "u is not fixed"),
    "rectangle, phi with no Dirichlet part and no conductance": (
        PAPER, ['geometry.left="roller_x"', 'geometry.right="roller_x"',
                'scene.effects=["piezoelectric", "contact", "friction"]'], "phi is defined only up to a constant"),
    "rectangle, phi with k_e = 0": (PAPER, [*FREE_ENDS, "electric_contact.k_e=0"],
                                    "phi is defined only up to a constant"),
    "box, both x faces free, plain elasticity": (PAPER3D, [*FREE_X_FACES, "scene.effects=[]"], "u is not fixed"),
    "box, rollers on x and y only": (DATA / "block3d.toml", ["scene.effects=[]"], "u is not fixed"),
    "box, theta with no Dirichlet part and no conductance": (
        PAPER3D, [*ROLLER_BOX, 'scene.effects=["thermal", "contact"]'], "theta is defined only up to a constant"),
    "gmsh, tilted contact without friction": (DATA / "tilted_block.toml",
                                               ['scene.effects=["piezoelectric", "thermal", "contact", '
                                                '"electric_contact", "thermal_contact"]'], "u is not fixed"),
    "gmsh, phi with k_e = 0": (DATA / "tilted_block.toml", ["electric_contact.k_e=0"],
                               "phi is defined only up to a constant"),
}

HELD = {
    "rectangle, both ends free, friction holds it": (PAPER, FREE_ENDS),
    "rectangle, rollers along x and y": (PAPER, ['geometry.left="roller_x"', 'geometry.right="roller_y"',
                                                 "scene.effects=[]"]),
    "box, rollers on x and y, the foundation's normal along z": (DATA / "block3d.toml", []),
    "box, theta fixed by the thermal contact": (
        PAPER3D, [*ROLLER_BOX, 'scene.effects=["thermal", "contact", "thermal_contact"]']),
    "gmsh, a free block on the foundation with friction": (DATA / "tilted_block.toml", []),
}


@pytest.mark.parametrize("name", list(REFUSED))
def test_a_scene_that_cannot_fix_a_field_is_refused_naming_it(name):
    case, overrides, words = REFUSED[name]
    with pytest.raises(SceneError, match=words) as info:
        load_scene(case, overrides)
    assert str(info.value).startswith(f"{case}: geometry: ") and "\n" not in str(info.value)


@pytest.mark.parametrize("name", list(HELD))
def test_a_scene_whose_data_fix_every_field_loads(name):
    case, overrides = HELD[name]
    load_scene(case, overrides)


@pytest.mark.parametrize("case, overrides", [(PAPER, [*FREE_ENDS, "scene.effects=[]"]),
                                             (PAPER3D, [*FREE_X_FACES, "scene.effects=[]"])])
def test_the_refusal_is_exit_2_with_one_line_before_anything_runs(tmp_path, capsys, case, overrides):
    sets = [word for item in overrides for word in ("--set", item)]
    code = main(["solve", str(case), "--n", "2", "--results", str(tmp_path / "results"), *sets])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == ExitCode.INPUT == 2
    assert len(err) == 1 and err[0].startswith("error:") and "u is not fixed" in err[0], err
    assert not (tmp_path / "results").exists()


def test_a_body_that_only_slipping_friction_holds_fails_with_one_line_saying_so(tmp_path, capsys):
    """The rule above accepts the paper's scene with both ends free (friction holds it), but
    at S = 8.5 every contact node slips under the contact's heating: nothing holds the body
    along the contact and Newton cannot settle a slide (exit 3). The one error line says why
    and what would hold it (freefem/newton.idp, docs/geometry.md); at S = 50 the middle node
    sticks and the same scene converges."""
    sets = [word for item in FREE_ENDS for word in ("--set", item)]
    code = main(["solve", str(PAPER), "--n", "2", "--results", str(tmp_path / "slips"), *sets])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == ExitCode.RUN == 3
    assert len(err) == 1 and err[0].startswith("error:"), err
    assert "every contact node slips" in err[0] and "clamp a part, add rollers or raise the slip bound" in err[0]
    held = main(["solve", str(PAPER), "--n", "2", "--results", str(tmp_path / "sticks"), *sets, "--set", "contact.S=50"])
    assert held == ExitCode.OK


# The BLAS kernels this project's machines run OpenBLAS with: its own choice (unset), and the two
# that machines of this kind force with OPENBLAS_CORETYPE (both run on any x86-64 with AVX2).
KERNELS = ("", "Haswell", "Sandybridge")


@pytest.mark.parametrize("kernel", KERNELS)
def test_a_converged_slide_that_any_shift_also_solves_is_refused_not_returned(tmp_path, capsys, monkeypatch, kernel):
    """At n = 8 from zero the free-ended paper scene converges with every quadrature point of Gamma_3
    slipping (|c_nu u_tau| >= S: 8.50 and 13.7 N/m^2 nearest the bound): any rigid shift along x that
    keeps each point's slip direction solves it too, so the run exits 3 naming that; at n = 16 two
    points stick (every node still slips) and there is one solution, returned. The verdict is the
    translation's (freefem/rigid_slide.idp), the same under every BLAS kernel: before, the default
    kernel gave this exit, Haswell's converged at the family's end (exit 0) and Sandybridge's hit
    Newton's maximum, each from the round-off the singular tangent made of the slide."""
    monkeypatch.setenv("OPENBLAS_CORETYPE", kernel)
    sets = [word for item in FREE_ENDS for word in ("--set", item)]
    zero = ["--set", 'scene.initial_guess="zero"']
    code = main(["solve", str(PAPER), "--n", "8", "--results", str(tmp_path / "n8"), *sets, *zero])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == ExitCode.RUN
    assert len(err) == 1 and "not unique" in err[0] and "any slide along it is a solution too" in err[0], err
    # The family's width, c_nu times the slides that keep every point slipping: 5.2 N/m^2, as the
    # Gauss points nearest their bound give it (8.50 - 8.5 on one side, 13.7 - 8.5 on the other).
    import json
    hint = json.loads((tmp_path / "n8" / "paper" / "n8.failed" / "run.json").read_text())["failure_hint"]
    width = float(hint.split("over an interval ")[1].split()[0])
    assert width == pytest.approx(5.176, abs=2e-3), hint
    assert not (tmp_path / "n8" / "paper" / "n8").exists()
    held = main(["solve", str(PAPER), "--n", "8", "--results", str(tmp_path / "S50"), *sets, *zero,
                 "--set", "contact.S=50"])
    assert held == ExitCode.OK


def test_a_balance_where_nothing_flows_out_is_judged_against_newtons_residual(tmp_path):
    """The free-ended paper scene at n = 16 (from zero) has no phi Dirichlet part: no charge can
    leave, so the charge let in through Gamma_3 is Newton's final residual alone (2.9e-12 C/m at
    newton.rtol = 1e-9), 2.9e-7 of the flow's 1e-5 C/m floor. Against the 1e-8 tolerance alone that
    failed; the balance is judged as the force balance is, within twice the Cauchy-Schwarz bound of
    the final residual's sum (harness/measure/checks.py), and passes."""
    import json

    from harness.measure.checks import TOLERANCES, physical_checks
    from harness.run.record import read_run_json

    sets = [word for item in FREE_ENDS for word in ("--set", item)]
    code = main(["solve", str(PAPER), "--n", "16", "--results", str(tmp_path), *sets,
                 "--set", 'scene.initial_guess="zero"'])
    assert code == ExitCode.OK
    level = tmp_path / "paper" / "n16"
    checks = physical_checks(read_run_json(level), load_scene(PAPER, FREE_ENDS))
    assert checks["charge_ok"] and checks["charge_imbalance"] > TOLERANCES["charge"][0]
    assert checks["charge_imbalance"] <= TOLERANCES["force"][0] * checks["charge_residual_bound"]
    assert 0 < json.loads((level / "run.json").read_text())["checks"]["heat_residual_bound"]


def test_a_field_that_nothing_determines_at_the_start_sends_newton_to_the_determined_state(tmp_path):
    """A block held by rollers between walls, heated through its contact (tests/data/heated_walls.toml):
    from zero the start solves the equations (u = 0, theta = 0, no conductance at zero penetration),
    and before it was returned with every check passing. Nothing but the conductance fixes theta, and
    it is zero there, so Newton restarts from the pressed state and returns the heated one: theta =
    theta_f = 100 K everywhere, as the pressed start gives it."""
    import json

    case = DATA / "heated_walls.toml"
    assert main(["solve", str(case), "--n", "4", "--results", str(tmp_path / "zero")]) == ExitCode.OK
    assert main(["solve", str(case), "--n", "4", "--results", str(tmp_path / "pressed"),
                 "--set", 'scene.initial_guess="pressed"']) == ExitCode.OK
    zero = json.loads((tmp_path / "zero" / "heated_walls" / "n4" / "run.json").read_text())
    pressed = json.loads((tmp_path / "pressed" / "heated_walls" / "n4" / "run.json").read_text())
    assert zero["restarted_at"] > 0
    assert zero["min_theta"] == pytest.approx(100, rel=1e-9) and zero["max_theta"] == pytest.approx(100, rel=1e-9)
    assert zero["contact_force"] == pytest.approx(pressed["contact_force"], rel=1e-8)
    assert zero["contact_force"] > 0


def test_a_field_that_nothing_determines_at_any_solution_is_refused_not_returned(tmp_path, capsys, monkeypatch):
    """The same walls over a cooled foundation (theta_f = -100 K): the block contracts off it, the
    contact opens, and every theta <= 0 that keeps it open is a solution. From zero Newton converges
    at once where nothing determines theta (u = 0, theta = 0), restarts from the pressed state, and
    whatever it does there (under OPENBLAS_CORETYPE=Sandybridge it cycled: the contact opens, theta's
    constant is free in the tangent again), the answer is the family found: exit 3, one line naming
    theta, on every kernel. From the pressed state no state is ever returned (there is no determined
    one): exit 3, its reason the path's."""
    case = DATA / "heated_walls.toml"
    for kernel in KERNELS:
        monkeypatch.setenv("OPENBLAS_CORETYPE", kernel)
        for start in ("zero", "pressed"):
            out = tmp_path / f"{start}{kernel}"
            code = main(["solve", str(case), "--n", "4", "--results", str(out),
                         "--set", "thermal_contact.theta_f=-100", "--set", f'scene.initial_guess="{start}"'])
            err = capsys.readouterr().err.strip().splitlines()
            assert code == ExitCode.RUN, (kernel, start, err)
            assert len(err) == 1 and err[0].startswith("error:"), err
            if start == "zero":
                assert "not unique" in err[0] and "theta is not determined" in err[0], (kernel, err)
            assert not (out / "heated_walls" / "n4").exists()
