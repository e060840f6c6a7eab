"""Material regions ([scene.materials]): each named body group of a gmsh scene has its own
material, bonded to its neighbours (one continuous P1 field).

Known answers: two layers loaded in series carry the same stress and strain as their own
stiffness says (u_y piecewise linear, exact in P1); a body split into regions of one material
is the one-region body; a metal shim, a dielectric of large permittivity, is nearly an
equipotential (its potential drop measured). Bad input: one line, exit 2."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from harness.cli import main
from harness.core.contract import ExitCode
from harness.measure.fields import read_state
from physics_runs import CASES, DATA, solve

# freefem/materials/Brass.idp (isotropic) and PZT-5H.idp: C33 and C13 [Pa].
C33 = {"Brass": 155.25e9, "PZT-5H": 11.7e10}
C13 = {"Brass": 69.75e9, "PZT-5H": 8.41e10}


def grid(coordinate: np.ndarray, n: int) -> np.ndarray:
    """solution.vtu's single-precision coordinates back on the mesh's lattice (h = 1/n)."""
    return np.round(coordinate.astype(float) * n) / n


@pytest.mark.parametrize("n, lower, upper", [(4, "Brass", "PZT-5H"), (8, "PZT-5H", "Brass")])
def test_two_layers_in_series_carry_one_stress_and_their_own_strains(tmp_path, n, lower, upper):
    run = solve(DATA / "bilayer.toml", n, tmp_path, f'scene.materials={{lower = "{lower}", upper = "{upper}"}}')
    u, = read_state(tmp_path / "bilayer" / f"n{n}" / "state.txt")[:1]
    y = grid(run.fields.points[:, 1], n)
    p, t1 = 1e6, 0.5
    exact = np.where(y <= t1, -p * y / C33[lower], -p * t1 / C33[lower] - p * (y - t1) / C33[upper])
    u = u.reshape(-1, 2)
    # The exact field is P1 on a mesh with the interface as a line: only round-off is left
    # (measured 9e-13 of max |u_y|; the Newton step of a linear problem).
    assert u[:, 1] == pytest.approx(exact, abs=1e-10 * np.abs(exact).max())
    assert np.abs(u[:, 0]).max() <= 1e-10 * np.abs(exact).max()
    # The stresses of the laminate: sigma_yy = -p in both layers, sigma_xx = C13 eps_yy in each.
    strain = {name: -p / C33[name] for name in (lower, upper)}
    assert C13[lower] * strain[lower] != pytest.approx(C13[upper] * strain[upper], rel=0.05)


def split_paper(tmp_path: Path, materials: str) -> Path:
    """cases/paper_gmsh.toml with its one body group cut into three regions (same mesh)."""
    geo = (CASES / "geo" / "paper.geo").read_text()
    assert 'Physical Surface("BaTiO3") = {1, 2, 3};' in geo
    (tmp_path / "geo").mkdir()
    (tmp_path / "geo" / "paper.geo").write_text(geo.replace(
        'Physical Surface("BaTiO3") = {1, 2, 3};',
        'Physical Surface("left") = {1};\nPhysical Surface("middle") = {2};\nPhysical Surface("right") = {3};'))
    toml = (CASES / "paper_gmsh.toml").read_text()
    toml = re.sub(r'(?m)^material = "BaTiO3".*$', "", toml)
    toml = toml.replace("[geometry]", f"[scene.materials]\n{materials}\n\n[geometry]", 1)
    case = tmp_path / "paper_gmsh.toml"
    case.write_text(toml)
    return case


def test_regions_of_one_material_are_the_one_region_body(tmp_path):
    case = split_paper(tmp_path, 'left = "BaTiO3"\nmiddle = "BaTiO3"\nright = "BaTiO3"')
    solve(CASES / "paper_gmsh.toml", 4, tmp_path / "one")
    solve(case, 4, tmp_path / "three")
    one = read_state(tmp_path / "one" / "paper_gmsh" / "n4" / "state.txt")
    three = read_state(tmp_path / "three" / "paper_gmsh" / "n4" / "state.txt")
    # Each cell's constants are the same doubles (P0 fields of the region labels against the
    # material's reals): the same arithmetic, measured identical to the last bit.
    for a, b in zip(one, three):
        assert np.array_equal(a, b)


def test_a_region_of_another_material_changes_the_solution(tmp_path):
    case = split_paper(tmp_path, 'left = "BaTiO3"\nmiddle = "PZT-5H"\nright = "BaTiO3"')
    solve(CASES / "paper_gmsh.toml", 2, tmp_path / "one")
    solve(case, 2, tmp_path / "three")
    one = read_state(tmp_path / "one" / "paper_gmsh" / "n2" / "state.txt")
    three = read_state(tmp_path / "three" / "paper_gmsh" / "n2" / "state.txt")
    assert np.abs(one[0] - three[0]).max() > 0.1 * np.abs(one[0]).max()


BAD = {
    "a region with no material": ('upper = "PZT-5H"\n', "", "physical surface 'upper' has no material"),
    "a material with no region": ('upper = "PZT-5H"\n', 'upper = "PZT-5H"\nshim = "Brass"\n',
                                  "has no physical surface named 'shim'"),
    "an unknown material": ('upper = "PZT-5H"\n', 'upper = "Unobtainium"\n', "unknown material 'Unobtainium'"),
    "both the shorthand and the table": ('effects = []\n', 'effects = []\nmaterial = "Brass"\n',
                                         "scene.material = 'Brass' and [scene.materials] both given"),
    "neither": ('[scene.materials]\nlower = "Brass"\nupper = "PZT-5H"\n', "", "missing key scene.material"),
}


@pytest.mark.parametrize("name", list(BAD))
def test_bad_regions_end_in_one_line_and_exit_2(tmp_path, capsys, name):
    old, new, message = BAD[name]
    text = (DATA / "bilayer.toml").read_text()
    assert old in text
    shutil.copy(DATA / "bilayer.geo", tmp_path / "bilayer.geo")
    (tmp_path / "bilayer.toml").write_text(text.replace(old, new, 1))
    code = main(["solve", str(tmp_path / "bilayer.toml"), "--n", "4", "--results", str(tmp_path / "results")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == ExitCode.INPUT == 2
    assert len(err) == 1 and err[0].startswith("error:") and message in err[0], err
    assert not (tmp_path / "results" / "bilayer" / "n4").exists()


@pytest.mark.parametrize("geo, message", [
    ('Physical Surface("upper") = {2};', "physical surfaces 'lower' and 'upper' overlap",
     ),
    ('Physical Surface("lower") = {1};', "surface 1 is in no physical surface"),
])
def test_overlapping_or_missing_region_groups_are_named(tmp_path, capsys, geo, message):
    text = (DATA / "bilayer.geo").read_text()
    if "overlap" in message:
        text = text.replace(geo, 'Physical Surface("upper") = {1, 2};')
    else:
        text = text.replace(geo, "")
        (tmp_path / "bilayer.toml").write_text((DATA / "bilayer.toml").read_text().replace('lower = "Brass"\n', ""))
    (tmp_path / "bilayer.geo").write_text(text)
    if not (tmp_path / "bilayer.toml").exists():
        shutil.copy(DATA / "bilayer.toml", tmp_path / "bilayer.toml")
    code = main(["solve", str(tmp_path / "bilayer.toml"), "--n", "4", "--results", str(tmp_path / "results")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == ExitCode.INPUT == 2
    assert len(err) == 1 and message in err[0], err


def test_regions_on_a_rectangle_are_refused(tmp_path, capsys):
    code = main(["solve", str(DATA / "layer.toml"), "--n", "2", "--results", str(tmp_path),
                 "--set", "scene.material=", "--set", 'scene.materials={body = "PZT-5H"}'])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "needs a gmsh scene" in err[0], err


def test_a_brass_shim_takes_a_small_stated_share_of_the_potential(tmp_path):
    """Brass is modelled as a dielectric of permittivity 1e-6 C/(V m): between the earthed
    clamp and a driven PZT-5H layer of the same thickness it takes the share of the potential
    that a series capacitor would, about beta_PZT / beta_brass. In one dimension, with PZT-5H's
    thickness permittivity free along the poling (beta33 + e33^2/C33 = 1.77e-8), that is
    1.7 %. Measured at the shim's top face: 2.11-2.58 % of V at n = 8 (2.09-2.51 % at n = 4,
    2.11-2.62 % at n = 16), the spread from the lateral clamping near the ends. A conductor
    would take 0: this is the error of the model's metal, stated in docs/materials.md."""
    run = solve(DATA / "shim.toml", 8, tmp_path)
    _, phi = read_state(tmp_path / "shim" / "n8" / "state.txt")[:2]
    y = grid(run.fields.points[:, 1], 8)
    share = phi[np.abs(y - 0.5) < 1e-9] / 100.0
    series = 1.77e-8 / (1e-6 + 1.77e-8)
    assert 0.9 * series < share.min() and share.max() < 1.6 * series, (share.min(), share.max())
    assert share.max() < 0.03


