"""The two device scenes of issue 22 at their two coarsest levels: each converges with every
physical check of the harness passing (`solve` exits 0 only then: force, charge and heat
balances, sigma_nu <= 0, the friction bound, no flux through open nodes), and meets bounds
known from the constitutive law (docs/model.md section 2) without the solver:

- the free charge on the driven side lies between the plate-capacitor values of the
  laterally clamped layer, (beta33 + e33^2/C33) V A/t, and of the stress-free one,
  (beta33 + e33 . C^-1 . e33) V A/t (in 2D, plane strain: the 1-3 block of C);
- the temperature stays below the foundation's theta_f (no heat source: the maximum
  principle of -div(k grad theta) = 0 with theta = 0 or the contact's Robin data);
- the whole contact part closes, and the contact force changes little between the two levels
  (measured 0.19 % for the strip, 0.81 % for the disc, whose n = 2 has one tetrahedron
  through the thickness: 2 % for both).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from harness.cli import main
from harness.core.contract import ExitCode
from physics_runs import CASES, solve

# PZT-5H (freefem/materials/PZT-5H.idp).
C = np.array([[12.6e10, 7.95e10, 8.41e10], [7.95e10, 12.6e10, 8.41e10], [8.41e10, 8.41e10, 11.7e10]])
E3 = np.array([-6.5, -6.5, 23.3])  # e31, e32, e33
BETA33 = 1.301565607e-8


def permittivity_bounds(dimension: int) -> tuple[float, float]:
    """Laterally clamped and stress-free effective permittivity along the poling axis."""
    keep = [0, 2] if dimension == 2 else [0, 1, 2]  # plane strain: axis 2 held
    c, e = C[np.ix_(keep, keep)], E3[keep]
    return BETA33 + E3[2] ** 2 / C[2, 2], BETA33 + float(e @ np.linalg.solve(c, e))


def levels(results: Path, name: str) -> dict[int, dict]:
    return {n: json.loads((results / name / f"n{n}" / "run.json").read_text()) for n in (2, 4)}


def test_the_strip_actuator_at_two_levels(tmp_path):
    solve(CASES / "strip_actuator.toml", 4, tmp_path)
    runs = levels(tmp_path, "strip_actuator")
    low, high = permittivity_bounds(2)
    volts, active_length, thickness = 100.0, 28e-3, 0.7e-3  # cases/devices/strip.geo
    for n, run in runs.items():
        charge = run["checks"]["electrode_charge"]   # the earthed stop takes only ~4e-3 of it
        assert low * volts * active_length / thickness < charge < high * volts * active_length / thickness, n
        assert 0.0 < run["max_theta"] < 20.0, n   # measured 15.9 K at n = 2
        # The tip face, 0.7 mm, all closed (the reported measure sums its segments: round-off).
        assert run["active_measure"] == pytest.approx(thickness, rel=1e-12), n
    assert runs[4]["contact_force"] == pytest.approx(runs[2]["contact_force"], rel=2e-2)


def test_the_disc_on_its_pad_at_two_levels(tmp_path):
    solve(CASES / "disc_pad.toml", 4, tmp_path)
    runs = levels(tmp_path, "disc_pad")
    low, high = permittivity_bounds(3)
    # cases/devices/disc.geo: a 32-gon of circumradius 5 mm, 1 mm thick.
    volts, area, thickness = 200.0, 16 * 5e-3**2 * np.sin(2 * np.pi / 32), 1e-3
    for n, run in runs.items():
        # The driven side's free charge: the electrode ring's and what the pad delivers.
        charge = run["checks"]["electrode_charge"] + run["charge_in_contact"]
        assert low * volts * area / thickness < charge < high * volts * area / thickness, n
        assert run["max_theta"] < 20.0, n   # measured 19.7 K at n = 2, 17.9 K at n = 4
        # The pad: a regular 32-gon inscribed in the circle of radius 3 mm, all closed.
        assert run["active_measure"] == pytest.approx(16 * 3e-3**2 * np.sin(2 * np.pi / 32), rel=1e-12), n
    assert runs[4]["contact_force"] == pytest.approx(runs[2]["contact_force"], rel=2e-2)


def test_the_getfem_peer_agrees_on_the_strip(tmp_path):
    """The independent GetFEM code on the strip at n = 2 (electrodes, a contact face of
    normal +x): within the crosscheck's 1e-8 (measured 2.9e-12; the disc 1.6e-15)."""
    code = main(["crosscheck", str(CASES / "strip_actuator.toml"), "--levels", "2", "--results", str(tmp_path)])
    assert code == ExitCode.OK


