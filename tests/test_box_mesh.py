"""The 3D box meshes (harness/mesh/box_mesh.py): oriented, nested, labelled, and read by FreeFEM."""

import subprocess

import numpy as np
import pytest

from harness.mesh.box_mesh import kuhn_box
from harness.mesh.msh import write_msh
from harness.mesh.simplex import signed_measures
from harness.core.contract import ROLE_LABELS
from harness.core.errors import MeshError
from harness.core.freefem import command, environment

BOX = (4.0, 1.0, 1.0)


def paper_roles(centroid, axis, side):
    """The paper's block in 3D: clamped at x = 0, 4; loaded on [1,3] x [0,1] x {1};
    contact on [1,3] x [0,1] x {0}."""
    x = centroid[0]
    if axis == 0:
        return "clamped"
    if axis == 2:
        return ("loaded" if side > 0 else "contact") if 1 < x < 3 else "free"
    return "free"


def barycentric(points: np.ndarray, tet: np.ndarray, xs: np.ndarray) -> np.ndarray:
    a = points[tet[0]]
    m = np.column_stack([points[tet[k]] - a for k in (1, 2, 3)])
    lam = np.linalg.solve(m, (xs - a).T).T
    return np.column_stack([1 - lam.sum(axis=1), lam])


@pytest.mark.parametrize("n", [1, 2, 4])
def test_tetrahedra_are_positive_and_fill_the_box(n):
    mesh = kuhn_box(BOX, n, paper_roles)
    volumes = signed_measures(mesh.points, mesh.cells)
    assert volumes.min() > 0
    # Exact up to round-off: 6 n^3 Lx Ly Lz tetrahedra of volume h^3 / 6 each.
    assert volumes.sum() == pytest.approx(np.prod(BOX), rel=1e-12)
    assert len(mesh.cells) == 6 * round(BOX[0] * n) * round(BOX[1] * n) * round(BOX[2] * n)


def test_boundary_triangles_are_outward_and_carry_their_roles():
    mesh = kuhn_box(BOX, 4, paper_roles)
    p = mesh.points[mesh.facets]
    normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]) / 2
    centroid = p.mean(axis=1)
    # Outward: the normal points away from the box's centre on every face.
    assert np.all(np.einsum("ij,ij->i", normal, centroid - np.array(BOX) / 2) > 0)
    area = np.linalg.norm(normal, axis=1)
    totals = {role: area[mesh.labels == label].sum() for role, label in ROLE_LABELS.items() if (mesh.labels == label).any()}
    assert totals == pytest.approx({"clamped": 2.0, "loaded": 2.0, "contact": 2.0, "free": 12.0}, rel=1e-12)


def test_meshes_are_nested_under_uniform_refinement():
    # Every tetrahedron at h/2 lies inside one tetrahedron at h, so a coarse P1 field is a
    # fine P1 field (the coarse-to-fine transfer of the study is then exact).
    unit = (1.0, 1.0, 1.0)
    coarse, fine = kuhn_box(unit, 2, paper_roles), kuhn_box(unit, 4, paper_roles)
    for tet in fine.cells:
        corners = fine.points[tet]
        inside = [np.all(barycentric(coarse.points, c, corners) > -1e-12) for c in coarse.cells]
        assert sum(inside) == 1


def test_a_side_off_the_grid_is_refused():
    with pytest.raises(MeshError, match="not a positive multiple"):
        kuhn_box((4.0, 1.0, 0.3), 2, paper_roles)


def test_freefem_reads_the_mesh_with_its_volume_and_face_labels(tmp_path):
    write_msh(kuhn_box(BOX, 2, paper_roles), tmp_path / "box.msh")
    script = tmp_path / "read.edp"
    script.write_text(
        'load "msh3"\nload "gmsh"\nmesh3 Th = gmshload3("box.msh");\n'
        'cout << "volume " << Th.measure << endl;\n'
        "for (int l = 1; l <= 4; ++l) cout << \"label \" << l << \" \" << int2d(Th, l)(1.) << endl;\n"
    )
    out = subprocess.run(command(script, []), cwd=tmp_path, env=environment(), capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr
    values = dict(line.split(" ", 1) for line in out.stdout.splitlines() if line.startswith("volume"))
    assert float(values["volume"]) == pytest.approx(4.0, rel=1e-12)
    areas = {int(line.split()[1]): float(line.split()[2]) for line in out.stdout.splitlines()
             if line.startswith("label")}
    assert areas == pytest.approx({ROLE_LABELS[r]: a for r, a in
                                   {"clamped": 2.0, "loaded": 2.0, "free": 12.0, "contact": 2.0}.items()}, rel=1e-12)


def test_an_unstructured_box_mesh_is_reproducible_exact_on_its_patches_and_not_the_lattice(tmp_path):
    """geometry.diagonals = "unstructured" for a box (harness/mesh/box_mesh.py unstructured_box): gmsh's
    tetrahedra on the box cut at every patch edge. Each role's triangles cover its patches'
    area exactly (checked inside build_mesh), every volume is positive, and the same bytes
    come out on every call."""
    from pathlib import Path

    import meshio

    from harness.mesh.mesh import build_mesh
    from harness.scene.scene import load_scene

    box = load_scene(Path(__file__).parents[1] / "cases" / "hard" / "unstructured3d.toml").geometry
    first, again = build_mesh(box, 4, tmp_path / "a"), build_mesh(box, 4, tmp_path / "b")
    assert first.path.read_bytes() == again.path.read_bytes()
    assert first.role_lengths == pytest.approx({"clamped": 2.0, "loaded": 2.0, "free": 12.0, "contact": 2.0})
    mesh = meshio.read(first.path)
    tets = mesh.cells_dict["tetra"]
    assert (signed_measures(mesh.points, tets) > 0).all()
    assert signed_measures(mesh.points, tets).sum() == pytest.approx(4.0, rel=1e-12)
    assert first.nodes != 17 * 5 * 5  # not the Kuhn lattice's (4n + 1)(n + 1)^2 nodes
