"""Meshes: structured, nested, positively oriented, diagonals as asked, boundary roles as
labelled line elements of the right lengths; anything else is a MeshError before FreeFEM."""

from __future__ import annotations

from pathlib import Path

import meshio
import numpy as np
import pytest
from matplotlib.tri import Triangulation

from harness.core.errors import MeshError
from harness.mesh.mesh import build_mesh
from harness.mesh.mesh_check import check_mesh
from harness.scene.scene import load_scene
from harness.core.contract import ROLE_LABELS


def read(path: Path) -> tuple[np.ndarray, np.ndarray, meshio.Mesh]:
    mesh = meshio.read(path)
    triangles = np.concatenate([c.data for c in mesh.cells if c.type == "triangle"])
    return mesh.points[:, :2], triangles, mesh


def diagonal_slopes(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Sign of dx*dy of each triangle's one slanted edge."""
    edges = points[np.roll(triangles, -1, axis=1)] - points[triangles]
    product = edges[..., 0] * edges[..., 1]
    return np.sign(product[product != 0])


@pytest.fixture(scope="module")
def paper_meshes(tmp_path_factory) -> dict[str, dict[int, Path]]:
    case = Path(__file__).parent / "data" / "paper.toml"
    out = {}
    for diagonals in ("SW-NE", "NW-SE"):
        scene = load_scene(case, [f"geometry.diagonals={diagonals}"])
        directory = tmp_path_factory.mktemp(diagonals)
        out[diagonals] = {n: build_mesh(scene.geometry, n, directory).path for n in (1, 2, 4, 8)}
    return out


@pytest.mark.parametrize("n", [1, 2, 4, 8])
def test_paper_mesh_has_the_structured_node_and_triangle_counts(paper_meshes, n):
    points, triangles, _ = read(paper_meshes["SW-NE"][n])
    assert len(points) == (4 * n + 1) * (n + 1)
    assert len(triangles) == 2 * (4 * n) * n


def test_files_are_msh_2_2_named_for_their_level(paper_meshes):
    path = paper_meshes["SW-NE"][4]
    assert path.name == "mesh_n4.msh"
    assert path.read_text().splitlines()[1].split()[0] == "2.2"


@pytest.mark.parametrize("diagonals, sign", [("SW-NE", 1), ("NW-SE", -1)])
def test_every_triangle_is_positive_and_cut_along_the_requested_diagonal(paper_meshes, diagonals, sign):
    for path in paper_meshes[diagonals].values():
        points, triangles, _ = read(path)
        a, b, c = (points[triangles[:, i]] for i in range(3))
        area = 0.5 * ((b - a)[:, 0] * (c - a)[:, 1] - (c - a)[:, 0] * (b - a)[:, 1])
        assert np.all(area > 0)
        slopes = diagonal_slopes(points, triangles)
        assert len(slopes) == len(triangles) and np.all(slopes == sign)


def test_each_role_is_one_label_of_the_expected_total_length(paper_meshes):
    points, _, mesh = read(paper_meshes["SW-NE"][8])
    lines = np.concatenate([c.data for c in mesh.cells if c.type == "line"])
    tags = np.concatenate([t for c, t in zip(mesh.cells, mesh.cell_data["gmsh:physical"]) if c.type == "line"])
    length = np.linalg.norm(points[lines[:, 1]] - points[lines[:, 0]], axis=1)
    # (the roller roles of a box scene label no edge here)
    totals = {role: length[tags == label].sum() for role, label in ROLE_LABELS.items() if (tags == label).any()}
    # Sums of 8 to 32 edges of length 1/8, exact in binary: no tolerance needed.
    assert totals == {"clamped": 2.0, "loaded": 2.0, "free": 4.0, "contact": 2.0}
    assert set(mesh.field_data) >= set(totals)


def test_level_n_nodes_are_exactly_nodes_of_level_2n(paper_meshes):
    meshes = paper_meshes["SW-NE"]
    for n in (1, 2, 4):
        coarse = {tuple(p) for p in read(meshes[n])[0]}
        fine = {tuple(p) for p in read(meshes[2 * n])[0]}
        assert coarse <= fine


@pytest.mark.parametrize("diagonals", ["SW-NE", "NW-SE"])
def test_every_fine_triangle_lies_inside_one_coarse_triangle(paper_meshes, diagonals):
    """Nesting of the triangulations (not only the nodes): what makes P1 transfer exact."""
    cp, ct, _ = read(paper_meshes[diagonals][4])
    fp, ft, _ = read(paper_meshes[diagonals][8])
    coarse = Triangulation(cp[:, 0], cp[:, 1], ct)
    host = coarse.get_trifinder()(*fp[ft].mean(axis=1).T)
    assert np.all(host >= 0)
    corners = cp[ct[host]]  # (M, 3, 2)
    for k in range(3):
        v = fp[ft[:, k]]
        # Barycentric coordinates of each fine vertex in its host; round-off only, so 1e-12.
        t = np.linalg.solve(
            np.stack([corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]], axis=2),
            (v - corners[:, 0])[:, :, None],
        )[:, :, 0]
        assert np.all(t >= -1e-12) and np.all(t.sum(axis=1) <= 1 + 1e-12)