def test_a_2d_mesh_below_gmshloads_area_threshold_is_read(tmp_path):
    """FreeFEM's gmshload refuses triangles under 1e-8 m^2 (an absolute threshold); the strip
    at n = 8 has 3.8e-9 m^2 cells, read by freefem/dimension.idp's own MSH 2.2 reader."""
    run = solve(CASES / "strip_actuator.toml", 8, tmp_path)
    p, t = run.fields.points.astype(float), run.fields.triangles
    a, b = p[t[:, 1]] - p[t[:, 0]], p[t[:, 2]] - p[t[:, 0]]
    area = 0.5 * np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    assert area.max() < 1e-8
    assert area.sum() == pytest.approx(35e-3 * 0.7e-3, rel=1e-6)  # single-precision coordinates
    assert run.record.converged


def sensor_voltage_bounds(force: float, area: float, thickness: float) -> tuple[float, float]:
    """The open-circuit voltage of a pressed PZT-5H plate (docs/model.md "Floating electrodes"):
    laterally held, -e33 t F / ((C33 beta33 + e33^2) A), and laterally free, the plate formula
    -g33 t F / A with g33 = d33 / eps33^T, d3 = C^-1 e3 and eps33^T = beta33 + e3 . C^-1 . e3."""
    held = -E3[2] * thickness * force / ((C[2, 2] * BETA33 + E3[2] ** 2) * area)
    d3 = np.linalg.solve(C, E3)
    free = -d3[2] / permittivity_bounds(3)[1] * thickness * force / area
    return held, free


def test_the_force_sensor_reads_between_the_held_and_the_free_plate(tmp_path):
    """cases/force_sensor.toml: 10 N on a 10 x 1 mm disc bonded to an earthed base, read by a
    floating electrode. The base holds the disc laterally near it, the top is free: the voltage
    lies between the two plate values (-1.445 V, -2.502 V) and moves from the held one towards
    the free one as the mesh resolves the free rim (measured -1.713, -1.795, -1.837 V at
    n = 2, 4, 8), with the electrode's charge 0 to round-off."""
    for n in (2, 4):   # each level from zero (a linear scene): two solves
        solve(CASES / "force_sensor.toml", n, tmp_path)
    runs = levels(tmp_path, "force_sensor")
    area = 16 * 5e-3**2 * np.sin(2 * np.pi / 32)   # cases/devices/sensor.geo: the 32-gon
    force = 1.2815e5 * area                          # loads.traction_z: 10.00 N
    held, free = sensor_voltage_bounds(force, area, 1e-3)
    volts = {n: run["checks"]["floating_potential"][0] for n, run in runs.items()}
    for n, run in runs.items():
        assert free < volts[n] < held, n
        assert run["checks"]["applied_load"][2] == pytest.approx(-force, rel=1e-12)
        assert abs(run["checks"]["floating_charge"][0]) < 1e-12 * run["checks"]["floating_charge_reading"][0], n
    assert volts[4] < volts[2]


def test_the_force_sensor_is_linear_in_its_force(tmp_path):
    """Twice the pressure, twice the voltage (the scene is linear: no contact)."""
    one = solve(CASES / "force_sensor.toml", 2, tmp_path)
    two = solve(CASES / "force_sensor.toml", 2, tmp_path, "loads.traction_z=-2.563e5", "scene.name=twice")
    assert two.record.checks["floating_potential"][0] == pytest.approx(2 * one.record.checks["floating_potential"][0], rel=1e-12)


def test_the_sensor_picture_shows_the_top_face_displacement(tmp_path):
    """Both faces of the sensor hold one potential each (earthed base, floating electrode): the
    face panel shows what varies there, u_z on the top face, not round-off of phi."""
    from harness.report.device_plot import face_panel, render

    run = solve(CASES / "force_sensor.toml", 2, tmp_path)
    title, label, nodes, shown = face_panel(run.fields, "phi", "V")
    assert title == "u_z on the top face" and label == "u_z [m]" and np.ptp(shown[nodes]) > 0
    render(tmp_path / "force_sensor" / "n2", tmp_path / "fields.png")
    assert (tmp_path / "fields.png").stat().st_size > 10_000
