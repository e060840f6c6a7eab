"""Floating electrodes (role `floating`, loads.floating_charge): the part's phi is uniform and
unknown and its net free charge given, solved by an exact elimination (freefem/floating.idp).
Known answers: the plate formula on a layer with a given charge, the midpoint potential of an
uncharged electrode by symmetry, and the open-circuit voltage of a pressed layer (the force
sensor), each exact for P1 (uniform or symmetric fields), so checked to round-off."""

from __future__ import annotations

import numpy as np
import pytest

from harness.cli import main
from harness.core.contract import ExitCode
from harness.measure.fields import read_state
from physics_runs import DATA, solve

# PZT-5H (freefem/materials/PZT-5H.idp): the constants the exact solutions need.
C33, E33, BETA33 = 11.7e10, 23.3, 1.301565607e-8
# The permittivity of a layer held laterally (u_x = 0) and free along its poling axis.
EPS = BETA33 + E33**2 / C33


def on_part(points: np.ndarray, n: int, y: float, x0: float, x1: float) -> np.ndarray:
    """The nodes of the side y = const between x0 and x1 (coordinates are multiples of 1/n)."""
    xs, ys = (np.round(points[:, i].astype(float) * n) / n for i in (0, 1))
    return (ys == y) & (xs >= x0) & (xs <= x1)


@pytest.mark.parametrize("n", [2, 4])
def test_a_charged_floating_electrode_holds_the_plate_formula_potential(tmp_path, n):
    run = solve(DATA / "floating_layer.toml", n, tmp_path)
    checks = run.record.checks
    charge, width, thickness = 3.5e-6, 2.0, 1.0
    exact = charge * thickness / (EPS * width)   # V = Q t / (eps A): 99.12 V
    # The field is uniform, so P1 is exact: measured 3e-16 relative at n = 2 and 4.
    assert checks["floating_potential"][0] == pytest.approx(exact, rel=1e-10)
    u, phi = read_state(tmp_path / "floating_layer" / f"n{n}" / "state.txt")
    y = np.round(run.fields.points[:, 1].astype(float) * n) / n
    assert phi == pytest.approx(exact * y / thickness, abs=1e-10 * exact)
    # The charge read from the residual is the given one, and the check says so.
    assert checks["floating_charge"][0] == pytest.approx(charge, rel=1e-10)
    assert checks["floating_charge_given"][0] == charge
    # All of it leaves through the earthed base (the charge balance's source).
    assert checks["charge_out_dirichlet"] == pytest.approx(charge, rel=1e-10)
    assert checks["charge_source"] == charge


def test_the_floating_potential_is_linear_in_the_charge(tmp_path):
    """Q = 0 leaves the layer unloaded; -2Q gives -2V exactly."""
    zero = solve(DATA / "floating_layer.toml", 2, tmp_path, "loads.floating_charge=0", "scene.name=zero")
    assert zero.record.max_abs_u == 0.0 and zero.record.checks["floating_potential"][0] == 0.0
    minus = solve(DATA / "floating_layer.toml", 2, tmp_path, "loads.floating_charge=-7e-6", "scene.name=minus")
    assert minus.record.checks["floating_potential"][0] == pytest.approx(-7e-6 / (EPS * 2.0), rel=1e-10)