def test_a_breakpoint_off_the_lattice_is_a_mesh_error(paper_case, tmp_path):
    scene = load_scene(paper_case, ['geometry.bottom=[[0.0, 1.25, "free"], [1.25, 4.0, "contact"]]'])
    with pytest.raises(MeshError, match=r"1\.25 is not a multiple of h = 1/2"):
        build_mesh(scene.geometry, 2, tmp_path)
    assert build_mesh(scene.geometry, 4, tmp_path).nodes == 17 * 5


def test_rebuilding_an_identical_mesh_leaves_the_file_and_no_temp_files(paper_case, tmp_path):
    scene = load_scene(paper_case)
    path = build_mesh(scene.geometry, 2, tmp_path).path
    before = path.stat().st_mtime_ns
    build_mesh(scene.geometry, 2, tmp_path)
    assert path.stat().st_mtime_ns == before
    assert [p.name for p in tmp_path.iterdir()] == ["mesh_n2.msh"]


def rewrite(source: Path, target: Path, edit) -> Path:
    mesh = meshio.read(source)
    edit(mesh)
    meshio.write(target, mesh, file_format="gmsh22", binary=False)
    return target


def test_the_check_rejects_a_negatively_oriented_triangle(paper_case, paper_meshes, tmp_path):
    def flip_first(mesh):
        block = next(c for c in mesh.cells if c.type == "triangle")
        block.data[0] = block.data[0][::-1]

    bad = rewrite(paper_meshes["SW-NE"][2], tmp_path / "bad.msh", flip_first)
    with pytest.raises(MeshError, match="1 triangles are not positively oriented"):
        check_mesh(bad, load_scene(paper_case).geometry, 2)


def test_the_check_rejects_a_mesh_whose_diagonals_run_the_other_way(paper_case, paper_meshes):
    with pytest.raises(MeshError, match="diagonals do not run SW-NE"):
        check_mesh(paper_meshes["NW-SE"][2], load_scene(paper_case).geometry, 2)


def test_the_check_rejects_a_missing_role(paper_case, paper_meshes, tmp_path):
    def relabel_contact_as_free(mesh):
        for block, tags in zip(mesh.cells, mesh.cell_data["gmsh:physical"]):
            if block.type == "line":
                tags[tags == ROLE_LABELS["contact"]] = ROLE_LABELS["free"]

    bad = rewrite(paper_meshes["SW-NE"][2], tmp_path / "bad.msh", relabel_contact_as_free)
    with pytest.raises(MeshError, match="role free .* has length 6.0, expected 4.0"):
        check_mesh(bad, load_scene(paper_case).geometry, 2)