@pytest.mark.parametrize("n", [2, 4])  # n = 4: the split level (each tetrahedron's 8 children keep its region)
def test_two_layers_in_series_in_3d(tmp_path, n):
    run = solve(DATA / "bilayer3d.toml", n, tmp_path)
    u, = read_state(tmp_path / "bilayer3d" / f"n{n}" / "state.txt")[:1]
    z = run.fields.points[:, 2].astype(float)
    p, t1, lower, upper = 1e6, 0.5, "Brass", "PZT-5H"
    exact = np.where(z <= t1, -p * z / C33[lower], -p * t1 / C33[lower] - p * (z - t1) / C33[upper])
    u = u.reshape(-1, 3)
    # Unstructured nodes: solution.vtu's single-precision z (relative 6e-8) bounds the comparison.
    assert u[:, 2] == pytest.approx(exact, abs=1e-6 * np.abs(exact).max())
    assert np.abs(u[:, :2]).max() <= 1e-10 * np.abs(exact).max()


# PZT-5H (freefem/materials/PZT-5H.idp): e33 [C/m^2].
E33 = 23.3


@pytest.mark.parametrize("n", [4, 8])
def test_two_layers_poled_oppositely_strain_oppositely(tmp_path, n):
    run = solve(DATA / "opposed.toml", n, tmp_path)
    u, phi = read_state(tmp_path / "opposed" / f"n{n}" / "state.txt")[:2]
    y = grid(run.fields.points[:, 1], n)
    V, t1 = 100.0, 0.5
    strain = -E33 * V / C33["PZT-5H"]  # the lower layer's, poled along +y; the upper's is -strain
    exact = np.where(y <= t1, strain * y, strain * t1 - strain * (y - t1))
    u = u.reshape(-1, 2)
    # P1-exact fields: round-off only (measured below 1e-12 of the largest value).
    assert phi == pytest.approx(V * y, abs=1e-10 * V)
    assert u[:, 1] == pytest.approx(exact, abs=1e-10 * np.abs(exact).max())
    assert np.abs(u[:, 0]).max() <= 1e-10 * np.abs(exact).max()


