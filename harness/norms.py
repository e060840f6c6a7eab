"""P1 transfer between meshes and the seminorms of docs/model.md section 7, on the fine mesh.

    ||v||_V^2 = int eps(v):eps(v),   ||xi||_W^2 = ||eta||_Q^2 = int |grad xi|^2

P1 gradients are constant per triangle, so the integrals are exact sums of area x integrand.
"""

from __future__ import annotations

import numpy as np
from matplotlib.tri import Triangulation

from harness.errors import FieldsError
from harness.fields import Fields


def gradients(points: np.ndarray, triangles: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-triangle (d/dx, d/dy) of the P1 function with nodal `values`, and |area|."""
    x, y = points[triangles, 0], points[triangles, 1]  # (M, 3)
    v = values[triangles]
    twice = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0])
    # Gradient of the barycentric coordinate of vertex i: the opposite edge turned by 90 degrees.
    bx = np.roll(y, -1, axis=1) - np.roll(y, -2, axis=1)
    by = np.roll(x, -2, axis=1) - np.roll(x, -1, axis=1)
    dx = (v * bx).sum(axis=1) / twice
    dy = (v * by).sum(axis=1) / twice
    return dx, dy, 0.5 * np.abs(twice)


def gradient_seminorm_sq(points: np.ndarray, triangles: np.ndarray, values: np.ndarray) -> float:
    dx, dy, area = gradients(points, triangles, values)
    return float(np.sum(area * (dx**2 + dy**2)))


def strain_seminorm_sq(points: np.ndarray, triangles: np.ndarray, u: np.ndarray) -> float:
    u1x, u1y, area = gradients(points, triangles, u[:, 0])
    u2x, u2y, _ = gradients(points, triangles, u[:, 1])
    e12 = 0.5 * (u1y + u2x)
    return float(np.sum(area * (u1x**2 + u2y**2 + 2.0 * e12**2)))


def seminorm(points: np.ndarray, triangles: np.ndarray, values: np.ndarray) -> float:
    """||.||_V for a vector field (N, 2), ||.||_W = ||.||_Q for a scalar field (N,)."""
    if values.ndim == 2:
        return float(np.sqrt(strain_seminorm_sq(points, triangles, values)))
    return float(np.sqrt(gradient_seminorm_sq(points, triangles, values)))


def transfer_weights(coarse: Fields, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The coarse triangle of each point (point location, once for every field) and the
    point's barycentric coordinates in it: the P1 interpolation from coarse to `points`.

    Exact (to round-off) when every coarse triangle is a union of fine ones (nested meshes);
    on non-nested meshes it is the nodal interpolant of the coarse field, an approximation of
    the true difference of the two P1 functions.
    """
    tri = Triangulation(coarse.points[:, 0], coarse.points[:, 1], coarse.triangles)
    found = tri.get_trifinder()(points[:, 0], points[:, 1])
    if np.any(found < 0):
        raise FieldsError(f"{coarse.source}: some fine nodes lie outside the coarse mesh")
    corners = coarse.triangles[found]  # (N, 3)
    a, b, c = (coarse.points[corners[:, i], :2] for i in range(3))
    twice = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
    p = points[:, :2]
    wb = ((p[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (p[:, 1] - a[:, 1])) / twice
    wc = ((b[:, 0] - a[:, 0]) * (p[:, 1] - a[:, 1]) - (p[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])) / twice
    return corners, np.column_stack([1.0 - wb - wc, wb, wc])


def transfer(coarse: Fields, name: str, points: np.ndarray,
             weights: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """The coarse P1 field `name` at `points` (transfer_weights, or the given ones)."""
    corners, w = weights if weights is not None else transfer_weights(coarse, points)
    values = coarse.field(name)
    at_corners = values[corners]  # (N, 3) or (N, 3, 2)
    return np.einsum("nk,nk...->n...", w, at_corners)


def error_norms(coarse: Fields, fine: Fields, names: list[str]) -> dict[str, float]:
    """||fine - coarse|| per field, on the fine mesh."""
    weights = transfer_weights(coarse, fine.points)
    return {
        name: seminorm(fine.points, fine.triangles, fine.field(name) - transfer(coarse, name, fine.points, weights))
        for name in names
    }