@pytest.mark.parametrize("case", ["paper.toml", "hard/unstructured.toml", "longcontact.toml"])
def test_our_msh_writer_gives_gmsh_own_bytes(case, tmp_path):
    """The GMSH style of the one MSH writer (harness/mesh/msh.py) replaces gmsh.write (which needed gmsh's per-node setNode to move
    the nodes): on a level gmsh meshed and left where it is, both files are the same bytes,
    so FreeFEM reads the same mesh, node for node, as before."""
    import gmsh

    from harness.mesh import rectangle_mesh as mesh
    from harness.mesh.msh import AS_GMSH, write_msh

    from harness.core import signals

    geometry = load_scene(Path(__file__).resolve().parents[1] / "cases" / case).geometry
    n = 8
    cells = {} if geometry.diagonals == "unstructured" else mesh.grid_cells(geometry, n)
    gmsh.initialize(readConfigFiles=False, interruptible=False)
    signals.reassert()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("scene")
        mesh.add_strips(geometry, cells, size=0.0 if cells else 1.0 / n)
        gmsh.model.mesh.generate(2)
        level, _ = mesh.read_rectangle()
        gmsh.option.setNumber("Mesh.MshFileVersion", 2.2)
        gmsh.write(str(tmp_path / "gmsh.msh"))
    finally:
        gmsh.finalize()
        signals.reassert()
    write_msh(level, tmp_path / "ours.msh", AS_GMSH)
    assert (tmp_path / "ours.msh").read_bytes() == (tmp_path / "gmsh.msh").read_bytes()


def test_the_scripts_msh_reader_gives_gmshloads_mesh(paper_case, tmp_path):
    """freefem/dimension.idp reads a 2D file itself only where gmshload would refuse small
    cells (-mesh.small_cells); elsewhere gmshload, which is 8 times faster at n = 64. Both
    must give the same mesh: vertices, triangles and boundary edges with their labels
    (the edges' direction aside)."""
    import os
    import subprocess

    from harness.core.freefem import PLUGIN_PATH

    msh = build_mesh(load_scene(paper_case).geometry, 8, tmp_path).path
    freefem = Path(__file__).resolve().parents[1] / "freefem"
    script = tmp_path / "compare.edp"
    script.write_text(f"""load "gmsh"
macro DIMENSION 2 //
include "{freefem / 'args.idp'}"
include "{freefem / 'dimension.idp'}"
mesh a = gmshload("{msh}");
mesh b = gmshLoad2D("{msh}");
real worst = 0;
for (int i = 0; i < a.nv; ++i) worst = max(worst, abs(a(i).x - b(i).x) + abs(a(i).y - b(i).y));
int differ = 0;
for (int k = 0; k < a.nt; ++k) for (int j = 0; j < 3; ++j) differ += (a[k][j] != b[k][j]);
// gmshload turns some edges round (the left side's), readmesh keeps the file's order: the same
// edge either way (FreeFEM's N on it comes from its triangle).
for (int e = 0; e < a.nbe; ++e)
  differ += (min(a.be(e)[0], a.be(e)[1]) != min(b.be(e)[0], b.be(e)[1])) + (max(a.be(e)[0], a.be(e)[1]) != max(b.be(e)[0], b.be(e)[1]))
            + (a.be(e).label != b.be(e).label);
cout << "compare " << a.nv << " " << b.nv << " " << a.nt << " " << b.nt << " " << a.nbe << " " << b.nbe << " " << worst << " " << differ << endl;
""")
    out = subprocess.run(["FreeFem++", "-nw", "-v", "0", str(script)], capture_output=True, text=True, timeout=120,
                         env=dict(os.environ, FF_LOADPATH=PLUGIN_PATH), cwd=tmp_path)
    line = next(line for line in out.stdout.splitlines() if line.startswith("compare "))
    nva, nvb, nta, ntb, nbea, nbeb, worst, differ = line.split()[1:]
    assert (nva, nta, nbea) == (nvb, ntb, nbeb)
    assert (int(nva), int(nta), int(nbea)) == (33 * 9, 2 * 32 * 8, 2 * (32 + 8))  # the (0,4)x(0,1) block at h = 1/8
    assert float(worst) == 0.0 and int(differ) == 0