def test_two_layers_of_real_size_are_bonded_not_held_at_their_interface(tmp_path):
    """The same known answer drawn in millimetres (tests/data/bilayer_mm.geo), whose cells are
    below gmshload's area threshold: freefem/dimension.idp's own reader reads every level.
    FreeFEM's readmesh makes the edges between two cell labels boundary edges, labelled with
    their vertices' label 1 (the clamped role's), which held the interface at u = 0, phi = 0."""
    n = 4
    run = solve(DATA / "opposed.toml", n, tmp_path, 'geometry.file="bilayer_mm.geo"')
    u, phi = read_state(tmp_path / "opposed" / f"n{n}" / "state.txt")[:2]
    y = grid(run.fields.points[:, 1] * 1e3, n) * 1e-3
    V, t1, thickness = 100.0, 0.5e-3, 1e-3
    strain = -E33 * V / (thickness * C33["PZT-5H"])
    exact = np.where(y <= t1, strain * y, strain * t1 - strain * (y - t1))
    u = u.reshape(-1, 2)
    # P1-exact fields, as at unit size (measured below 1e-12 of the largest value).
    assert phi == pytest.approx(V * y / thickness, abs=1e-10 * V)
    assert u[:, 1] == pytest.approx(exact, abs=1e-10 * np.abs(exact).max())
    assert np.abs(u[:, 0]).max() <= 1e-10 * np.abs(exact).max()


def test_every_region_poled_the_other_way_is_the_body_poled_the_other_way(tmp_path):
    """Both layers poled -y through their own entries, against one material poled -y."""
    regions = 'scene.materials={lower = {material = "PZT-5H", poling_axis = "-y"}, upper = {material = "PZT-5H", poling_axis = "-y"}}'
    solve(DATA / "opposed.toml", 4, tmp_path / "two", regions)
    solve(DATA / "opposed.toml", 4, tmp_path / "one", "scene.materials={}", 'scene.material="PZT-5H"',
          'scene.poling_axis="-y"')
    two = read_state(tmp_path / "two" / "opposed" / "n4" / "state.txt")
    one = read_state(tmp_path / "one" / "opposed" / "n4" / "state.txt")
    for a, b in zip(one, two):
        assert b == pytest.approx(a, abs=1e-12 * np.abs(a).max())
        assert np.abs(a).max() > 0


def test_a_bad_region_poling_is_named(tmp_path, capsys):
    code = main(["solve", str(DATA / "opposed.toml"), "--n", "4", "--results", str(tmp_path), "--set",
                 'scene.materials={lower = "PZT-5H", upper = {material = "PZT-5H", poling_axis = [0, 0]}}'])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "scene.materials.upper: scene.poling_axis = [0, 0] has zero length" in err[0], err
