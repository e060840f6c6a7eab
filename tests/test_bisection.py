"""Newest-vertex bisection (harness/mesh/bisection.py): conforming, nested, area- and
role-preserving, shape-regular however often it refines; Dörfler's marking."""

from __future__ import annotations

import numpy as np
import pytest

from harness.mesh.bisection import dorfler, oriented, refine, start, uniform
from harness.mesh.simplex import SimplexMesh


def square(n: int = 4):
    """The unit square in n x n cells, each cut along one diagonal; its four sides labelled 1..4."""
    xs = np.linspace(0.0, 1.0, n + 1)
    points = np.array([(x, y) for y in xs for x in xs])
    node = lambda i, j: j * (n + 1) + i  # noqa: E731
    cells = []
    for j in range(n):
        for i in range(n):
            a, b, c, d = node(i, j), node(i + 1, j), node(i + 1, j + 1), node(i, j + 1)
            cells += [(a, b, c), (a, c, d)]
    facets, labels = [], []
    for i in range(n):
        facets += [(node(i, 0), node(i + 1, 0)), (node(n, i), node(n, i + 1)),
                   (node(i + 1, n), node(i, n)), (node(0, i + 1), node(0, i))]
        labels += [1, 2, 3, 4]
    return start(points, np.array(cells), np.array(facets), np.array(labels))


def areas(points, cells):
    p = points[cells]
    return 0.5 * ((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1]) - (p[:, 2, 0] - p[:, 0, 0]) * (p[:, 1, 1] - p[:, 0, 1]))


def min_angle(points, cells):
    p = points[cells]
    worst = np.inf
    for i in range(3):
        u, v = p[:, (i + 1) % 3] - p[:, i], p[:, (i + 2) % 3] - p[:, i]
        cos = np.einsum("ij,ij->i", u, v) / np.linalg.norm(u, axis=1) / np.linalg.norm(v, axis=1)
        worst = min(worst, np.degrees(np.arccos(np.clip(cos, -1, 1))).min())
    return worst


def assert_conforming(mesh):
    """Every edge in one or two cells; those in one are exactly the boundary facets."""
    c = mesh.cells
    edges = np.sort(np.vstack([c[:, [0, 1]], c[:, [1, 2]], c[:, [2, 0]]]), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    assert counts.max() == 2
    boundary = {tuple(e) for e in unique[counts == 1]}
    assert boundary == {tuple(sorted(f)) for f in mesh.facets.tolist()}
    assert len(np.unique(mesh.points, axis=0)) == len(mesh.points)  # no node twice


def test_refinement_near_a_corner_stays_conforming_nested_and_shape_regular():
    mesh = square()
    first = min_angle(mesh.points, mesh.cells)
    for _ in range(12):  # refine the cells touching the origin, a corner singularity's pattern
        centre = mesh.points[mesh.cells].mean(axis=1)
        near = np.linalg.norm(centre, axis=1) <= np.sort(np.linalg.norm(centre, axis=1))[2]
        coarse = mesh
        mesh = refine(mesh, near)
        assert len(mesh.cells) > len(coarse.cells)
        assert_conforming(mesh)
        assert np.abs(areas(mesh.points, mesh.cells)).sum() == pytest.approx(1.0, rel=1e-13)
        # nested: the coarse nodes are kept, and each fine cell lies in one coarse cell
        assert np.array_equal(mesh.points[:len(coarse.points)], coarse.points)
        # the roles' lengths are kept, side by side
        for label in (1, 2, 3, 4):
            f = mesh.facets[mesh.labels == label]
            assert np.linalg.norm(mesh.points[f[:, 1]] - mesh.points[f[:, 0]], axis=1).sum() == pytest.approx(1.0)
    # 12 steps toward the corner made cells 2^12 times smaller there ...
    small = np.abs(areas(mesh.points, mesh.cells)).min()
    assert small < 1.0 / 32 / 2**10
    # ... and bisection's bounded number of shapes keeps the angles: the right isosceles
    # start (45 degrees) stays at 45 degrees.
    assert min_angle(mesh.points, mesh.cells) == pytest.approx(first)


def test_a_fine_cell_lies_inside_one_coarse_cell():
    coarse = square(2)
    fine = refine(coarse, np.arange(len(coarse.cells)) % 3 == 0)
    corners = coarse.points[coarse.cells]
    for cell in fine.cells:
        centre = fine.points[cell].mean(axis=0)
        # barycentric coordinates of the fine cell's centre in every coarse cell
        inside = 0
        for a, b, c in corners:
            t = np.linalg.solve(np.column_stack([b - a, c - a]), centre - a)
            inside += (t >= -1e-12).all() and t.sum() <= 1 + 1e-12
        assert inside == 1


def test_uniform_bisection_twice_quarters_every_cell():
    mesh = square(3)
    fine = uniform(mesh, 2)
    assert len(fine.cells) == 4 * len(mesh.cells)
    assert_conforming(fine)
    assert sorted(np.round(np.abs(areas(fine.points, fine.cells)), 14)) == sorted(
        np.round(np.repeat(np.abs(areas(mesh.points, mesh.cells)) / 4, 4), 14))


def test_oriented_cells_have_positive_area_and_keep_their_refinement_edge():
    mesh = refine(square(2), np.ones(8, dtype=bool))
    assert (areas(mesh.points, mesh.cells) < 0).any()  # bisection turns children over
    turned = oriented(mesh.points, mesh.cells)
    assert (areas(mesh.points, turned) > 0).all()
    assert np.array_equal(np.sort(turned[:, :2], axis=1), np.sort(mesh.cells[:, :2], axis=1))
    assert np.array_equal(turned[:, 2], mesh.cells[:, 2])


def test_dorfler_marks_the_fewest_cells_that_hold_the_fraction():
    eta = np.array([1.0, 3.0, 2.0, 0.5])          # squares 1, 9, 4, 0.25: total 14.25
    assert dorfler(eta, 0.5).tolist() == [False, True, False, False]    # 9 >= 7.125
    assert dorfler(eta, 0.9).tolist() == [False, True, True, False]     # 13 >= 12.825
    assert dorfler(eta, 0.95).tolist() == [True, True, True, False]     # 14 >= 13.54 > 13
    assert dorfler(eta, 1.0).all()


def test_every_child_keeps_its_parents_material_region():
    """Two regions, x < 1/2 and x > 1/2 (a line of the coarse mesh): after a local refinement
    and a uniform round, every cell's centroid lies in its region's half and each region keeps
    its area exactly; a one-region mesh stays one region."""
    mesh = square(4)
    centre = mesh.points[mesh.cells].mean(axis=1)
    two = SimplexMesh(mesh.points, mesh.cells, mesh.facets, mesh.labels, np.where(centre[:, 0] < 0.5, 1, 2))
    fine = uniform(refine(two, centre[:, 0] + centre[:, 1] < 0.6))
    centre = fine.points[fine.cells].mean(axis=1)
    assert np.array_equal(fine.regions, np.where(centre[:, 0] < 0.5, 1, 2))
    area = np.abs(areas(fine.points, fine.cells))
    assert [area[fine.regions == r].sum() for r in (1, 2)] == pytest.approx([0.5, 0.5], rel=1e-14)  # round-off
    assert uniform(mesh).regions is None
