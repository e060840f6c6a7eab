"""The seminorms of docs/model.md section 7 and the coarse-to-fine P1 transfer, against known answers."""

from __future__ import annotations

from pathlib import Path

import meshio
import numpy as np
import pytest

from harness.core.errors import FieldsError
from harness.measure.fields import Fields, read_fields
from harness.mesh.mesh import build_mesh
from harness.core.layout import REPO
from harness.measure.norm_table import FIELD_NAMES, MEASURE, MMS_NORMS, norm_table_idp, norm_table_path
from harness.measure.norms import (EXACT_INTEGRANDS, P1_INTEGRANDS, error_norms, exact_errors, gradient_seminorm_sq, seminorm,
                           strain_seminorm_sq, transfer)
from harness.scene.unknowns import FIELDS
from harness.scene.scene import load_scene

AREA = 4.0  # the paper's (0,4)x(0,1)
# Each norm is a sum of a few hundred positive terms of exact P1 gradients: relative
# round-off stays far below 1e-12.
ROUND_OFF = 1e-12


@pytest.fixture(scope="module")
def meshes(tmp_path_factory) -> dict[int, Fields]:
    scene = load_scene(Path(__file__).parent / "data" / "paper.toml")
    out = tmp_path_factory.mktemp("meshes")
    found = {}
    for n in (2, 3, 4, 8):
        mesh = meshio.read(build_mesh(scene.geometry, n, out).path)
        triangles = np.concatenate([c.data for c in mesh.cells if c.type == "triangle"])
        found[n] = Fields(mesh.points[:, :2], triangles, {}, Path(f"mesh_n{n}"))
    return found


def with_values(mesh: Fields, **values: np.ndarray) -> Fields:
    return Fields(mesh.points, mesh.triangles, values, mesh.source)


def test_gradient_seminorm_of_a_linear_function(meshes):
    p = meshes[4].points
    xi = 3 * p[:, 0] - 2 * p[:, 1]
    # |grad xi|^2 = 3^2 + 2^2 = 13 everywhere.
    assert gradient_seminorm_sq(p, meshes[4].triangles, xi) == pytest.approx(13 * AREA, rel=ROUND_OFF)


@pytest.mark.parametrize("a", [1.0, -2.5, 1e-9])
def test_strain_seminorm_of_a_simple_shear(meshes, a):
    p = meshes[4].points
    u = np.column_stack([a * p[:, 1], np.zeros(len(p))])
    # eps12 = eps21 = a/2, the rest zero: eps:eps = 2 (a/2)^2.
    expected = 2 * (a / 2) ** 2 * AREA
    assert strain_seminorm_sq(p, meshes[4].triangles, u) == pytest.approx(expected, rel=ROUND_OFF)


def test_strain_seminorm_of_a_dilation_and_of_a_rigid_rotation(meshes):
    p, t = meshes[4].points, meshes[4].triangles
    dilation = p.copy()  # eps = I: eps:eps = 2
    assert strain_seminorm_sq(p, t, dilation) == pytest.approx(2 * AREA, rel=ROUND_OFF)
    rotation = np.column_stack([-p[:, 1], p[:, 0]])  # no strain at all
    assert strain_seminorm_sq(p, t, rotation) == pytest.approx(0.0, abs=ROUND_OFF)


def test_norms_do_not_depend_on_triangle_orientation(meshes):
    p, t = meshes[4].points, meshes[4].triangles
    xi = np.sin(p[:, 0]) * p[:, 1]
    assert gradient_seminorm_sq(p, t[:, ::-1], xi) == pytest.approx(gradient_seminorm_sq(p, t, xi), rel=ROUND_OFF)


def test_seminorm_picks_V_for_vectors_and_W_for_scalars(meshes):
    p, t = meshes[2].points, meshes[2].triangles
    assert seminorm(p, t, 3 * p[:, 0]) == pytest.approx(np.sqrt(9 * AREA), rel=ROUND_OFF)
    assert seminorm(p, t, p.copy()) == pytest.approx(np.sqrt(2 * AREA), rel=ROUND_OFF)


