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

LIBRARY = Path(__file__).parents[1] / "freefem" / "materials"

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


def one_and_three_regions(tmp_path, materials: str, n: int):
    """The states of the gmsh paper scene as one body and split into three regions."""
    solve(CASES / "paper_gmsh.toml", n, tmp_path / "one")
    solve(split_paper(tmp_path, materials), n, tmp_path / "three")
    return tuple(read_state(tmp_path / run / "paper_gmsh" / f"n{n}" / "state.txt") for run in ("one", "three"))


def test_regions_of_one_material_are_the_one_region_body(tmp_path):
    one, three = one_and_three_regions(tmp_path, 'left = "BaTiO3"\nmiddle = "BaTiO3"\nright = "BaTiO3"', 4)
    # Each cell's constants are the same doubles (P0 fields of the region labels against the
    # material's reals): the same arithmetic, measured identical to the last bit.
    for a, b in zip(one, three):
        assert np.array_equal(a, b)


def test_a_region_of_another_material_changes_the_solution(tmp_path):
    one, three = one_and_three_regions(tmp_path, 'left = "BaTiO3"\nmiddle = "PZT-5H"\nright = "BaTiO3"', 2)
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


def layers_exact(z: np.ndarray, lower: str, upper: str, p: float = 1e6, t1: float = 0.5) -> np.ndarray:
    """u along the load of two layers in series under the pressure p (tests/data/bilayer.toml)."""
    return np.where(z <= t1, -p * z / C33[lower], -p * t1 / C33[lower] - p * (z - t1) / C33[upper])


@pytest.mark.parametrize("n, lower, upper", [(4, "Brass", "PZT-5H"), (8, "PZT-5H", "Brass")])
def test_the_rectangles_two_blocks_are_the_two_layers_drawn_in_gmsh(tmp_path, n, lower, upper):
    """[geometry.blocks] on the rectangle (tests/data/bilayer_rect.toml) against the same two
    layers drawn in gmsh (tests/data/bilayer.toml): both the exact P1 field, so equal node by node."""
    materials = f'scene.materials={{lower = "{lower}", upper = "{upper}"}}'
    rect = solve(DATA / "bilayer_rect.toml", n, tmp_path / "rect", materials)
    drawn = solve(DATA / "bilayer.toml", n, tmp_path / "gmsh", materials)
    u_rect = read_state(tmp_path / "rect" / "bilayer_rect" / f"n{n}" / "state.txt")[0].reshape(-1, 2)
    u_gmsh = read_state(tmp_path / "gmsh" / "bilayer" / f"n{n}" / "state.txt")[0].reshape(-1, 2)
    at_rect = np.column_stack([grid(rect.fields.points[:, k], n) for k in range(2)])
    at_gmsh = np.column_stack([grid(drawn.fields.points[:, k], n) for k in range(2)])
    exact = layers_exact(at_rect[:, 1], lower, upper)
    scale = np.abs(exact).max()
    # Round-off only: measured 6.8e-16 of max |u_y| (the gmsh scene's 5.6e-13) at n = 4.
    assert u_rect[:, 1] == pytest.approx(exact, abs=1e-10 * scale)
    assert np.abs(u_rect[:, 0]).max() <= 1e-10 * scale
    # The same nodes (the lattice), matched by their coordinates.
    order_rect, order_gmsh = np.lexsort(at_rect.T), np.lexsort(at_gmsh.T)
    assert np.array_equal(at_rect[order_rect], at_gmsh[order_gmsh])
    assert u_rect[order_rect] == pytest.approx(u_gmsh[order_gmsh], abs=1e-10 * scale)


