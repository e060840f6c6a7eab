"""Read a FreeFEM solution.vtu: P1 nodal fields on a triangle (2D) or tetrahedral (3D) mesh, by name."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from harness.core.errors import FieldsError


@dataclass(frozen=True)
class Fields:
    points: np.ndarray  # (N, 2)
    triangles: np.ndarray  # (M, 3)
    values: dict[str, np.ndarray]  # name -> (N,) scalar or (N, 2) vector
    source: Path
    tetrahedra: np.ndarray | None = None  # (M, 4) of a 3D solution; points are then (N, 3)

    @property
    def cells(self) -> np.ndarray:
        """The mesh's simplices: tetrahedra in 3D, triangles in 2D."""
        return self.triangles if self.tetrahedra is None else self.tetrahedra

    def field(self, name: str) -> np.ndarray:
        if name not in self.values:
            raise FieldsError(f"{self.source}: no field {name!r} (has {', '.join(self.values) or 'none'})")
        return self.values[name]


def read_fields(path: Path) -> Fields:
    if not path.is_file():
        raise FieldsError(f"solution file not found: {path}")
    import meshio  # here, not at start-up: its import (95 ms, its CLI pulls in rich) would delay FreeFEM's start (engine warms it while the last level runs)
    try:
        mesh = meshio.read(path)
    except Exception as exc:  # meshio raises several unrelated types for a broken file
        raise FieldsError(f"cannot read {path}: {exc}") from None
    tetrahedra = [block.data for block in mesh.cells if block.type == "tetra"]
    if tetrahedra:
        values = {name: np.asarray(data, dtype=float) for name, data in mesh.point_data.items()}
        values = {name: v[:, 0] if v.ndim == 2 and v.shape[1] == 1 else v for name, v in values.items()}
        return Fields(mesh.points.copy(), np.zeros((0, 3), dtype=int), values, path, np.concatenate(tetrahedra))
    triangles = [block.data for block in mesh.cells if block.type == "triangle"]
    if not triangles:
        raise FieldsError(f"{path}: no triangles")
    if np.any(mesh.points[:, 2] != 0):
        raise FieldsError(f"{path}: only planar (2D) solutions are supported")
    values = {name: planar(np.asarray(data, dtype=float)) for name, data in mesh.point_data.items()}
    return Fields(mesh.points[:, :2].copy(), np.concatenate(triangles), values, path)


def planar(data: np.ndarray) -> np.ndarray:
    """VTU stores 2D vectors with a z component (0 in plane problems): keep (x, y); scalars flat."""
    if data.ndim == 2 and data.shape[1] == 1:
        return data[:, 0]
    if data.ndim == 2 and data.shape[1] == 3:
        return data[:, :2]
    return data


def read_state(path: Path) -> list[np.ndarray]:
    """The full-precision state a run writes for warm starts (output.idp's state.txt): one
    array of dof values per field present (u interleaved u1, u2; then phi; then theta), in
    FreeFEM's stream format: each array's length, then its values."""
    try:
        tokens = np.array(path.read_text().split(), dtype=float)
    except (OSError, ValueError) as exc:
        raise FieldsError(f"cannot read state {path}: {exc}") from None
    arrays, at = [], 0
    while at < len(tokens):
        size = int(tokens[at])
        if size <= 0 or at + 1 + size > len(tokens):
            raise FieldsError(f"{path}: truncated state (array of {size} values at token {at})")
        arrays.append(tokens[at + 1: at + 1 + size])
        at += 1 + size
    return arrays
