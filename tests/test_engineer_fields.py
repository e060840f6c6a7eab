"""The fields engineers read in solution.vtu (stress and von Mises, E, D, heat flux; freefem/
fields.idp) and the reactions per boundary part in run.json (freefem/reactions.idp), against
states P1 reproduces exactly: a uniform pressure, a linear potential, a linear temperature."""

from __future__ import annotations

import json
import math
from pathlib import Path

import meshio
import numpy as np
import pytest

from harness.core.layout import Layout
from harness.scene.material_constants import material_constants
from physics_runs import CASES, DATA, solve
from test_parallel import mpi_missing

P = 100.0  # block.toml's pressure on the loaded top [N/m^2]
# Round-off of a uniform state solved to newton.rtol = 1e-9: the stress of a P1 state read
# per cell, relative to the load (measured: 3e-11).
ROUND_OFF = 1e-8


def cells(directory: Path) -> dict[str, np.ndarray]:
    mesh = meshio.read(directory / "solution.vtu")
    return {name: np.asarray(data[0]) for name, data in mesh.cell_data.items()}


def von_mises(sxx, syy, szz, sxy=0.0, syz=0.0, sxz=0.0):
    return math.sqrt(0.5 * ((sxx - syy) ** 2 + (syy - szz) ** 2 + (szz - sxx) ** 2) + 3 * (sxy**2 + syz**2 + sxz**2))


def rollers_block(tmp_path: Path, *overrides: str):
    """block.toml between two roller_x walls: u_x = 0 everywhere, a uniform compression."""
    return solve(DATA / "block.toml", 4, tmp_path, 'geometry.left="roller_x"', 'geometry.right="roller_x"', *overrides)


def test_uniform_pressure_stress_is_exact_with_its_von_mises_and_wall_reactions(tmp_path):
    """Elastic block on rollers under p: eps_xx = 0, so sigma_yy = -p, sigma_xx = -p C13/C33 and
    the out-of-plane sigma_zz = -p C23/C33 (plane strain); each wall carries -sigma_xx times its
    height, the two equal and opposite, summing to checks.clamp_reaction."""
    run = rollers_block(tmp_path, 'scene.effects=["contact"]')
    c = material_constants("BaTiO3", Layout(results=tmp_path))
    field = cells(tmp_path / "block" / "n4")
    n = len(field["stress_yy"])
    for name in ("stress_xx", "stress_yy", "stress_zz", "stress_xy", "von_mises"):
        assert field[name].shape == (n, 1), name
    assert "electric_field" not in field and "heat_flux" not in field  # no phi, no theta in this scene
    sxx, szz = -P * c["f13"] / c["f33"], -P * c["fC23"] / c["f33"]
    assert np.allclose(field["stress_yy"], -P, rtol=0, atol=ROUND_OFF * P)
    assert np.allclose(field["stress_xx"], sxx, rtol=0, atol=ROUND_OFF * P)
    assert np.allclose(field["stress_zz"], szz, rtol=0, atol=ROUND_OFF * P)
    assert np.allclose(field["stress_xy"], 0, rtol=0, atol=ROUND_OFF * P)
    assert np.allclose(field["von_mises"], von_mises(sxx, -P, szz), rtol=0, atol=ROUND_OFF * P)

    walls = run.record.reactions["roller_x"]
    left, right = sorted(walls["parts"], key=lambda part: part["at"][0])
    assert left["at"] == pytest.approx([0.0, 0.5]) and right["at"] == pytest.approx([2.0, 0.5])
    assert left["measure"] == pytest.approx(1.0) and right["measure"] == pytest.approx(1.0)
    # The wall pushes the compressed block back: +x on the left, -x on the right.
    assert left["force"][0] == pytest.approx(-sxx * 1.0, rel=ROUND_OFF)
    assert right["force"][0] == pytest.approx(sxx * 1.0, rel=ROUND_OFF)
    assert left["force"][1] == 0 and right["force"][1] == 0  # a roller holds u_x only
    clamp = run.record.checks["clamp_reaction"]
    assert walls["force"] == pytest.approx(clamp, abs=1e-12 * P)
    assert left["force"][0] + right["force"][0] == pytest.approx(clamp[0], abs=1e-12 * P)
    assert set(run.record.reactions) == {"roller_x"}  # the only part fixing a field of this scene


def test_coupled_uniform_pressure_keeps_sigma_yy_exact(tmp_path):
    """With every effect: the open-circuit top makes D_y = 0, so phi is linear with
    E_y = -e33 eps33 / beta33 and sigma_yy = -p still, exactly."""
    rollers_block(tmp_path)
    c = material_constants("BaTiO3", Layout(results=tmp_path))
    field = cells(tmp_path / "block" / "n4")
    stiff = c["f33"] + c["e33"] ** 2 / c["b33"]  # C33 stiffened by the open circuit
    eps33 = -P / stiff
    assert np.allclose(field["stress_yy"], -P, rtol=0, atol=ROUND_OFF * P)
    assert np.allclose(field["stress_xx"], (c["f13"] + c["e31"] * c["e33"] / c["b33"]) * eps33, rtol=0, atol=ROUND_OFF * P)
    assert field["electric_field"].shape == (len(field["stress_yy"]), 3)
    assert np.allclose(field["electric_field"][:, 1], -c["e33"] * eps33 / c["b33"], rtol=1e-8)
    assert np.allclose(field["electric_displacement"], 0, atol=1e-8 * abs(c["e33"] * eps33))