def brass_named(path: Path, name: str, stiffer: bool = False) -> Path:
    """freefem/materials/Brass.idp as the material file `path` named `name` (its C11 = C22 = C33
    raised by 100 GPa when `stiffer`: another answer, to tell the two files apart)."""
    text = (LIBRARY / "Brass.idp").read_text().replace('materialName = "Brass"', f'materialName = "{name}"')
    if stiffer:
        assert text.count("155.25e9") == 3
        text = text.replace("155.25e9", "255.25e9")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def bilayer_rect_with(case: Path, lower: str) -> Path:
    """tests/data/bilayer_rect.toml as `case`, its lower block of the material `lower` (or the
    region's table, when `lower` is one: `{material = ...}`)."""
    text = (DATA / "bilayer_rect.toml").read_text()
    assert 'lower = "Brass"\n' in text
    case.parent.mkdir(parents=True, exist_ok=True)
    entry = lower if lower.startswith("{") else f'"{lower}"'
    case.write_text(text.replace('lower = "Brass"\n', f"lower = {entry}\n", 1))
    return case


def assert_brass_under_pzt(run, n: int, results: Path) -> None:
    """The known answer of two layers in series, brass below, PZT-5H above."""
    u = read_state(results / "bilayer_rect" / f"n{n}" / "state.txt")[0].reshape(-1, 2)
    exact = layers_exact(grid(run.fields.points[:, 1], n), "Brass", "PZT-5H")
    # Round-off only, as the blocks' test above (measured 6.8e-16 of max |u_y|).
    assert u[:, 1] == pytest.approx(exact, abs=1e-10 * np.abs(exact).max())


def test_a_regions_material_file_is_the_one_beside_the_case_file_not_the_one_where_it_runs(tmp_path, monkeypatch):
    """`lower = "Soft.idp"` is the Soft.idp beside the case file, as `scene.material` and a .geo
    are; a Soft.idp in the folder the run starts from (stiffer here) is not read. Before, it
    was: a wrong answer with exit 0. run.json records each region's file."""
    case = bilayer_rect_with(tmp_path / "case" / "bilayer_rect.toml", "Soft.idp")
    beside = brass_named(tmp_path / "case" / "Soft.idp", "Soft")
    brass_named(tmp_path / "elsewhere" / "Soft.idp", "Soft", stiffer=True)
    monkeypatch.chdir(tmp_path / "elsewhere")
    run = solve(case, 2, tmp_path / "results")
    assert_brass_under_pzt(run, 2, tmp_path / "results")
    pzt = LIBRARY / "PZT-5H.idp"
    assert run.record.regions == [{"name": "lower", "material": "Soft", "file": str(beside.resolve())},
                                  {"name": "upper", "material": "PZT-5H", "file": str(pzt.resolve())}]


@pytest.mark.parametrize("given", ["../materials/Soft.idp", "absolute", '{material = "../materials/Soft.idp"}'])
def test_a_regions_material_may_be_a_path_relative_to_the_case_file_or_absolute(tmp_path, given):
    """A region's own material file by a path, as `scene.material` takes one (docs/materials.md);
    before, a path was refused ("must be a material name")."""
    soft = brass_named(tmp_path / "materials" / "Soft.idp", "Soft")
    case = bilayer_rect_with(tmp_path / "case" / "bilayer_rect.toml", str(soft) if given == "absolute" else given)
    run = solve(case, 2, tmp_path / "results")
    assert_brass_under_pzt(run, 2, tmp_path / "results")
    assert run.record.regions[0] == {"name": "lower", "material": "Soft", "file": str(soft.resolve())}