@pytest.mark.parametrize("n", [2, 4])
def test_an_uncharged_floating_electrode_midway_holds_half_the_drive(tmp_path, n):
    """The half-turn symmetry of floating_symmetric.toml gives V/2 exactly; the electrode's
    nodes all hold it, where the same parts left free do not."""
    run = solve(DATA / "floating_symmetric.toml", n, tmp_path)
    _, phi = read_state(tmp_path / "floating_symmetric" / f"n{n}" / "state.txt")
    parts = on_part(run.fields.points, n, 0.0, 0.5, 1.5) | on_part(run.fields.points, n, 1.0, 0.5, 1.5)
    # Round-off of the symmetric discrete problem: measured <= 3e-14 V.
    assert run.record.checks["floating_potential"][0] == pytest.approx(50.0, abs=1e-10)
    assert phi[parts] == pytest.approx(np.full(parts.sum(), 50.0), abs=1e-10)
    assert abs(run.record.checks["floating_charge"][0]) < 1e-12 * EPS * 100.0
    free = solve(DATA / "floating_symmetric.toml", n, tmp_path, "scene.name=free",
                 'geometry.bottom=[[0.0, 0.5, "roller_x"], [0.5, 1.5, "free"], [1.5, 2.0, "roller_y"]]',
                 'geometry.top=[[0.0, 0.5, "roller_y"], [0.5, 1.5, "free"], [1.5, 2.0, "roller_x"]]')
    _, phi_free = read_state(tmp_path / "free" / f"n{n}" / "state.txt")
    assert np.ptp(phi_free[parts]) > 10.0   # the drive's field runs along them: ~50 V


def exact_sensor_voltage(pressure: float, thickness: float) -> float:
    """Open circuit (D3 = 0) of a laterally held layer under sigma33 = -p (floating_sensor.toml)."""
    return -E33 * pressure * thickness / (C33 * BETA33 + E33**2)


@pytest.mark.parametrize("case, n", [("floating_sensor", 2), ("floating_sensor", 4), ("floating_sensor3d", 2)])
def test_a_pressed_layer_with_an_open_electrode_gives_the_sensor_voltage(tmp_path, case, n):
    run = solve(DATA / f"{case}.toml", n, tmp_path)
    checks = run.record.checks
    exact = exact_sensor_voltage(1.0e4, 1.0)   # -112.8 V
    # Uniform field, P1 exact: measured 1e-15 relative (2D n = 2, 4; 3D n = 2).
    assert checks["floating_potential"][0] == pytest.approx(exact, rel=1e-10)
    # The textbook plate formula V = g33 t F / A (laterally free, g33 = d33 / eps33^T =
    # 19.7e-3 V m/N for PZT-5H: Morgan Electro Ceramics' data as in the material file) has
    # the same sign convention and order: the laterally held layer is stiffer electrically.
    g33_textbook = 593e-12 / (3400 * 8.854e-12)
    ratio = checks["floating_potential"][0] / (-g33_textbook * 1.0e4 * 1.0)
    assert 0.5 < ratio < 1.0
    # The given charge (0) on the electrode to round-off of the terms its reading sums.
    assert abs(checks["floating_charge"][0]) <= 1e-12 * checks["floating_charge_reading"][0]


def one_error_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.startswith("error:")]
    assert len(lines) == 1, err
    return lines[0]


def test_a_floating_electrode_touching_an_earthed_part_is_refused_with_one_line(tmp_path, capsys):
    """Two conditions at one node: the floating top meets a clamped side."""
    code = main(["solve", str(DATA / "floating_layer.toml"), "--n", "2", "--results", str(tmp_path),
                 "--set", 'geometry.left="clamped"'])
    line = one_error_line(capsys.readouterr().err)
    assert code == ExitCode.INPUT
    assert "floating electrode" in line and "fixed potential" in line
    assert not (tmp_path / "floating_layer" / "n2" / "run.json").exists()


@pytest.mark.parametrize("override, words", [
    ("loads.floating_charge=1e-6", ("loads.floating_charge", "no boundary part")),
    ('run.linear_solver="petsc"', ("run.linear_solver", "one rank")),
    ("run.ranks=2", ("run.ranks = 2", "one rank")),
])
def test_a_floating_charge_or_solver_it_cannot_use_is_refused_with_one_line(tmp_path, capsys, override, words):
    case = "layer.toml" if override.startswith("loads") else "floating_layer.toml"
    code = main(["solve", str(DATA / case), "--n", "2", "--results", str(tmp_path), "--set", override])
    line = one_error_line(capsys.readouterr().err)
    assert code == ExitCode.INPUT
    assert all(word in line for word in words), line