def test_linear_potential_gives_constant_E_and_D_and_electrode_charges(tmp_path):
    """layer.toml: phi = V y / t, so E_y = -V/t, D_y = -(beta33 + e33^2/C33) V/t in every cell; the
    electrode's charge is -D_y w, the bottom's the opposite, shared by its clamped and ground halves."""
    run = solve(DATA / "layer.toml", 4, tmp_path)
    c = material_constants("PZT-5H", Layout(results=tmp_path))
    field = cells(tmp_path / "layer" / "n4")
    volts, t, w = 100.0, 1.0, 2.0
    d_y = -(c["b33"] + c["e33"] ** 2 / c["f33"]) * volts / t
    assert np.allclose(field["electric_field"][:, 0], 0, atol=1e-9 * volts)
    assert np.allclose(field["electric_field"][:, 1], -volts / t, rtol=1e-9)
    assert np.allclose(field["electric_field"][:, 2], 0)
    assert np.allclose(field["electric_displacement"][:, 1], d_y, rtol=1e-8)
    assert np.allclose(field["stress_yy"], 0, atol=1e-8 * abs(c["e33"]) * volts / t)  # sigma33 = 0 (free along y)
    reactions = run.record.reactions
    assert reactions["electrode"]["charge"] == pytest.approx(-d_y * w, rel=1e-8)
    assert reactions["electrode"]["charge"] == pytest.approx(run.record.checks["electrode_charge"], rel=1e-12)
    # The node at x = 1 closes both bottom parts; it counts for the first role (clamped), with the
    # share h of the bottom it carries (h = 1/n).
    h = 1 / 4
    assert reactions["clamped"]["charge"] == pytest.approx(d_y * (w / 2 + h / 2), rel=1e-8)
    assert reactions["ground"]["charge"] == pytest.approx(d_y * (w / 2 - h / 2), rel=1e-8)
    assert len(reactions["electrode"]["parts"]) == 1
    assert json.loads(json.dumps(reactions)) == reactions  # plain JSON, no NaN


def test_linear_temperature_gives_constant_heat_flux(tmp_path):
    """A manufactured linear theta* = a + b x + c y (thermal effects only): P1 holds it exactly, so
    q = -K grad(theta) = (-k11 b, -k33 c) in every cell, and the stress is the thermal one alone,
    sigma = -m theta (u* = 0) at each cell's centroid."""
    a, b, cy = 0.5e-3, 0.3e-3, -0.2e-3
    solve(CASES / "mms" / "bulk.toml", 4, tmp_path, 'scene.name="mms_bulk"', 'scene.effects=["thermal"]',
          f'manufactured.theta="{a!r} + {b!r}*x + {cy!r}*y"', 'manufactured.u1="0"', 'manufactured.u2="0"')
    c = material_constants("BaTiO3", Layout(results=tmp_path))
    directory = tmp_path / "mms_bulk" / "n4"
    field = cells(directory)
    q = field["heat_flux"]
    assert q.shape == (len(field["stress_xx"]), 3)
    assert np.allclose(q[:, 0], -c["k11"] * b, rtol=1e-10)
    assert np.allclose(q[:, 1], -c["k33"] * cy, rtol=1e-10)
    assert np.all(q[:, 2] == 0)
    mesh = meshio.read(directory / "solution.vtu")
    centroid = mesh.points.astype(float)[mesh.cells[0].data].mean(axis=1)
    theta = a + b * centroid[:, 0] + cy * centroid[:, 1]
    # The file stores the points in single precision (iovtk), 6e-8 relative: theta at them to 1e-6.
    assert np.allclose(field["stress_xx"][:, 0], -c["m11"] * theta, rtol=1e-6)
    assert np.allclose(field["stress_yy"][:, 0], -c["m33"] * theta, rtol=1e-6)
    assert np.allclose(field["stress_zz"][:, 0], -c["m22"] * theta, rtol=1e-6)  # plane strain holds eps_zz = 0


@pytest.mark.skipif(bool(mpi_missing()), reason=mpi_missing() or "-")
def test_on_petsc_ranks_the_fields_are_gathered_and_roles_reported_whole(tmp_path):
    """Two ranks writing the outputs themselves (PETSc): the cell fields gathered onto the whole
    mesh, the same uniform stress; a rank holds pieces of pieces, so no `parts`."""
    run = rollers_block(tmp_path, 'scene.effects=["contact"]', "run.ranks=2", 'run.linear_solver="petsc"')
    c = material_constants("BaTiO3", Layout(results=tmp_path))
    field = cells(tmp_path / "block" / "n4")
    assert np.allclose(field["stress_yy"], -P, rtol=0, atol=ROUND_OFF * P)
    assert np.allclose(field["stress_xx"], -P * c["f13"] / c["f33"], rtol=0, atol=ROUND_OFF * P)
    walls = run.record.reactions["roller_x"]
    assert "parts" not in walls
    assert walls["force"] == pytest.approx(run.record.checks["clamp_reaction"], abs=1e-12 * P)
