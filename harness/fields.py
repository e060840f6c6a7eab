"""Read a FreeFEM solution.vtu: P1 nodal fields on a triangle mesh, by name."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import meshio
import numpy as np

from harness.errors import FieldsError


@dataclass(frozen=True)
class Fields:
    points: np.ndarray  # (N, 2)
    triangles: np.ndarray  # (M, 3)
    values: dict[str, np.ndarray]  # name -> (N,) scalar or (N, 2) vector
    source: Path

    def field(self, name: str) -> np.ndarray:
        if name not in self.values:
            raise FieldsError(f"{self.source}: no field {name!r} (has {', '.join(self.values) or 'none'})")
        return self.values[name]


def read_fields(path: Path) -> Fields:
    if not path.is_file():
        raise FieldsError(f"solution file not found: {path}")
    try:
        mesh = meshio.read(path)
    except Exception as exc:  # meshio raises several unrelated types for a broken file
        raise FieldsError(f"cannot read {path}: {exc}") from None
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