@pytest.mark.parametrize("coarse_n, fine_n", [(2, 4), (2, 8), (3, 4)])  # (3, 4) is not nested
def test_transfer_reproduces_a_linear_function_exactly(meshes, coarse_n, fine_n):
    """P1 contains the linear functions, so nested or not their transfer is exact."""
    cp, fp = meshes[coarse_n].points, meshes[fine_n].points
    coarse = with_values(meshes[coarse_n], phi=1 + 3 * cp[:, 0] - 2 * cp[:, 1], u=cp * [0.5, -1.0])
    # Absolute 1e-12 against values of order 10: round-off of barycentric weights.
    np.testing.assert_allclose(transfer(coarse, "phi", fp), 1 + 3 * fp[:, 0] - 2 * fp[:, 1], atol=1e-12)
    np.testing.assert_allclose(transfer(coarse, "u", fp), fp * [0.5, -1.0], atol=1e-12)


def test_transfer_to_a_nested_mesh_loses_nothing(meshes):
    """Any coarse P1 field, transferred to a nested fine mesh, is the same function: the
    error against itself is zero and its seminorm is unchanged."""
    rng = np.random.default_rng(1)
    cp = meshes[2].points
    coarse = with_values(meshes[2], theta=rng.normal(size=len(cp)), u=rng.normal(size=(len(cp), 2)))
    fine = meshes[8]
    same = with_values(fine, theta=transfer(coarse, "theta", fine.points), u=transfer(coarse, "u", fine.points))
    errors = error_norms(coarse, same, ["u", "theta"])
    # Random values of order 1 on 1/8-size triangles: round-off only.
    assert errors["u"] < 1e-11 and errors["theta"] < 1e-11
    assert gradient_seminorm_sq(fine.points, fine.triangles, same.values["theta"]) == pytest.approx(
        gradient_seminorm_sq(cp, coarse.triangles, coarse.values["theta"]), rel=ROUND_OFF
    )


def test_error_norms_measure_the_difference_on_the_fine_mesh(meshes):
    cp, fp = meshes[2].points, meshes[4].points
    coarse = with_values(meshes[2], phi=np.zeros(len(cp)))
    fine = with_values(meshes[4], phi=3 * fp[:, 0] - 2 * fp[:, 1])
    assert error_norms(coarse, fine, ["phi"])["phi"] == pytest.approx(np.sqrt(13 * AREA), rel=ROUND_OFF)


def test_points_outside_the_coarse_mesh_are_an_error(meshes):
    coarse = with_values(meshes[2], phi=np.zeros(len(meshes[2].points)))
    with pytest.raises(FieldsError, match="outside the coarse mesh"):
        transfer(coarse, "phi", np.array([[5.0, 0.5]]))


def test_fields_by_name_from_a_vtu(tmp_path):
    points = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=float)
    mesh = meshio.Mesh(
        points, [("triangle", np.array([[0, 1, 2]]))],
        point_data={"u": np.array([[1, 2, 0], [3, 4, 0], [5, 6, 0]], float), "phi": np.array([1.0, 2, 3])},
    )
    meshio.write(tmp_path / "solution.vtu", mesh)
    fields = read_fields(tmp_path / "solution.vtu")
    assert fields.points.shape == (3, 2) and fields.triangles.tolist() == [[0, 1, 2]]
    assert fields.field("u").tolist() == [[1, 2], [3, 4], [5, 6]]
    with pytest.raises(FieldsError, match="no field 'theta'"):
        fields.field("theta")


def test_a_missing_solution_file_is_an_error(tmp_path):
    with pytest.raises(FieldsError, match="solution file not found"):
        read_fields(tmp_path / "solution.vtu")


