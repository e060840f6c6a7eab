"""A level's real lengths: its largest cell (h_max, in the model's units, whatever n says) and
how many cells lie through the thinnest section of each part of the body.

n is a label of the level (the rectangle's and box's h = 1/n; a gmsh scene's coarsest mesh
and its splits), not a length: a 20 mm part at n = 2 need not have cells of 0.5. h_max is
the longest cell edge (a simplex's diameter). The cells through a body's thinnest section
are its thickness along the shortest side of its bounding box, divided by the largest
extent along that axis of a cell whose centroid lies in the box: exact for the layered
meshes of a plate or strip, an estimate for a body whose thin part is not along an axis."""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

# Fewer cells than this through a section: P1 cannot bend it (one cell is a rigid layer in
# bending) and the level's errors say little about the finer ones.
MIN_CELLS_THROUGH = 2.0


@dataclass(frozen=True)
class Body:
    """A part of the body (a gmsh surface in 2D or volume in 3D, or the whole rectangle or
    box) by its name and bounding box."""

    name: str
    lo: tuple[float, ...]
    hi: tuple[float, ...]


def h_max(points: np.ndarray, cells: np.ndarray) -> float:
    """The longest edge of any cell."""
    # Edge by edge: a 3D level of millions of cells never holds all its corners at once.
    return float(max(np.linalg.norm(points[cells[:, i]] - points[cells[:, j]], axis=1).max()
                     for i, j in itertools.combinations(range(cells.shape[1]), 2)))


def cells_through(points: np.ndarray, cells: np.ndarray, body: Body) -> tuple[float, int, float]:
    """(cells through the body's thinnest section, that section's axis, its thickness)."""
    lo, hi = np.array(body.lo), np.array(body.hi)
    axis = int(np.argmin(hi - lo))
    thickness = float(hi[axis] - lo[axis])
    slack = 1e-9 * float((hi - lo).max())
    inside = np.ones(len(cells), dtype=bool)
    for k in range(len(lo)):  # the centroid inside the box, one coordinate at a time
        centroid = points[:, k][cells].mean(axis=1)
        inside &= (centroid >= lo[k] - slack) & (centroid <= hi[k] + slack)
    if not inside.any():
        return float("inf"), axis, thickness
    along = points[:, axis][cells[inside]]
    return thickness / float((along.max(axis=1) - along.min(axis=1)).max()), axis, thickness


def thin_warnings(bodies: tuple[Body, ...], n: int, points: np.ndarray, cells: np.ndarray) -> list[str]:
    """One line for a level with fewer than MIN_CELLS_THROUGH cells through a body's thinnest
    section, naming the body with the fewest."""
    counts = [(cells_through(points, cells, body), body) for body in bodies]
    if not counts:
        return []
    (count, axis, thickness), body = min(counts, key=lambda item: item[0][0])
    if count >= MIN_CELLS_THROUGH * (1 - 1e-6):  # a layered mesh's count, to round-off
        return []
    return [f"level n={n}: {count:.1f} cell(s) through the thinnest section of {body.name} "
            f"({thickness:.4g} along {'xyz'[axis]}; largest cell {h_max(points, cells):.3g}): its results "
            "are far from converged; use finer levels or set smaller mesh sizes in the .geo"]
