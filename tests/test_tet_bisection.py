"""Longest-edge bisection of tetrahedra (harness/mesh/tet_bisection.py): conforming, nested, volume-
and role-preserving, and its quality held over repeated local refinement."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from harness.mesh import tet_bisection as tb
from harness.mesh.simplex import SimplexMesh, boundary_facets, quality, signed_measures


def cube(n: int = 2) -> SimplexMesh:
    """The unit cube in n^3 Kuhn cubes of six tetrahedra; the face z = 0 labelled 3, the rest 1."""
    xs = np.linspace(0.0, 1.0, n + 1)
    points = np.array([(x, y, z) for z in xs for y in xs for x in xs])
    node = lambda i, j, k: (k * (n + 1) + j) * (n + 1) + i  # noqa: E731
    cells = []
    for i, j, k in itertools.product(range(n), repeat=3):
        corner = [node(i + a, j + b, k + c) for c in (0, 1) for b in (0, 1) for a in (0, 1)]
        for order in itertools.permutations(range(3)):
            at, path = [0, 0, 0], [0]
            for axis in order:
                at[axis] = 1
                path.append(at[0] + 2 * at[1] + 4 * at[2])
            cells.append([corner[p] for p in path])
    cells = np.array(cells)
    facets = boundary_facets(cells)
    labels = np.where(np.isclose(points[facets].mean(axis=1)[:, 2], 0.0), 3, 1)
    return tb.start(points, cells, facets, labels)


def face_set(faces: np.ndarray) -> set[tuple[int, ...]]:
    return {tuple(f) for f in np.sort(faces, axis=1).tolist()}


def areas(points: np.ndarray, facets: np.ndarray) -> np.ndarray:
    p = points[facets]
    return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)


def test_local_refinement_toward_a_corner_is_conforming_nested_and_keeps_its_quality():
    mesh = cube()
    first = quality(mesh.points, tb.oriented(mesh.points, mesh.cells))
    for _ in range(10):
        centre = np.linalg.norm(mesh.points[mesh.cells].mean(axis=1), axis=1)
        coarse = mesh
        mesh = tb.refine(mesh, centre <= np.sort(centre)[7])
        assert len(mesh.cells) > len(coarse.cells)
        assert np.array_equal(mesh.points[:len(coarse.points)], coarse.points)  # nested: nodes kept
        # conforming: the faces met once are exactly the labelled boundary (a hanging node
        # leaves an inner face met once)
        assert face_set(boundary_facets(mesh.cells)) == face_set(mesh.facets)
        assert np.abs(signed_measures(mesh.points, mesh.cells)).sum() == pytest.approx(1.0, rel=1e-13)
        assert areas(mesh.points, mesh.facets[mesh.labels == 3]).sum() == pytest.approx(1.0, rel=1e-13)
        assert areas(mesh.points, mesh.facets[mesh.labels == 1]).sum() == pytest.approx(5.0, rel=1e-13)
    smallest = np.abs(signed_measures(mesh.points, mesh.cells)).min()
    assert smallest < (1 / 48) / 2**6  # refined toward the corner ...
    last = quality(mesh.points, tb.oriented(mesh.points, mesh.cells))
    # ... and the Kuhn tetrahedra's shapes come back: min dihedral 45 degrees, aspect 1.56 at most
    assert last["min_dihedral_deg"] >= first["min_dihedral_deg"] - 1e-9
    assert last["max_aspect"] <= 1.2 * first["max_aspect"]


def test_a_fine_tetrahedron_lies_inside_one_coarse_one():
    coarse = cube(1)
    fine = tb.refine(coarse, np.arange(len(coarse.cells)) % 2 == 0)
    corners = coarse.points[coarse.cells]
    inverse = np.linalg.inv(np.swapaxes(corners[:, 1:] - corners[:, :1], 1, 2))
    for cell in fine.cells:
        centre = fine.points[cell].mean(axis=0)
        w = np.einsum("mij,mj->mi", inverse, centre - corners[:, 0])
        inside = (w >= -1e-12).all(axis=1) & (w.sum(axis=1) <= 1 + 1e-12)
        assert inside.sum() == 1


def test_uniform_rounds_refine_every_tetrahedron():
    mesh = cube(1)
    fine = tb.uniform(mesh, 3)
    assert len(fine.cells) >= 2**3 * len(mesh.cells)  # each round cuts every tetrahedron once at least
    assert face_set(boundary_facets(fine.cells)) == face_set(fine.facets)
    assert np.abs(signed_measures(fine.points, fine.cells)).sum() == pytest.approx(1.0, rel=1e-13)


def test_the_refinement_edge_is_the_longest_and_ties_agree_across_cells():
    mesh = cube(1)
    i, j = tb.longest_edges(mesh.points, mesh.cells)
    rows = np.arange(len(mesh.cells))
    cut = np.linalg.norm(mesh.points[mesh.cells[rows, i]] - mesh.points[mesh.cells[rows, j]], axis=1)
    assert np.allclose(cut, np.sqrt(3.0))  # every Kuhn tetrahedron's longest edge: the cube's diagonal
    keys = tb.edge_key(mesh.cells[rows, i], mesh.cells[rows, j])
    assert len(np.unique(keys)) == 1  # all six share it


def test_every_child_keeps_its_parents_material_region():
    """Two regions, z < 1/2 and z > 1/2 (a plane of the Kuhn grid): after a local refinement
    and a uniform round, every tetrahedron's centroid lies in its region's half and each region
    keeps its volume exactly; a one-region mesh stays one region."""
    mesh = cube()
    centre = mesh.points[mesh.cells].mean(axis=1)
    two = SimplexMesh(mesh.points, mesh.cells, mesh.facets, mesh.labels, np.where(centre[:, 2] < 0.5, 1, 2))
    fine = tb.uniform(tb.refine(two, centre.sum(axis=1) < 1.0), 1)
    centre = fine.points[fine.cells].mean(axis=1)
    assert np.array_equal(fine.regions, np.where(centre[:, 2] < 0.5, 1, 2))
    volume = np.abs(signed_measures(fine.points, fine.cells))
    assert [volume[fine.regions == r].sum() for r in (1, 2)] == pytest.approx([0.5, 0.5], rel=1e-14)  # round-off
    assert tb.uniform(mesh, 1).regions is None
