"""Known answers for the harness's own numerics and checks: norms, transfer, slopes, meshes,
VTU round trip, and case-file errors."""

from __future__ import annotations

from pathlib import Path

import meshio
import numpy as np
import pytest

from harness.cli import main
from harness.errors import SceneError
from harness.fields import Fields, read_fields
from harness.mesh import build_mesh
from harness.norms import gradient_seminorm_sq, strain_seminorm_sq, transfer
from harness.rates import fitted_slope, pairwise_orders
from harness.scene import load_scene

ROOT = Path(__file__).parents[1]
PAPER = ROOT / "cases" / "paper.toml"


@pytest.fixture(scope="module")
def meshes(tmp_path_factory):
    scene = load_scene(PAPER)
    out = tmp_path_factory.mktemp("meshes")
    return {n: meshio.read(build_mesh(scene.geometry, n, out).path) for n in (2, 4)}


def points_triangles(mesh: meshio.Mesh) -> tuple[np.ndarray, np.ndarray]:
    tri = np.concatenate([c.data for c in mesh.cells if c.type == "triangle"])
    return mesh.points[:, :2], tri


def test_gradient_seminorm_of_a_linear_function_is_exact(meshes):
    pts, tri = points_triangles(meshes[4])
    xi = 3 * pts[:, 0] - 2 * pts[:, 1]
    # |grad xi|^2 = 13 over the area 4: exact for P1 up to round-off.
    assert gradient_seminorm_sq(pts, tri, xi) == pytest.approx(13 * 4, rel=1e-12)


def test_strain_seminorm_of_a_shear_is_exact(meshes):
    pts, tri = points_triangles(meshes[4])
    u = np.column_stack([0.5 * pts[:, 1], np.zeros(len(pts))])
    # eps12 = 0.25, eps:eps = 2 eps12^2 = 0.125, area 4.
    assert strain_seminorm_sq(pts, tri, u) == pytest.approx(0.125 * 4, rel=1e-12)


def test_transfer_of_a_coarse_p1_field_is_exact_on_the_nested_fine_mesh(meshes):
    """A nested fine mesh represents every coarse P1 function exactly, so the transferred
    field must have the same gradient seminorm on the fine mesh as on the coarse one."""
    cp, ct = points_triangles(meshes[2])
    fp, ft = points_triangles(meshes[4])
    values = np.random.default_rng(0).normal(size=len(cp))
    fine = transfer(Fields(cp, ct, {"f": values}, Path("coarse")), "f", fp)
    assert gradient_seminorm_sq(fp, ft, fine) == pytest.approx(gradient_seminorm_sq(cp, ct, values), rel=1e-12)
    on_coarse = np.array([np.abs(cp - p).sum(axis=1).min() < 1e-9 for p in fp])
    assert on_coarse.sum() == len(cp)  # and it interpolates: equal at the shared nodes
    np.testing.assert_allclose(np.sort(fine[on_coarse]), np.sort(values), atol=1e-12)


def test_slope_fit_and_pairwise_orders_recover_a_power_law():
    h = np.array([1 / 2, 1 / 4, 1 / 8, 1 / 16])
    errors = 3.0 * h**1.5
    assert fitted_slope(h, errors) == pytest.approx(1.5, abs=1e-12)
    np.testing.assert_allclose(pairwise_orders(h, errors)[1:], 1.5, atol=1e-12)


def test_paper_meshes_are_structured_nested_oriented_and_labelled(meshes):
    for n, mesh in meshes.items():
        pts, tri = points_triangles(mesh)
        assert len(pts) == (4 * n + 1) * (n + 1)
        a, b, c = pts[tri[:, 0]], pts[tri[:, 1]], pts[tri[:, 2]]
        area = 0.5 * ((b - a)[:, 0] * (c - a)[:, 1] - (c - a)[:, 0] * (b - a)[:, 1])
        assert np.all(area > 0)
        # Every node sits on the lattice of step h: uniform refinement nests.
        np.testing.assert_allclose(pts * n, np.round(pts * n), atol=1e-9)
        labels = np.concatenate([d for c_, d in zip(mesh.cells, mesh.cell_data["gmsh:physical"])
                                 if c_.type == "line"])
        assert set(labels) == {1, 2, 3, 4}
    coarse = {tuple(p) for p in np.round(points_triangles(meshes[2])[0] * 4).astype(int)}
    fine = {tuple(p) for p in np.round(points_triangles(meshes[4])[0] * 4).astype(int)}
    assert coarse <= fine


def test_vtu_round_trip_keeps_point_data(tmp_path):
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=float)
    u = np.array([[1, 2, 0], [3, 4, 0], [5, 6, 0]], dtype=float)
    meshio.write(tmp_path / "s.vtu", meshio.Mesh(pts, [("triangle", np.array([[0, 1, 2]]))],
                                                 point_data={"u": u, "phi": np.array([1.0, 2.0, 3.0])}))
    fields = read_fields(tmp_path / "s.vtu")
    np.testing.assert_array_equal(fields.field("u"), u[:, :2])
    np.testing.assert_array_equal(fields.field("phi"), [1.0, 2.0, 3.0])


@pytest.mark.parametrize("override, message", [
    ("contact.nope=1", "contact.nope"),
    ("contact.c_nu=-1", "contact.c_nu"),
])
def test_bad_overrides_name_the_key(override, message):
    with pytest.raises(SceneError, match=message.replace(".", r"\.")):
        load_scene(PAPER, [override])


def test_case_file_errors_are_one_line_and_exit_2(tmp_path, capsys):
    broken = tmp_path / "broken.toml"
    broken.write_text("[scene\nname = 1\n")
    unknown_material = tmp_path / "m.toml"
    unknown_material.write_text(PAPER.read_text().replace('material = "BaTiO3"', 'material = "Unobtainium"'))
    missing_key = tmp_path / "k.toml"
    missing_key.write_text(PAPER.read_text().replace("c_nu = 1e7", ""))
    for case, word in [(tmp_path / "absent.toml", "not found"), (broken, "broken.toml"),
                       (unknown_material, "Unobtainium"), (missing_key, "c_nu")]:
        code = main(["solve", str(case), "--n", "2", "--results", str(tmp_path / "r")])
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and len(err) == 1 and word in err[0], (case, err)