def test_a_floating_electrode_needs_the_potential(tmp_path, capsys):
    code = main(["solve", str(DATA / "floating_sensor.toml"), "--n", "2", "--results", str(tmp_path),
                 "--set", 'scene.effects=["thermal"]'])
    line = one_error_line(capsys.readouterr().err)
    assert code == ExitCode.INPUT and "floating" in line and "piezoelectric" in line


def test_only_a_scene_with_a_floating_part_compiles_the_elimination():
    """Scenes without the role compile to the scheme they had (no FLOATING macro: every hook of
    freefem/floating.idp is empty)."""
    from harness.scene.floating import floating_macros
    from harness.scene.scene import load_scene
    assert floating_macros(load_scene(DATA / "layer.toml").geometry) == {}
    assert floating_macros(load_scene(DATA / "floating_layer.toml").geometry) == {"FLOATING": "1"}
    assert floating_macros(load_scene(DATA / "floating_sensor3d.toml").geometry) == {"FLOATING": "1"}


def test_a_floating_electrode_on_the_contact_scene_is_the_driven_one_of_its_own_potential(tmp_path):
    """With contact, friction and heat (the paper's scene, its top's middle floating with no
    charge, pressed by its weight): an electrode driven at the floating potential found gives the same
    state and carries no charge, the nonlinear case's known answer."""
    top = 'geometry.top=[[0.0, 1.0, "free"], [1.0, 3.0, "{}"], [3.0, 4.0, "free"]]'
    floating = solve(DATA / "paper.toml", 4, tmp_path, top.format("floating"), "loads.traction_y=0", "loads.body_force_y=-50",
                     "scene.name=open")
    potential = floating.record.checks["floating_potential"][0]
    assert floating.record.contact_force > 0 and abs(potential) > 1.0   # the contact and the field act
    assert floating.record.checks["floating_charge"][0] == pytest.approx(0.0, abs=1e-12 * floating.record.checks["floating_charge_reading"][0])
    driven = solve(DATA / "paper.toml", 4, tmp_path, top.format("electrode"), "loads.traction_y=0", "loads.body_force_y=-50",
                   f"loads.electrode_potential={potential!r}", "scene.name=driven")
    # Both converged quadratically past newton.rtol = 1e-9, so round-off is left: measured
    # <= 1.2e-14 of each field and 1.5e-17 of the charge's reading at n = 4, 8 (V = -12.5, -14.1 V);
    # 1e-11 leaves room for another sparse solver's pivoting.
    reading = driven.record.checks["charge_reading"]
    assert abs(driven.record.checks["electrode_charge"]) < 1e-11 * reading
    u_open, phi_open, theta_open = read_state(tmp_path / "open" / "n4" / "state.txt")
    u_driven, phi_driven, theta_driven = read_state(tmp_path / "driven" / "n4" / "state.txt")
    assert u_driven == pytest.approx(u_open, abs=1e-11 * np.abs(u_open).max())
    assert phi_driven == pytest.approx(phi_open, abs=1e-11 * np.abs(phi_open).max())
    assert theta_driven == pytest.approx(theta_open, abs=1e-11 * np.abs(theta_open).max())


def test_two_floating_electrodes_are_reciprocal_and_superpose(tmp_path):
    """floating_pair.toml: the potential a charge on one electrode raises on the other is the
    same both ways (the elastance matrix of a self-adjoint problem is symmetric), and both
    charges together give the sum of the two states; each electrode keeps its own charge."""
    q = 1.0e-6
    one = solve(DATA / "floating_pair.toml", 4, tmp_path).record.checks
    two = solve(DATA / "floating_pair.toml", 4, tmp_path, "loads.floating_charge=0", f"loads.floating_charge_2={q}",
                "scene.name=second").record.checks
    both = solve(DATA / "floating_pair.toml", 4, tmp_path, f"loads.floating_charge_2={q}", "scene.name=both").record.checks
    assert len(one["floating_potential"]) == 2 and one["floating_charge_given"] == [q, 0.0]
    # Measured 2e-16 relative (n = 4): the discrete problem is symmetric too.
    assert one["floating_potential"][1] == pytest.approx(two["floating_potential"][0], rel=1e-10)
    assert one["floating_potential"][1] > 0   # the other electrode is not a copy: 16.3 V against 47.0 V
    assert one["floating_potential"][1] < 0.5 * one["floating_potential"][0]
    for k in (0, 1):
        assert both["floating_potential"][k] == pytest.approx(one["floating_potential"][k] + two["floating_potential"][k],
                                                              rel=1e-10)
        assert both["floating_charge"][k] == pytest.approx(q, rel=1e-10)


