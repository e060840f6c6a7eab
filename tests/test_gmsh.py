"""Scenes drawn in gmsh (issue 22): the paper's scene as a .geo is the same model on the same
meshes; a tilted contact face meets the known answers of the axis-aligned one; a 3D gmsh
scene runs with its checks; every bad geometry input ends with one line and exit code 2."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import meshio
import numpy as np
import pytest

from harness.measure.checks import contact_node_count, contact_nodes, contact_normal
from harness.cli import main
from harness.core.contract import ExitCode, ROLE_LABELS
from harness.core.errors import MeshError
from harness.mesh.gmsh_mesh import oriented
from harness.mesh.simplex import quality
from harness.mesh.mesh import build_mesh
from harness.scene.scene import load_scene
from harness.measure.fields import read_state
from physics_runs import CASES, DATA, solve
from test_parallel import RTOL, mpi_missing

ALPHA = math.pi / 6  # the tilt of tests/data/tilted_*.geo
NU = np.array([math.sin(ALPHA), -math.cos(ALPHA)])  # their contact part's outward normal
TAU = np.array([-NU[1], NU[0]])  # the 2D tangent (-nu_y, nu_x), as freefem/dimension.idp's


def by_position(points: np.ndarray) -> np.ndarray:
    """Row order that sorts points by their coordinates rounded far below h (the two meshes'
    nodes agree to round-off of gmsh's transfinite placement)."""
    return np.lexsort(np.round(points, 9).T[::-1])


@pytest.mark.parametrize("n", [2, 4])
def test_the_paper_drawn_in_gmsh_is_the_same_model_on_the_same_mesh(tmp_path, n):
    """cases/paper_gmsh.toml (geo/paper.geo, split from n = 2) gives cases/paper.toml's mesh
    and solution: the gmsh path changes nothing but the numbering of the nodes."""
    ours = solve(CASES / "paper_gmsh.toml", n, tmp_path)
    theirs = solve(CASES / "paper.toml", n, tmp_path)
    a, b = by_position(ours.fields.points), by_position(theirs.fields.points)
    np.testing.assert_allclose(ours.fields.points[a], theirs.fields.points[b], rtol=0, atol=1e-12)
    # The same triangles (as sets of positions) and the same boundary labels.
    rank_a, rank_b = np.empty_like(a), np.empty_like(b)
    rank_a[a], rank_b[b] = np.arange(len(a)), np.arange(len(b))
    tri = lambda rank, cells: {tuple(sorted(t)) for t in rank[cells].tolist()}
    assert tri(rank_a, ours.fields.triangles) == tri(rank_b, theirs.fields.triangles)
    for name in ("u", "phi", "theta"):
        x, y = ours.fields.field(name)[a], theirs.fields.field(name)[b]
        # The same nodes and triangles in another numbering: another LU ordering, so Newton's
        # iterates differ by round-off and its last step (relative increment < rtol = 1e-9,
        # quadratic) leaves them ~1e-12 apart: measured <= 5.1e-12 (u), 1.1e-12 (phi),
        # 2.5e-12 (theta) of the field's size at n = 2, 4, 8, 16; 1e-10 leaves a 20x margin.
        np.testing.assert_allclose(x, y, rtol=0, atol=1e-10 * np.abs(y).max())
    for key in ("contact_force", "heat_in_contact", "charge_in_contact"):
        assert ours.record.value(key) == pytest.approx(theirs.record.value(key), rel=1e-10)  # measured <= 1.1e-12
    assert ours.record.newton_iterations == theirs.record.newton_iterations


def test_split_levels_nest_and_report_their_quality(tmp_path):
    """Level 4 of a split scene holds every node of level 2 (a coarse P1 field is a fine one);
    each level's summary has its min angle and max aspect, and the structured right
    triangles of the paper's mesh have 45 degrees and R / (2 r) = (1 + sqrt 2) / 2."""
    scene = load_scene(CASES / "paper_gmsh.toml")
    coarse, fine = (build_mesh(scene.geometry, n, tmp_path) for n in (2, 4))
    pc, pf = (meshio.read(m.path).points for m in (coarse, fine))
    keys = {tuple(p) for p in np.round(pf, 12).tolist()}
    assert all(tuple(p) in keys for p in np.round(pc, 12).tolist())
    assert fine.quality["min_angle_deg"] == pytest.approx(45.0, abs=1e-9)
    # A right isosceles triangle with legs 1: R = sqrt(2) / 2, r = (2 - sqrt 2) / 2.
    assert fine.quality["max_aspect"] == pytest.approx((1.0 + math.sqrt(2.0)) / 2.0, rel=1e-9)
    assert fine.role_lengths == pytest.approx({"clamped": 2.0, "contact": 2.0, "free": 4.0, "loaded": 2.0})


def test_a_3d_gmsh_scene_runs_with_its_checks_and_reports_its_dihedral_angles(tmp_path):
    """cases/paper3d_gmsh.toml (gmsh's tetrahedra of the paper's block) at n = 2: the contact
    normal read from the mesh is -z and the contact part covers [1,3] x [0,1]."""
    run = solve(CASES / "paper3d_gmsh.toml", 2, tmp_path)
    assert run.record.converged
    scene = load_scene(CASES / "paper3d_gmsh.toml")
    np.testing.assert_allclose(contact_normal(scene, run.fields), [0.0, 0.0, -1.0], atol=1e-12)
    assert scene.geometry.contact_measure() == pytest.approx(2.0, rel=1e-12)
    mesh = build_mesh(scene.geometry, 2, tmp_path / "m")
    assert 0.0 < mesh.quality["min_dihedral_deg"] < 70.6 and mesh.quality["max_aspect"] >= 1.0
    assert mesh.role_lengths["contact"] == pytest.approx(2.0, rel=1e-12)


# ---- a tilted contact face: the known answers of tests/test_physics.py (b), (c) -----------

def test_tilted_face_under_uniform_pressure_carries_the_load_with_penetration_load_over_penalty(tmp_path):
    """(b) turned by 30 degrees: the contact normal comes from the mesh, the contact force
    equals the load and the penetration u . nu is p / c_nu at every node of Gamma_3."""
    run = solve(DATA / "tilted_block.toml", 8, tmp_path)
    scene = load_scene(DATA / "tilted_block.toml")
    assert run.record.converged
    np.testing.assert_allclose(contact_normal(scene, run.fields), NU, atol=1e-6)  # single-precision VTU
    # Equilibrium along nu is exact up to Newton's final residual, as in (b).
    assert run.record.contact_force == pytest.approx(100.0 * 2.0, rel=1e-7)
    nodes = np.concatenate(contact_nodes(scene, run.fields))
    assert len(nodes) == contact_node_count(scene, run.fields) == 2 * 8 + 1
    penetration = run.fields.field("u")[nodes] @ NU
    # (b)'s tolerance and reason: the tangential penalty restrains the Poisson expansion
    # (measured 6.2e-7 here, so the tilt costs nothing against it).
    assert penetration == pytest.approx(np.full(len(nodes), 100.0 / 1e7), rel=1e-3)


def test_tilted_face_sticks_below_the_bound_with_friction_along_the_tangent(tmp_path):
    """(c) turned: a shear of 4.25 N/m^2 along the face's tangent, S = 8.5: no node slips and
    the friction force is 8.5 N/m along the tangent (nothing along the normal)."""
    tx, ty = (float(t) for t in 100.0 * NU + 4.25 * TAU)
    run = solve(DATA / "tilted_block.toml", 8, tmp_path, f"loads.traction_x={tx!r}", f"loads.traction_y={ty!r}",
                "contact.S=8.5")
    assert run.record.converged
    assert run.record.slip_nodes[-1] == 0
    assert run.record.friction_force == pytest.approx(4.25 * 2.0, rel=1e-7)
    assert run.record.friction_force_vector == pytest.approx(list(4.25 * 2.0 * TAU), rel=1e-7, abs=1e-12)


def test_tilted_face_slips_above_the_bound_with_shear_equal_to_the_bound(tmp_path):
    """(c) turned: the paper's scene tilted by 30 degrees, S = 1e-3 N/m^2 and a shear of 100
    N/m^2 along the tangent on top: where c_nu |u_tau| >= S the contact carries exactly S."""
    tx, ty = (float(t) for t in 100.0 * NU + 100.0 * TAU)
    run = solve(DATA / "tilted_paper.toml", 8, tmp_path, f"loads.traction_x={tx!r}", f"loads.traction_y={ty!r}",
                "contact.S=1e-3")
    assert run.record.converged
    scene = load_scene(DATA / "tilted_paper.toml")
    nodes = np.concatenate(contact_nodes(scene, run.fields))
    assert len(nodes) == 2 * 8 + 1
    u_tau = run.fields.field("u")[nodes] @ TAU
    shear = run.fields.field("contact_shear")[nodes]
    slipping = 1e7 * np.abs(u_tau) >= 1e-3
    assert slipping.sum() >= 0.75 * len(nodes)
    assert run.record.slip_nodes[-1] == slipping.sum()
    np.testing.assert_allclose(shear[slipping], 1e-3 * np.sign(u_tau[slipping]), rtol=1e-12)
    assert np.all(np.abs(shear[~slipping]) < 1e-3)
    assert abs(run.record.friction_force) <= 1e-3 * 2.0


# ---- bad input: one line, exit code 2 ------------------------------------------------------

def variant(tmp: Path, toml: dict[str, str] | None = None, geo: dict[str, str] | None = None,
            source: Path = CASES / "paper_gmsh.toml") -> Path:
    """A copy of a gmsh case (and its .geo) in tmp with text replaced in either."""
    (tmp / "geo").mkdir(parents=True, exist_ok=True)
    for path in (CASES / "geo").glob("*.geo"):
        text = path.read_text()
        for old, new in (geo or {}).items():
            text = text.replace(old, new)
        (tmp / "geo" / path.name).write_text(text)
    text = source.read_text()
    for old, new in (toml or {}).items():
        assert old in text, old
        text = text.replace(old, new)
    case = tmp / "case.toml"
    case.write_text(text)
    return case


NO_FRICTION = 'effects = ["piezoelectric", "thermal", "contact"]'
PAPER_EFFECTS = ('effects = ["piezoelectric", "thermal", "pyroelectric", "contact", "friction", '
                 '"electric_contact", "thermal_contact"]')

BAD = {
    "missing file": ({"geo/paper.geo": "geo/nope.geo"}, None, "no such file"),
    "gmsh syntax error": (None, {"Line(1 + i) = {1 + i, 2 + i};": "Line(1 + i) = {1 + i, 2 + i;"}, "gmsh cannot read paper.geo"),
    "a name with no role": ({'top_free = "free"\n': ""}, None, "physical curve 'top_free' has no role"),
    "a role with no group": ({'top_free = "free"\n': 'top_free = "free"\nghost = "free"\n'}, None,
                             "no physical curve named 'ghost'"),
    "a group that holds nothing": (None, {'Physical Curve("foundation") = {2};': 'Physical Curve("foundation") = {99};'},
                                   "no physical curve named 'foundation'"),
    "no clamped part": ({'ends = "clamped"': 'ends = "free"', PAPER_EFFECTS: NO_FRICTION}, None, "no part is clamped"),
    "an empty contact part": ({'foundation = "contact"': 'foundation = "free"'}, None, "the contact part is empty"),
    "a 2D file for a 3D scene": ({"dimension = 2": "dimension = 3"}, None, "draws a 2D body but geometry.dimension = 3"),
    "a 3D file for a 2D scene": ({"geo/paper.geo": "geo/block3d.geo"}, None, "draws a 3D body but geometry.dimension = 2"),
    "an unnamed boundary part": ({'top_free = "free"\n': ""}, {'Physical Curve("top_free") = {4, 6};': ""},
                                 "is in no named part"),
    "a poling axis of zero length": ({'coarsest_guess = "zero"': 'coarsest_guess = "zero"\npoling_axis = [0.0, 0.0]'},
                                     None, "scene.poling_axis = [0.0, 0.0] has zero length"),
    "remesh of a file that fixes its mesh": ({'levels = "split"': 'levels = "remesh"'}, None,
                                             "so remesh cannot refine it"),
    "quadrilaterals": (None, {"Transfinite Curve{7:10}": "Recombine Surface{1:3};\nTransfinite Curve{7:10}"},
                       "only first-order triangles (2D) and tetrahedra (3D) are solved"),
    "a split level off the coarsest's powers of 2": ({"coarsest = 2": "coarsest = 3"}, None,
                                                     "must be the coarsest level 3 times a power of 2"),
}


@pytest.mark.parametrize("name", list(BAD))
def test_bad_geometry_input_is_refused_with_one_line_and_exit_code_2(tmp_path, capsys, name):
    toml, geo, message = BAD[name]
    case = variant(tmp_path, toml, geo)
    code = main(["solve", str(case), "--n", "4", "--results", str(tmp_path / "results")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == ExitCode.INPUT == 2
    assert len(err) == 1 and err[0].startswith("error:") and message in err[0], err


def test_a_curved_contact_part_is_refused_naming_a_facet(tmp_path, capsys):
    """A half disc resting on its arc: the arc's facets turn by h / R from each other."""
    case = variant(tmp_path, {'bottom_free = "free"\npressed = "loaded"\ntop_free = "free"\n': ""})
    (tmp_path / "geo" / "paper.geo").write_text(
        "SetFactory(\"OpenCASCADE\");\nDisk(1) = {2, 1, 0, 1};\nRectangle(2) = {1, 1, 0, 2, 1};\n"
        "BooleanDifference{ Surface{1}; Delete; }{ Surface{2}; Delete; }\n"
        "e = 1e-6;\nflat[] = Curve In BoundingBox{1 - e, 1 - e, -e, 3 + e, 1 + e, e};\n"
        "all[] = Boundary{ Surface{1}; };\narc[] = all[];\narc[] -= flat[];\n"
        "Physical Curve(\"ends\") = flat[];\nPhysical Curve(\"foundation\") = arc[];\n")
    code = main(["solve", str(case), "--n", "4", "--results", str(tmp_path / "results")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "the contact part is not flat" in err[0], err


def test_an_inverted_or_degenerate_element_is_refused_naming_it():
    """Two triangles of one surface, the second turned over; then a flat one."""
    points = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    cells = np.array([[0, 1, 2], [1, 2, 3]])  # (1, 2, 3) is clockwise
    with pytest.raises(MeshError, match=r"triangle 2 at \(0.666667, 0.666667\) is inverted"):
        oriented(points, cells, np.array([7, 7]), 2)
    flat = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    with pytest.raises(MeshError, match="triangle 1 at .* is degenerate"):
        oriented(flat, np.array([[0, 1, 2]]), np.array([1]), 2)
    # A surface gmsh drew clockwise as a whole is turned over, not refused.
    turned = oriented(points, np.array([[0, 2, 1], [1, 2, 3]]), np.array([7, 7]), 2)
    assert quality(points, turned)["min_angle_deg"] == pytest.approx(45.0)


def test_the_poling_axis_may_be_named_or_given_as_the_default_unit_vector():
    for value in ('"y"', "[0.0, 2.0]"):
        assert load_scene(CASES / "paper_gmsh.toml", [f"scene.poling_axis={value}"]).dimension == 2
    assert load_scene(CASES / "paper3d_gmsh.toml", ['scene.poling_axis=[0, 0, 1]']).dimension == 3


def test_a_gmsh_scene_may_be_poled_along_any_axis():
    assert load_scene(CASES / "paper_gmsh.toml", ['scene.poling_axis="x"']).poling.axis == (1.0, 0.0)
    assert load_scene(CASES / "paper3d_gmsh.toml", ['scene.poling_axis="-z"']).poling.axis == (0.0, 0.0, -1.0)


def test_a_role_added_to_the_contract_flows_through_to_the_mesh_labels(tmp_path, monkeypatch):
    """A role added to ROLE_LABELS (as the electrode role of the device scenes) is accepted
    in [geometry.roles] and written as its label, with no edit to the gmsh code."""
    monkeypatch.setitem(ROLE_LABELS, "electrode", 8)
    case = variant(tmp_path, {'top_free = "free"': 'top_free = "electrode"'})
    # Not piezoelectric: on the paper's outline this part touches the clamped ends, two
    # potentials at one point, which a piezoelectric scene refuses when it loads.
    mesh = build_mesh(load_scene(case, ['scene.effects=["contact"]']).geometry, 2, tmp_path / "m")
    assert mesh.role_lengths["electrode"] == pytest.approx(2.0)
    tags = np.concatenate(meshio.read(mesh.path).cell_data["gmsh:physical"])
    assert 8 in set(tags.tolist())


@pytest.mark.skipif(bool(mpi_missing()), reason=mpi_missing() or "-")
def test_a_tilted_gmsh_scene_on_two_ranks_gives_the_one_rank_solution(tmp_path):
    """The tilted paper scene (split from n = 2) at n = 8 on 2 MPI ranks: the state agrees
    with one rank's to Newton's tolerance (test_parallel's criterion), so do the forces."""
    one = solve(DATA / "tilted_paper.toml", 8, tmp_path, "scene.name=one")
    two = solve(DATA / "tilted_paper.toml", 8, tmp_path, "scene.name=two", "run.ranks=2")
    for name, a, b in zip(("u", "phi", "theta"), read_state(tmp_path / "one/n8/state.txt"),
                          read_state(tmp_path / "two/n8/state.txt")):
        assert np.abs(a - b).max() <= RTOL * np.abs(a).max(), name
    assert two.record.ranks == 2 and min(two.record.parallel["contact_nodes_per_rank"]) >= 1
    assert two.record.contact_force == pytest.approx(one.record.contact_force, rel=1e-8)


def turned_normal() -> np.ndarray:
    """R (0, 0, -1) for R the turn of tests/data/tilted_cube.geo: 30 degrees about (1, 1, 0)."""
    a = np.array([1.0, 1.0, 0.0]) / math.sqrt(2.0)
    k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    rotation = np.eye(3) + math.sin(ALPHA) * k + (1.0 - math.cos(ALPHA)) * k @ k
    return rotation @ np.array([0.0, 0.0, -1.0])


def test_a_turned_cube_under_uniform_pressure_carries_the_load_in_3d(tmp_path):
    """(b) in 3D on gmsh's tetrahedra: a unit cube turned about an oblique axis, pressed along
    its contact face's normal: that normal read from the mesh, contact force = load, and
    u . nu = p / c_nu on Gamma_3."""
    run = solve(DATA / "tilted_cube.toml", 4, tmp_path)
    scene = load_scene(DATA / "tilted_cube.toml")
    nu = turned_normal()
    assert run.record.converged
    np.testing.assert_allclose(contact_normal(scene, run.fields), nu, atol=1e-6)  # single-precision VTU
    assert run.record.contact_force == pytest.approx(100.0, rel=1e-7)  # area 1 m^2; (b)'s tolerance
    nodes = np.concatenate(contact_nodes(scene, run.fields))
    penetration = run.fields.field("u")[nodes] @ nu
    # Measured within 8e-10 of p / c_nu at n = 4 (153 nodes); 1e-6 bounds the tangential
    # penalty's restraint of the base's Poisson expansion that (b) allows 1e-3 for in 2D.
    assert penetration == pytest.approx(np.full(len(nodes), 100.0 / 1e7), rel=1e-6)


def test_tilted_face_sticks_below_mu_pressure_with_coulomb_friction(tmp_path):
    """test_coulomb's stick answer turned by 30 degrees: mu = 0.3, a shear of 0.5 mu p along
    the face's tangent sticks everywhere and friction carries all of it."""
    shear = 0.5 * 0.3 * 100.0
    tx, ty = (float(t) for t in 100.0 * NU + shear * TAU)
    run = solve(DATA / "tilted_block.toml", 8, tmp_path, f"loads.traction_x={tx!r}", f"loads.traction_y={ty!r}",
                'contact.friction_law="coulomb"', "contact.mu=0.3")
    assert run.record.converged
    assert run.record.slip_nodes[-1] == 0
    assert run.record.friction_force_vector == pytest.approx(list(shear * 2.0 * TAU), rel=1e-7, abs=1e-12)


def test_the_guards_count_a_gmsh_levels_nodes_exactly_when_split_and_above_when_remeshed(tmp_path):
    """The memory and disk guards size a gmsh level from the coarsest mesh's vertex, edge,
    (face,) cell counts: exact for split levels (each split adds a node per edge), an upper
    bound for remeshed ones (measured 1.24-1.43x on the wedge at n = 4 ... 16)."""
    for case, n in ((CASES / "paper3d_gmsh.toml", 4), (CASES / "paper_gmsh.toml", 8)):
        geometry = load_scene(case).geometry
        assert build_mesh(geometry, n, tmp_path / case.stem).nodes == geometry.nodes_at(n)
    wedge = load_scene(CASES / "hard" / "gmsh_wedge.toml").geometry
    made = build_mesh(wedge, 8, tmp_path / "wedge").nodes
    # gmsh's sizes are a target, not a bound (Frontal-Delaunay); 1.5 leaves room for that.
    assert made <= wedge.nodes_at(8) <= 1.5 * made
