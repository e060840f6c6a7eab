"""Coulomb friction (issue 23): contact.friction_law = "coulomb" bounds the tangential traction
by mu c_nu (u_nu - g)_+ = mu p instead of Tresca's S (freefem/friction.idp, docs/laws.md).
Known answers: a load below mu p sticks, one above it cannot be held, slipping nodes carry
exactly mu p against the slip (2D, and at an angle in 3D), and Newton's tangent is exact
(its bound's derivative in u_nu included): quadratic convergence, lost without it."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from harness.cli import main
from harness.scene.scene import load_scene
from harness.core.errors import SceneError
from harness.run.record import read_run_json
from physics_runs import CASES, DATA, solve

REPO = Path(__file__).parents[1]
MU = 0.3
PRESSURE = 100.0  # the blocks' uniform load = their contact pressure [N/m^2]


def coulomb(mu: float) -> tuple[str, str]:
    return ('contact.friction_law="coulomb"', f"contact.mu={mu}")


def test_a_tangential_load_below_mu_pressure_sticks(tmp_path):
    """The free block (tests/data/block.toml) under 100 N/m^2 with mu = 0.3: a shear of
    0.5 mu p = 15 N/m^2 sticks everywhere and friction carries all of it (the Tresca test's
    answer, with the bound mu p = 30 N/m^2 instead of S)."""
    shear = 0.5 * MU * PRESSURE
    run = solve(DATA / "block.toml", 8, tmp_path, f"loads.traction_x={shear}", *coulomb(MU))
    assert run.record.converged
    assert run.record.slip_nodes[-1] == 0
    # Horizontal equilibrium to Newton's final residual (as the Tresca test: rel 1e-7).
    assert run.record.friction_force == pytest.approx(shear * 2.0, rel=1e-7)
    assert run.record.friction_force_vector == pytest.approx([shear * 2.0, 0.0], rel=1e-7, abs=1e-12)
    # The shear on top tilts the pressure along the bottom (a moment: the bulk reads 57 ... 143
    # N/m^2 at h = 1/8); the check's node is the one nearest its bound, mu times a pressure
    # read there, and it still sticks (measured 15.0 against 17.1).
    checks = run.record.checks
    assert -checks["max_sigma_nu"] <= checks["S"] / MU <= -checks["min_sigma_nu"]
    assert checks["max_abs_sigma_tau"] < checks["S"]


def test_a_tangential_load_above_mu_pressure_cannot_be_held(tmp_path):
    """The same free block with 1.5 mu p = 45 N/m^2: nothing but friction holds it, friction
    holds at most mu p = 30 N/m^2 on average, so no equilibrium exists and the run fails
    (exit code RUN: Newton's iteration limit). With mu = 1 the same load is held, friction
    carrying all of it."""
    shear = 1.5 * MU * PRESSURE
    argv = ["solve", str(DATA / "block.toml"), "--n", "4", "--results", str(tmp_path),
            "--set", f"loads.traction_x={shear}", "--set", 'contact.friction_law="coulomb"']
    assert main(argv + ["--set", f"contact.mu={MU}"]) == 3
    # Exit 1 is allowed: the tilted block lifts a corner node to s = 0, whose open-node heat
    # flux check (theta_f = 0: round-off against round-off) is not what this test is about.
    assert main(argv + ["--set", "contact.mu=1.0", "--set", "scene.name=held"]) in (0, 1)
    held = read_run_json(tmp_path / "held" / "n4")
    assert held is not None and held.converged
    assert held.friction_force == pytest.approx(shear * 2.0, rel=1e-7)


def test_slipping_nodes_carry_mu_pressure_against_the_slip_in_2d(tmp_path):
    """cases/coulomb.toml: the clamped elastic block, a shear of 30 N/m^2, mu = 0.3. The
    pressure varies along Gamma_3 (so this is not Tresca with another S); at every slipping
    node the tangential traction is mu times that node's pressure, opposite to the slip, and
    below it at every sticking node."""
    run = solve(CASES / "coulomb.toml", 16, tmp_path)
    assert run.record.converged
    pts = run.fields.points
    on = np.isclose(pts[:, 1], 0.0) & (pts[:, 0] >= 1.0) & (pts[:, 0] <= 3.0)
    pressure = run.fields.field("contact_pressure")[on]
    shear = run.fields.field("contact_shear")[on]   # along tau = (1, 0) for nu = (0, -1)
    u_tau = run.fields.field("u")[on, 0]
    closed = pressure > 0
    assert pressure[closed].max() > 1.5 * pressure[closed].min()   # measured: 1.7 at h = 1/16
    slipping = 1e7 * np.abs(u_tau) >= MU * pressure
    assert 0 < (slipping & closed).sum() < closed.sum()           # measured 7 of 33 at h = 1/16
    assert run.record.slip_nodes[-1] == slipping.sum()
    # The projection on the ball of radius mu p: exact to round-off on slipping nodes.
    np.testing.assert_allclose(shear[slipping], MU * pressure[slipping] * np.sign(u_tau[slipping]), rtol=1e-12)
    assert np.all(np.abs(shear[~slipping]) < MU * pressure[~slipping])
    assert run.record.checks["max_abs_sigma_tau"] <= run.record.checks["S"] * (1 + 1e-6)


def test_a_load_beyond_mu_pressure_slips_at_mu_pressure_off_axis_in_3d(tmp_path):
    """block3d with rollers on x = 0 and y = 0 holding what friction cannot, a shear (8.66, 5)
    N/m^2 at 30 degrees and mu = 1e-6, so mu p ~ 1e-4 N/m^2 (p ~ 100) is far below it: the
    bottom slips with |sigma_tau| = mu |sigma_nu| at each node, in directions that follow the
    elastic displacement, off every axis: the disc of radius mu p, not two 1D clamps."""
    mu = 1e-6
    faces = dict(zip(("x0", "x1", "y0", "y1"), ("roller_x", "free", "roller_y", "free")))
    # (contact.S: a friction scene's required key, which Coulomb does not use.)
    run = solve(DATA / "block3d.toml", 4, tmp_path, "scene.name=coulomb3d", 'scene.effects=["contact", "friction"]',
                *coulomb(mu), "contact.S=0", "loads.traction_x=8.66", "loads.traction_y=5.0",
                *(f'geometry.{face}="{role}"' for face, role in faces.items()))
    assert run.record.converged
    bottom = np.isclose(run.fields.points[:, 2], 0.0)
    pressure = run.fields.field("contact_pressure")[bottom]
    shear = run.fields.field("contact_shear")[bottom]   # |P_B(c_nu u_tau)| in 3D
    slipping = shear > 0.5 * mu * PRESSURE
    assert slipping.sum() >= 20  # of 25 bottom nodes (measured 24: all but the corner on both rollers)
    assert shear[slipping] == pytest.approx(mu * pressure[slipping], rel=1e-9)
    assert pressure[slipping] == pytest.approx(np.full(slipping.sum(), PRESSURE), rel=0.05)
    u = run.fields.field("u")[bottom][slipping]
    angles = np.degrees(np.arctan2(u[:, 1], u[:, 0]))
    off_axis = (np.abs(angles % 90) > 10) & (np.abs(angles % 90) < 80)
    assert off_axis.sum() >= 10, angles
    # From the bulk: a nodal traction averages the law's over the node's hat function, where
    # the slip direction turns, so |sigma_tau| <= mu |sigma_nu| with near equality at the node
    # nearest its bound (measured 0.9988 of it).
    checks = run.record.checks
    assert 0.99 * checks["S"] <= checks["max_abs_sigma_tau"] <= checks["S"] * (1 + 1e-6)
    assert checks["S"] == pytest.approx(mu * PRESSURE, rel=0.05)


def increments(directory: Path) -> list[float]:
    return json.loads((directory / "run.json").read_text())["increments"]["u"]


@pytest.mark.parametrize("case, n", [("paper", 8), ("paper3d", 4)])
def test_the_tangent_is_exact_with_the_bounds_derivative(tmp_path, case, n):
    """The paper's scene (2D, and its 3D block) under a shear of 1e5 N/m^2 with mu = 0.5: most
    of Gamma_3 slips, where the bound mu c_nu (u_nu - g)_+ moves with u_nu. With its
    derivative in the tangent (forms.idp frictionT) Newton converges quadratically; without it
    (a copy of the law file with dSlipBound = 0) linearly. Measured increments of u:
    2D h = 1/8: 0.13, 2e-7, 1.5e-14 against 0.13, 4e-6, 1e-10;
    3D h = 1/4: 0.48, 0.029, 1.2e-8, 4.3e-15 against 0.48, 0.029, 1.3e-6, 7.4e-11.
    The last step of the exact tangent is at round-off, where the other is 1e4 above it."""
    overrides = ["--set", "loads.traction_x=1e5", "--set", 'contact.friction_law="coulomb"', "--set", "contact.mu=0.5"]
    argv = ["solve", str(CASES / f"{case}.toml"), "--n", str(n), *overrides]
    exact = tmp_path / "exact"
    assert main(argv + ["--results", str(exact)]) == 0
    scripts = tmp_path / "freefem"
    shutil.copytree(REPO / "freefem", scripts)
    law = scripts / "friction.idp"
    text = law.read_text()
    spelled = "macro dSlipBound(p, dp) (slipMu0 * dp) //"
    assert spelled in text, "friction.idp no longer spells Coulomb's dSlipBound: update this test"
    law.write_text(text.replace(spelled, "macro dSlipBound(p, dp) (0. * dp) //"))
    inexact = tmp_path / "inexact"
    assert main(argv + ["--results", str(inexact), "--freefem", str(scripts)]) == 0
    a, b = increments(exact / case / f"n{n}"), increments(inexact / case / f"n{n}")
    assert a[1] > 1e-2 and b[1] > 1e-2        # the same first step from the level below
    assert len(b) >= len(a) and a[-1] < 1e-12 < b[len(a) - 1], (a, b)


def test_tresca_ignores_mu_and_is_the_default(tmp_path):
    """friction_law = "tresca" with any mu is the default law: the same run.json numbers."""
    plain = solve(CASES / "paper.toml", 4, tmp_path / "a")
    explicit = solve(CASES / "paper.toml", 4, tmp_path / "b", 'contact.friction_law="tresca"', "contact.mu=0.7")
    assert explicit.record.residuals == plain.record.residuals
    assert explicit.record.checks == plain.record.checks
    assert explicit.record.friction_force == plain.record.friction_force


@pytest.mark.parametrize("override, named", [('contact.friction_law="amontons"', "contact.friction_law"),
                                             ("contact.mu=-0.1", "contact.mu")])
def test_a_bad_friction_law_or_coefficient_is_named(override, named):
    with pytest.raises(SceneError, match=named.replace(".", r"\.")):
        load_scene(CASES / "coulomb.toml", [override])


def test_mu_without_friction_is_ignored_with_a_warning():
    scene = load_scene(CASES / "coulomb.toml", ['scene.effects=["contact"]'])
    assert "contact.mu is ignored: effect 'friction' is off" in scene.warnings
    assert "mu" not in scene.solver_parameters()["contact"]
    assert math.isclose(load_scene(CASES / "coulomb.toml").solver_parameters()["contact"]["mu"], MU)