def test_two_floating_electrodes_sharing_a_node_are_refused_with_one_line(tmp_path, capsys):
    code = main(["solve", str(DATA / "floating_pair.toml"), "--n", "4", "--results", str(tmp_path), "--set",
                 'geometry.top=[[0.0, 1.0, "floating"], [1.0, 2.0, "floating_2"]]'])
    line = one_error_line(capsys.readouterr().err)
    assert code == ExitCode.INPUT and "two floating electrodes share a node" in line


def test_a_charge_for_an_electrode_the_scene_lacks_is_refused_with_one_line(tmp_path, capsys):
    code = main(["solve", str(DATA / "floating_layer.toml"), "--n", "2", "--results", str(tmp_path), "--set",
                 "loads.floating_charge_3=1e-6"])
    line = one_error_line(capsys.readouterr().err)
    assert code == ExitCode.INPUT and "loads.floating_charge_3" in line and "'floating_3'" in line


@pytest.mark.parametrize("n", [2, 4])
def test_a_laterally_free_pressed_plate_gives_the_textbook_plate_formula(tmp_path, n):
    """floating_free_sensor3d.toml: a free slab pressed through an uncharged floating electrode
    onto an earthed frictionless foundation holds V = -g33 t p, g33 = d33 / eps33^T from the
    material's C, e, beta (19.53e-3 V m/N for PZT-5H): -195.25 V at p = 10 kPa, t = 1 m."""
    c = np.array([[12.6e10, 7.95e10, 8.41e10], [7.95e10, 12.6e10, 8.41e10], [8.41e10, 8.41e10, 11.7e10]])
    e3 = np.array([-6.5, -6.5, 23.3])
    d3 = np.linalg.solve(c, e3)
    g33 = d3[2] / (BETA33 + e3 @ d3)
    run = solve(DATA / "floating_free_sensor3d.toml", n, tmp_path)
    checks = run.record.checks
    # The uniform state, P1 exact; the contact only closes uniformly: measured 2.3e-15 relative.
    assert checks["floating_potential"][0] == pytest.approx(-g33 * 1.0 * 1.0e4, rel=1e-10)
    assert run.record.contact_force == pytest.approx(1.0e4 * 2.0 * 1.0, rel=1e-10)
    assert abs(checks["floating_charge"][0]) <= 1e-12 * checks["floating_charge_reading"][0]


def test_make_crosscheck_takes_every_scene_the_force_sensor_too():
    """The peer solves floating electrodes, regions and Coulomb friction: `make crosscheck`
    leaves no case out (before, the force sensor was, the peer having no floating electrode)."""
    import subprocess
    from pathlib import Path

    root = Path(__file__).parents[1]
    # --no-print-directory: under `make test` this make is nested and would end with "Leaving directory"
    listed = subprocess.run(["make", "--no-print-directory", "-n", "crosscheck"], cwd=root, capture_output=True,
                            text=True, check=True, timeout=60).stdout.splitlines()[-1]
    every = sorted(str(p.relative_to(root)) for p in [*root.glob("cases/*.toml"), *root.glob("cases/hard/*.toml")])
    assert all(case in listed.split() for case in every)
    assert {"cases/force_sensor.toml", "cases/bimorph.toml", "cases/coulomb.toml"} <= set(listed.split())