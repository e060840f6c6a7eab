"""Electrodes (issue 22): the roles `electrode` (phi = loads.electrode_potential, zero
traction, theta = 0) and `ground` (phi = 0, zero traction, theta = 0). A piezoelectric layer
between them has a uniform exact solution that P1 reproduces to round-off, so each field and
the electrode's charge are checked against the constitutive law of docs/model.md section 2:
phi = V z/t; sigma33 = C33 eps33 + e33 V/t = 0 gives u_3 = -e33 V z/(C33 t); the free charge
-D . nu on the electrode is (beta33 + e33^2/C33) V A/t."""

from __future__ import annotations

import numpy as np
import pytest

from harness.cli import main
from harness.core.contract import ExitCode
from harness.measure.fields import read_state
from physics_runs import DATA, solve

# PZT-5H (freefem/materials/PZT-5H.idp): the constants the exact solution needs.
C33, E33, BETA33 = 11.7e10, 23.3, 1.301565607e-8
V = 100.0  # the case files' electrode_potential [V]


def exact_charge(area: float, thickness: float, potential: float = V) -> float:
    """The electrode's free charge: the permittivity at zero lateral strain, free along the poling axis."""
    return (BETA33 + E33**2 / C33) * potential * area / thickness


def grid(coordinate: np.ndarray, n: int) -> np.ndarray:
    """The nodes' exact coordinates, multiples of h = 1/n: solution.vtu stores them in single
    precision (off by up to 3e-8 relative), the fields (state.txt) in double."""
    return np.round(coordinate.astype(float) * n) / n


@pytest.mark.parametrize("n", [2, 4])
def test_a_layer_between_electrodes_has_the_uniform_exact_solution_2d(tmp_path, n):
    run = solve(DATA / "layer.toml", n, tmp_path)
    u, phi, theta = read_state(tmp_path / "layer" / f"n{n}" / "state.txt")
    y = grid(run.fields.points[:, 1], n)
    # phi and u are linear: P1 is exact and the problem linear (Newton's second step is
    # round-off), so only round-off is left: measured <= 8e-15 of V and of u_top at n = 2, 4
    # and in 3D; 1e-10 leaves room for another sparse solver's pivoting.
    assert phi == pytest.approx(V * y / 1.0, abs=1e-10 * V)
    uy_top = E33 * V / C33
    assert u[0::2] == pytest.approx(np.zeros_like(y), abs=1e-10 * uy_top)
    assert u[1::2] == pytest.approx(-uy_top * y, abs=1e-10 * uy_top)
    assert theta == pytest.approx(np.zeros_like(y), abs=1e-30)
    checks = run.record.checks
    # Width 2, thickness 1. The reaction sum is exact for P1 up to round-off (measured 5e-16).
    assert checks["electrode_charge"] == pytest.approx(exact_charge(2.0, 1.0), rel=1e-10)
    # All of it returns through the ground and the clamp: the net charge out is ~0.
    assert abs(checks["charge_out_dirichlet"]) < 1e-12 * exact_charge(2.0, 1.0)


def test_a_layer_between_electrodes_has_the_uniform_exact_solution_3d(tmp_path):
    run = solve(DATA / "layer3d.toml", 2, tmp_path)
    u, phi = read_state(tmp_path / "layer3d" / "n2" / "state.txt")
    z = grid(run.fields.points[:, 2], 2)
    assert phi == pytest.approx(V * z, abs=1e-10 * V)
    uz_top = E33 * V / C33
    assert u[2::3] == pytest.approx(-uz_top * z, abs=1e-10 * uz_top)
    assert np.abs(u[0::3]).max() < 1e-10 * uz_top and np.abs(u[1::3]).max() < 1e-10 * uz_top
    assert run.record.checks["electrode_charge"] == pytest.approx(exact_charge(2.0, 1.0), rel=1e-10)


def test_the_charge_is_linear_in_the_potential_and_zero_at_zero(tmp_path):
    """V = 0 is the unloaded state; -V flips the charge exactly (the law is linear)."""
    zero = solve(DATA / "layer.toml", 2, tmp_path, "loads.electrode_potential=0", "scene.name=zero")
    assert zero.record.max_abs_u == 0.0 and zero.record.checks["electrode_charge"] == 0.0
    minus = solve(DATA / "layer.toml", 2, tmp_path, "loads.electrode_potential=-250", "scene.name=minus")
    assert minus.record.checks["electrode_charge"] == pytest.approx(exact_charge(2.0, 1.0, -250.0), rel=1e-10)


def test_an_electrode_touching_an_earthed_part_is_refused_with_one_line(tmp_path, capsys):
    """Two potentials at one node: the electrode on the whole top meets a clamped side."""
    code = main(["solve", str(DATA / "layer.toml"), "--n", "2", "--results", str(tmp_path),
                 "--set", 'geometry.left="clamped"'])
    err = capsys.readouterr().err
    assert code == ExitCode.INPUT
    lines = [line for line in err.splitlines() if line.startswith("error:")]
    assert len(lines) == 1 and "electrode" in lines[0] and "clamped or ground" in lines[0], err


def test_the_getfem_peer_imposes_the_electrode_potential_too(tmp_path):
    """The independent GetFEM code (docs/crosscheck.md) on the same layer, 2D and 3D: agreement
    within the crosscheck's 1e-8 (measured 5.3e-15) is exit 0."""
    code = main(["crosscheck", str(DATA / "layer.toml"), str(DATA / "layer3d.toml"), "--levels", "2",
                 "--results", str(tmp_path)])
    assert code == ExitCode.OK


def refused_before_meshing(capsys, tmp_path, case, *overrides: str) -> str:
    """The one error line of a solve refused when the scene loads: nothing meshed or written."""
    code = main(["solve", str(case), "--n", "2", "--results", str(tmp_path / "results"),
                 *[arg for o in overrides for arg in ("--set", o)]])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == ExitCode.INPUT
    assert len(err) == 1 and err[0].startswith("error: ") and err[0].count("error") == 1, err
    assert not (tmp_path / "results").exists()
    return err[0]


def test_a_rectangles_electrode_touching_a_clamp_is_found_at_load_with_its_point(tmp_path, capsys):
    line = refused_before_meshing(capsys, tmp_path, DATA / "layer.toml", 'geometry.left="clamped"')
    assert "geometry.top [0, 2]" in line and "clamped part geometry.left" in line and "at (0, 1)" in line, line


def test_a_boxs_electrode_touching_a_ground_patch_is_found_at_load_with_its_point(tmp_path, capsys):
    line = refused_before_meshing(capsys, tmp_path, DATA / "layer3d.toml", 'geometry.x1="ground"')
    assert "electrode part geometry.z1" in line and "ground part geometry.x1" in line and "at (2, 0, 1)" in line, line


def test_a_gmsh_electrode_touching_a_clamp_is_found_at_load_with_its_point(tmp_path, capsys):
    strip = DATA.parents[1] / "cases" / "strip_actuator.toml"
    roles = ('geometry.roles={mount="clamped", ground_electrode="ground", driven_electrode="electrode", '
             'margin="clamped", base="free", tip="contact"}')
    line = refused_before_meshing(capsys, tmp_path, strip, roles)
    assert "'driven_electrode'" in line and "clamped part strip.geo: 'margin'" in line and "at (0.007, 0.0007)" in line