@pytest.mark.parametrize("given, message", [
    ("../materials/Missing.idp", "unknown material"),
    ("../materials/Soft", "must be a material name or a path to a .idp file"),
])
def test_a_bad_region_material_path_is_one_line_naming_the_case_file(tmp_path, capsys, given, message):
    brass_named(tmp_path / "materials" / "Soft.idp", "Soft")
    case = bilayer_rect_with(tmp_path / "case" / "bilayer_rect.toml", given)
    code = main(["solve", str(case), "--n", "2", "--results", str(tmp_path / "results")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == ExitCode.INPUT == 2
    assert len(err) == 1 and err[0].startswith(f"error: {case}") and message in err[0], err
    assert not (tmp_path / "results" / "bilayer_rect" / "n2").exists()


@pytest.mark.parametrize("n", [2, 4])
def test_the_boxs_two_blocks_are_two_layers_in_series(tmp_path, n):
    """[geometry.blocks] on the box (tests/data/bilayer_box.toml), the known answer of
    tests/data/bilayer3d.toml on the Kuhn tetrahedra: u_z piecewise linear, exact in P1."""
    run = solve(DATA / "bilayer_box.toml", n, tmp_path)
    u = read_state(tmp_path / "bilayer_box" / f"n{n}" / "state.txt")[0].reshape(-1, 3)
    exact = layers_exact(grid(run.fields.points[:, 2], n), "Brass", "PZT-5H")
    # Round-off only: measured 1.9e-15 of max |u_z| at n = 4.
    assert u[:, 2] == pytest.approx(exact, abs=1e-10 * np.abs(exact).max())
    assert np.abs(u[:, :2]).max() <= 1e-10 * np.abs(exact).max()


def test_a_rectangle_without_blocks_meshes_as_before(tmp_path):
    """The mesh files of scenes without blocks are the bytes they were: the region labels and
    names are written only when a scene maps blocks (the regions' label 1, 'region_1', replaces
    the body's label 1, 'body': harness/mesh/msh.py)."""
    from harness.mesh.mesh import build_mesh
    from harness.scene.scene import load_scene
    plain = load_scene(DATA / "bilayer_rect.toml", ["scene.materials={}", 'scene.material="Brass"'])
    layered = load_scene(DATA / "bilayer_rect.toml")
    a = build_mesh(plain.geometry, 4, tmp_path / "plain").path.read_text()
    b = build_mesh(layered.geometry, 4, tmp_path / "layered").path.read_text()
    assert '2 1 "body"' in a and '2 1 "region_1"' in b and '2 2 "region_2"' in b
    # Only the triangles' physical tags differ: 1 below y = 1/2, 2 above (tests/test_mesh.py
    # holds the plain writer to gmsh's own bytes).
    lines_a, lines_b = a.splitlines(), b.splitlines()
    triangles = [(x, y) for x, y in zip(lines_a[lines_a.index("$Elements"):], lines_b[lines_b.index("$Elements"):])
                 if x.split()[1:2] == ["2"]]
    assert triangles and all(x.split()[3] == "1" for x, _ in triangles)
    assert {y.split()[3] for _, y in triangles} == {"1", "2"}


BAD_BLOCKS = {
    "overlap": ("upper = [0.0, 2.0, 0.5, 1.0]", "upper = [0.0, 2.0, 0.25, 1.0]", "'lower' and 'upper' overlap"),
    "gap": ("upper = [0.0, 2.0, 0.5, 1.0]", "upper = [0.0, 2.0, 0.75, 1.0]", "do not cover the body"),
    "outside": ("upper = [0.0, 2.0, 0.5, 1.0]", "upper = [0.0, 2.0, 0.5, 1.5]", "must be [x0, x1, y0, y1]"),
    "no material": ('upper = "PZT-5H"\n', "", "geometry.blocks.upper has no material"),
    "no block": ('upper = "PZT-5H"\n', 'upper = "PZT-5H"\nmiddle = "Brass"\n', "no block named 'middle'"),
    "unstructured": ('diagonals = "SW-NE"', 'diagonals = "unstructured"', "need the structured lattice"),
}


@pytest.mark.parametrize("name", BAD_BLOCKS)
def test_bad_blocks_are_one_line_before_anything_runs(tmp_path, capsys, name):
    old, new, message = BAD_BLOCKS[name]
    text = (DATA / "bilayer_rect.toml").read_text()
    assert old in text
    (tmp_path / "case.toml").write_text(text.replace(old, new, 1))
    code = main(["solve", str(tmp_path / "case.toml"), "--n", "4", "--results", str(tmp_path / "results")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == ExitCode.INPUT == 2
    assert len(err) == 1 and err[0].startswith("error:") and message in err[0], err
    assert not (tmp_path / "results").exists()


def test_a_block_off_the_levels_grid_is_named(tmp_path, capsys):
    # The interface y = 1/2 is a grid line at even n only: at n = 3 cells would straddle it.
    code = main(["solve", str(DATA / "bilayer_rect.toml"), "--n", "3", "--results", str(tmp_path)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == ExitCode.INPUT and len(err) == 1 and "block 'lower' has a side at 0.5, not a multiple of h = 1/3" in err[0], err
    # Refused before anything is meshed, naming the case file (it named only the level and block).
    assert err[0].startswith(f"error: {DATA / 'bilayer_rect.toml'}: n=3: block 'lower'"), err
    assert not (tmp_path / "bilayer_rect").exists()


def test_blocks_off_the_grid_of_the_boxs_unstructured_mesh_are_not_refused(tmp_path):
    """gmsh cuts the box's unstructured tetrahedra along the blocks' faces: the guard that names
    an off-grid block (before meshing) asks what the mesher asks, so n = 3 runs."""
    run = solve(DATA / "bilayer_box.toml", 3, tmp_path, 'geometry.diagonals="unstructured"')
    assert run.record.converged is True


# PZT-5H's beta33 [C/(V m)] (freefem/materials/PZT-5H.idp).
BETA33 = 1.301565607e-8
ROLLERS = 'geometry.roles={bottom = "clamped", sides = "roller_x", top = "electrode"}'


@pytest.mark.parametrize("n", [4, 8])
def test_a_brass_shim_tied_to_the_ground_is_an_equipotential(tmp_path, n):
    """tests/data/shim.toml with rollers on the sides (one-dimensional) and the shim a conductor
    tied to the ground: phi = 0 in the whole shim, and the PZT-5H layer above carries the whole
    drive, phi = V (y - t1) / t2, free along y: u_y = -e33 V (y - t1) / (C33 t2) there, 0 in the
    shim (sigma_yy = 0 throughout). P1-exact: round-off only (measured 7e-17 of V, 1.3e-15 of
    u_y at n = 4). The dielectric shim of the same scene holds 1.73 % of V at its top instead."""
    run = solve(DATA / "shim.toml", n, tmp_path, ROLLERS,
                'scene.materials={lower = {material = "Brass", conductor = "ground"}, upper = "PZT-5H"}')
    u, phi = read_state(tmp_path / "shim" / f"n{n}" / "state.txt")[:2]
    y = grid(run.fields.points[:, 1], n)
    V, t1, t2 = 100.0, 0.5, 0.5
    # Dirichlet dofs, penalised by 1e30 (freefem/bulk.idp): the ground's 0 to ~1e-91 V.
    assert np.abs(phi[y <= t1]).max() <= 1e-20 * V
    assert phi == pytest.approx(np.where(y <= t1, 0.0, V * (y - t1) / t2), abs=1e-10 * V)
    strain = -E33 * V / (t2 * C33["PZT-5H"])
    exact = np.where(y <= t1, 0.0, strain * (y - t1))
    u = u.reshape(-1, 2)
    assert u[:, 1] == pytest.approx(exact, abs=1e-10 * np.abs(exact).max())
    assert np.abs(u[:, 0]).max() <= 1e-10 * np.abs(exact).max()
    # The electrode's charge: the layer's capacitance, free along the poling (width 2).
    charge = (BETA33 + E33**2 / C33["PZT-5H"]) * V * 2.0 / t2
    assert run.record.checks["electrode_charge"] == pytest.approx(charge, rel=1e-10)


def test_a_shim_tied_to_the_electrode_carries_the_electrodes_charge(tmp_path):
    """The shim tied to the electrode (100 V), the top earthed, rollers below and on the sides:
    the PZT-5H layer between them sees phi = V (1 - y) / t2, and the electrode's free charge, read
    over the shim's dofs too, is the layer's (beta33 + e33^2 / C33) V w / t2, to round-off."""
    run = solve(DATA / "shim.toml", 4, tmp_path,
                'geometry.roles={bottom = "roller_y", sides = "roller_x", top = "ground"}',
                'scene.materials={lower = {material = "Brass", conductor = "electrode"}, upper = "PZT-5H"}')
    _, phi = read_state(tmp_path / "shim" / "n4" / "state.txt")[:2]
    y = grid(run.fields.points[:, 1], 4)
    V, t1, t2 = 100.0, 0.5, 0.5
    assert phi == pytest.approx(np.where(y <= t1, V, V * (1.0 - y) / t2), abs=1e-10 * V)
    charge = (BETA33 + E33**2 / C33["PZT-5H"]) * V * 2.0 / t2
    assert run.record.checks["electrode_charge"] == pytest.approx(charge, rel=1e-10)


@pytest.mark.parametrize("materials, message", [
    ('{lower = {material = "Brass", conductor = "free"}, upper = "PZT-5H"}',
     "scene.materials.lower.conductor = 'free': a conductor region is tied to the potential of one of the roles"),
    # Tied to the floating electrode while clamped and earthed below: freefem/floating.idp's line.
    ('{lower = {material = "Brass", conductor = "floating"}, upper = "PZT-5H"}',
     "node(s) of a floating electrode also belong to a part of fixed potential"),
    ('{lower = {material = "Brass", conductor = "electrode"}, upper = "PZT-5H"}',
     "node(s) of a conductor region would hold two potentials"),
])
def test_a_conductor_region_that_cannot_be_one_is_refused_in_one_line(tmp_path, capsys, materials, message):
    # The second: the shim tied to the electrode is clamped and earthed below (phi = 0 and V at one node).
    code = main(["solve", str(DATA / "shim.toml"), "--n", "4", "--results", str(tmp_path),
                 "--set", f"scene.materials={materials}"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == ExitCode.INPUT and len(err) == 1 and message in err[0], err


def test_a_conductor_region_without_the_potential_is_refused_in_one_line(tmp_path, capsys):
    code = main(["solve", str(DATA / "bilayer_rect.toml"), "--n", "4", "--results", str(tmp_path), "--set",
                 'scene.materials={lower = {material = "Brass", conductor = "ground"}, upper = "PZT-5H"}'])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == ExitCode.INPUT and len(err) == 1, err
    assert "scene.materials.lower.conductor = 'ground' needs the effect 'piezoelectric'" in err[0], err
    assert not (tmp_path / "bilayer_rect").exists()


@pytest.mark.parametrize("n", [4, 8])
def test_a_floating_conductor_shim_sits_at_half_the_drive(tmp_path, n):
    """tests/data/floating_shim.toml: the shim tied to the floating electrode (its dofs eliminated
    with the electrode's, freefem/floating.idp) is one unknown potential, V/2 by the symmetry of
    the series, with zero net charge; phi and u are the exact P1 fields (round-off only)."""
    run = solve(DATA / "floating_shim.toml", n, tmp_path)
    u, phi = read_state(tmp_path / "floating_shim" / f"n{n}" / "state.txt")[:2]
    y = grid(run.fields.points[:, 1], n)
    V, t = 100.0, 0.25
    exact = np.where(y <= t, V / 2 * y / t, np.where(y < 1 - t, V / 2, V / 2 + V / 2 * (y - 1 + t) / t))
    assert phi == pytest.approx(exact, abs=1e-10 * V)
    checks = run.record.checks
    assert checks["floating_potential"] == pytest.approx([V / 2], abs=1e-10 * V)
    assert abs(checks["floating_charge"][0]) <= 1e-12 * checks["floating_charge_reading"][0]
    strain = -E33 * (V / 2) / (t * C33["PZT-5H"])
    uy = np.where(y <= t, strain * y, np.where(y < 1 - t, strain * t, strain * t + strain * (y - 1 + t)))
    u = u.reshape(-1, 2)
    assert u[:, 1] == pytest.approx(uy, abs=1e-10 * np.abs(uy).max())
    assert checks["electrode_charge"] == pytest.approx((BETA33 + E33**2 / C33["PZT-5H"]) * (V / 2) * 2.0 / t, rel=1e-10)
