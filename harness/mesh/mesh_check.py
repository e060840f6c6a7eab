"""Checks on a written mesh that FreeFEM's gmshload and the nesting argument rely on."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import meshio

from harness.core.contract import ROLE_LABELS
from harness.core.errors import MeshError
from harness.mesh.simplex import label_measures, signed_measures
from harness.scene.segments import Geometry


@dataclass(frozen=True)
class MeshSummary:
    path: Path
    n: int
    nodes: int
    triangles: int
    role_lengths: dict[str, float]
    # min angle (2D) or dihedral (3D) in degrees and max aspect (gmsh scenes: harness/mesh/gmsh_mesh.py)
    quality: dict[str, float] = field(default_factory=dict)


def check_mesh(path: Path, geometry: Geometry, n: int) -> MeshSummary:
    """check_arrays on a written file."""
    import meshio  # here, not at start-up: its import (95 ms, its CLI pulls in rich) would delay FreeFEM's start (freefem.launch warms it)
    mesh = meshio.read(path, file_format="gmsh")
    lines = cells_of(mesh, "line")
    tags = np.concatenate(
        [tag for block, tag in zip(mesh.cells, mesh.cell_data["gmsh:physical"]) if block.type == "line"]
    )
    return replace(check_arrays(mesh.points[:, :2], cells_of(mesh, "triangle"), lines, tags, geometry, n), path=path)


def check_arrays(points: np.ndarray, triangles: np.ndarray, lines: np.ndarray, tags: np.ndarray,
                 geometry: Geometry, n: int) -> MeshSummary:
    """A rectangle's level: distinct nodes, positive triangles, the asked diagonals, and each
    role's boundary length that of its segments (the summary's path is left empty)."""
    where = f"mesh n={n}"
    check_unique_nodes(points, where, h=1.0 / n)
    check_orientation(points, triangles, where)
    if geometry.diagonals != "unstructured":
        check_diagonals(points, triangles, geometry.diagonals, where)
    lengths = check_roles(lines, tags, points, geometry, where)
    return MeshSummary(Path(), n, len(points), len(triangles), lengths)


def cells_of(mesh: meshio.Mesh, kind: str) -> np.ndarray:
    blocks = [block.data for block in mesh.cells if block.type == kind]
    if not blocks:
        raise MeshError(f"{mesh} has no {kind} elements")
    return np.concatenate(blocks)


def check_unique_nodes(points: np.ndarray, where: str, h: float) -> None:
    # Distinct nodes are at least h apart; anything closer than h/1000 is the same node twice.
    keys = np.round(points / (h * 1e-3)).astype(np.int64)
    # Rows sorted, then neighbours compared: np.unique(axis=0) would do the same but imports
    # numpy.ma on first use (20 ms of every process's start-up).
    rows = keys[np.lexsort(keys.T)]
    if np.any(np.all(rows[1:] == rows[:-1], axis=1)):
        raise MeshError(f"{where}: duplicate nodes")


def check_orientation(points: np.ndarray, triangles: np.ndarray, where: str) -> None:
    bad = int(np.count_nonzero(signed_measures(points, triangles) <= 0))
    if bad:
        raise MeshError(f"{where}: {bad} triangles are not positively oriented")


def check_diagonals(points: np.ndarray, triangles: np.ndarray, diagonals: str, where: str) -> None:
    """In a structured cell split, each triangle has exactly one edge that is neither
    horizontal nor vertical; its slope sign says which way the cell was cut."""
    want = 1.0 if diagonals == "SW-NE" else -1.0
    edges = points[np.roll(triangles, -1, axis=1)] - points[triangles]  # (M, 3, 2)
    scale = np.abs(edges).max()
    slanted = (np.abs(edges) > 1e-9 * scale).all(axis=2)  # round-off of coordinates only
    if not (slanted.sum(axis=1) == 1).all():
        raise MeshError(f"{where}: not a structured split (a triangle without exactly one diagonal)")
    diag = edges[slanted]
    if not (np.sign(diag[:, 0] * diag[:, 1]) == want).all():
        raise MeshError(f"{where}: some diagonals do not run {diagonals}")


def check_roles(lines: np.ndarray, tags: np.ndarray, points: np.ndarray, geometry: Geometry, where: str) -> dict[str, float]:
    measured = label_measures(points, lines, tags)
    expected = geometry.role_lengths()
    found = {}
    for role, label in ROLE_LABELS.items():
        total = measured.get(label, 0.0)
        want = expected.get(role, 0.0)
        # Lengths are sums of at most a few hundred edges of exact length h: 1e-9 is round-off.
        if abs(total - want) > 1e-9 * max(1.0, want):
            raise MeshError(f"{where}: boundary role {role} (label {label}) has length {total}, expected {want}")
        if total:
            found[role] = total
    unknown = set(np.unique(tags)) - set(ROLE_LABELS.values())
    if unknown:
        raise MeshError(f"{where}: unexpected boundary labels {sorted(unknown)}")
    return found