def test_errors_against_exact_functions(meshes):
    """The manufactured-solution norms: zero for a linear field (P1 holds it exactly); the
    vector field 0 against (x, 2x - y) on (0,4)x(0,1): int x^2 = 64/3, int (2x - y)^2 = 212/3,
    and |grad|^2 = 1 + 5 everywhere."""
    mesh = meshes[4]
    x, y = mesh.points[:, 0], mesh.points[:, 1]
    linear = (lambda a, b: 2 * a - b, lambda a, b: 2 + 0 * a, lambda a, b: -1 + 0 * a)
    zero = exact_errors(mesh.points, mesh.triangles, 2 * x - y, [linear])
    assert zero["L2"] < ROUND_OFF and zero["H1"] < ROUND_OFF
    ramp = (lambda a, b: a, lambda a, b: 1 + 0 * a, lambda a, b: 0 * a)
    errors = exact_errors(mesh.points, mesh.triangles, np.zeros((len(x), 2)), [ramp, linear])
    assert errors["L2"] ** 2 == pytest.approx(64 / 3 + 212 / 3, rel=ROUND_OFF)
    assert errors["H1"] ** 2 == pytest.approx(AREA * (1 + 5), rel=ROUND_OFF)


def test_point_location_in_unstructured_tetrahedra_reproduces_linear_fields(tmp_path):
    """The error transfer on non-nested 3D meshes (norms.tetrahedron_weights): P1 interpolation
    is exact for a linear field at any point; on a Kuhn mesh it finds the tetrahedra the
    grid-based kuhn_weights finds, with the same weights."""
    from harness.mesh.box_mesh import grid_index, kuhn_box, kuhn_weights
    from harness.measure.norms import tetrahedron_weights

    box = load_scene(Path(__file__).parents[1] / "cases" / "hard" / "unstructured3d.toml").geometry
    raw = meshio.read(build_mesh(box, 4, tmp_path).path)
    coarse = Fields(raw.points, np.zeros((0, 3), dtype=int), {}, tmp_path, raw.cells_dict["tetra"])
    at = np.random.default_rng(1).uniform([0, 0, 0], box.lengths, (500, 3))
    at = np.vstack([at, raw.points[:50]])  # mesh nodes too (on faces, edges, corners)
    nodes, w = tetrahedron_weights(coarse, at)
    linear = lambda x: 1.0 + 2.0 * x[..., 0] - 3.0 * x[..., 1] + 0.5 * x[..., 2]
    assert np.allclose(w.sum(axis=1), 1.0) and (w >= -1e-5).all()
    assert np.allclose(np.einsum("nk,nk->n", w, linear(raw.points[nodes])), linear(at), rtol=0, atol=1e-10)

    kuhn = kuhn_box(box.lengths, 4, box.role_of)
    structured = Fields(kuhn.points, np.zeros((0, 3), dtype=int), {}, tmp_path, kuhn.cells)
    inside = at[:500]
    grid, spacing = grid_index(kuhn.points)
    expected_nodes, expected_w = kuhn_weights(kuhn.points, grid, spacing, inside)
    got_nodes, got_w = tetrahedron_weights(structured, inside)
    value = np.random.default_rng(2).normal(size=len(kuhn.points))  # any P1 field
    assert np.allclose(np.einsum("nk,nk->n", got_w, value[got_nodes]),
                       np.einsum("nk,nk->n", expected_w, value[expected_nodes]), atol=1e-12)


def test_committed_norm_table_idp_is_generated_from_the_table():
    """freefem/norm_table.idp is `python -m harness.measure.norm_table`'s output: FreeFEM and Python
    measure each field in the same norm."""
    assert norm_table_path().read_text() == norm_table_idp()


def test_every_norm_of_the_table_has_its_integrands_in_both_languages():
    """Each stem the table names is an integrand of freefem/norms.idp (of a difference and of a
    field alone) and of harness/measure/norms.py; the error measure covers every field once."""
    idp = (REPO / "freefem" / "norms.idp").read_text()
    for stem in {t.stem for t in MEASURE} | {s for n in MMS_NORMS for s in (n.vector, n.scalar)}:
        assert f"macro {stem}DiffSq(s, a, b)" in idp and f"macro {stem}Sq(b)" in idp, stem
    assert {t.stem for t in MEASURE} <= set(P1_INTEGRANDS)
    assert {n.scalar for n in MMS_NORMS} <= set(EXACT_INTEGRANDS)
    assert [t.field for t in MEASURE] == list(FIELD_NAMES) == [f.name for f in FIELDS]
    # docs/model.md section 7: u in the strain (energy) norm V, phi and theta in W, Q = |grad|.
    assert [(t.norm, t.stem) for t in MEASURE] == [("V", "strain"), ("W", "grad"), ("Q", "grad")]
