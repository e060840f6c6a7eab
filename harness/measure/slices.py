"""A plane section of a solution for pictures: the values of P1 fields on the plane
x_axis = value, as weights of mesh nodes at points with 2D coordinates in the plane and the
triangles between them. A mesh with a grid plane of nodes there (a Kuhn box, the plane of a
2D mesh) gives its own nodes; any other tetrahedral mesh (a gmsh scene) is sampled on a grid
of the plane by point location."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from matplotlib.tri import Triangulation

from harness.measure.fields import Fields
from harness.measure.norms import tetrahedron_weights


@dataclass(frozen=True)
class Section:
    """Values on a plane of the body: P1 weights of sample points and their 2D coordinates."""

    coords: np.ndarray    # (P, 2) in the plane
    nodes: np.ndarray     # (P, k) mesh nodes each sample interpolates
    weights: np.ndarray   # (P, k)
    triangles: np.ndarray

    def of(self, values: np.ndarray) -> np.ndarray:
        return np.einsum("pk,pk...->p...", self.weights, values[self.nodes])

    def triangulation(self, shift: np.ndarray | None = None) -> Triangulation:
        xy = self.coords if shift is None else self.coords + shift
        return Triangulation(xy[:, 0], xy[:, 1], self.triangles)


def plane(fields: Fields, axis: int, value: float, across: int = 160) -> Section:
    """The section x_axis = value: the mesh's own nodes when a grid plane of them lies there
    (a Kuhn mesh), else a grid of `across` samples along its longer side, inside the body."""
    others = [i for i in range(3) if i != axis]
    on = np.flatnonzero(np.abs(fields.points[:, axis] - value) < 1e-6)
    if len(on) >= 3 and len(on) >= 0.5 * len(fields.points) ** (2 / 3):
        xy = fields.points[on][:, others]
        return Section(xy, on[:, None], np.ones((len(on), 1)), Triangulation(xy[:, 0], xy[:, 1]).triangles)
    low, high = fields.points.min(axis=0)[others], fields.points.max(axis=0)[others]
    step = max(high - low) / across
    a, b = (np.arange(lo, hi + step / 2, step) for lo, hi in zip(low, high))
    ga, gb = (g.ravel() for g in np.meshgrid(a, b, indexing="ij"))
    at = np.zeros((len(ga), 3))
    at[:, axis], at[:, others[0]], at[:, others[1]] = value, ga, gb
    nodes, weights = tetrahedron_weights(fields, at, outside=None)
    inside = nodes[:, 0] >= 0
    if inside.sum() < 3:
        raise SystemExit(f"error: the plane {'xyz'[axis]} = {value} does not cut the body")
    xy = np.column_stack([ga, gb])[inside]
    tri = Triangulation(xy[:, 0], xy[:, 1])
    # Delaunay fills the concave parts of the section: keep the grid's own triangles.
    edges = xy[tri.triangles] - xy[np.roll(tri.triangles, 1, axis=1)]
    keep = np.linalg.norm(edges, axis=2).max(axis=1) < 1.5 * step
    return Section(xy, nodes[inside], weights[inside], tri.triangles[keep])


def whole(fields: Fields) -> Section:
    """A 2D solution: every node, every triangle."""
    nodes = np.arange(len(fields.points))
    return Section(fields.points[:, :2], nodes[:, None], np.ones((len(nodes), 1)), fields.triangles)
