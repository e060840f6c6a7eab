"""Read the harness's MSH 2.2 meshes (ASCII) and make the GetFEM mesh with one region per
boundary label.

The harness writes triangles (2D) or tetrahedra (3D) for the body and, for the boundary,
segments (2D) or triangles (3D) whose first tag is the role label of harness/core/contract.py.
GetFEM regions take those labels as their numbers, so a region is a role."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

# gmsh element type -> number of nodes, for the types the harness writes.
NODES_OF_TYPE = {1: 2, 2: 3, 4: 4, 15: 1}
# The GetFEM region of the cells whose physical tag is t (a material region's label, 1, 2, ...,
# harness/gmsh_mesh.py) is CELL_REGION + t: clear of the boundary labels (1 ... 12).
CELL_REGION = 100


class MeshFileError(ValueError):
    """The mesh file cannot be read as the harness's MSH 2.2."""


@dataclass(frozen=True)
class MshMesh:
    points: np.ndarray  # (N, 3)
    cells: np.ndarray  # (M, dim + 1) node indices (0-based) of the body's simplices
    faces: np.ndarray  # (F, dim) node indices of labelled boundary facets
    labels: np.ndarray  # (F,) their role labels
    cell_labels: np.ndarray  # (M,) the cells' physical tags: their material region's label


def read_msh(path: Path, dimension: int) -> MshMesh:
    try:
        lines = path.read_text().split("\n")
    except (OSError, UnicodeDecodeError) as exc:
        raise MeshFileError(f"cannot read mesh {path}: {exc}") from exc
    try:
        return parse(lines, dimension)
    except (ValueError, IndexError, KeyError) as exc:
        raise MeshFileError(f"mesh {path} is not an MSH 2.2 file of a {dimension}D mesh ({exc})") from exc


def section(lines: list[str], name: str) -> list[str]:
    start = lines.index(f"${name}")
    end = lines.index(f"$End{name}", start)
    return lines[start + 1:end]


def parse(lines: list[str], dimension: int) -> MshMesh:
    if not section(lines, "MeshFormat")[0].startswith("2.2"):
        raise ValueError("not version 2.2")
    nodes = section(lines, "Nodes")
    count = int(nodes[0])
    table = np.array([row.split() for row in nodes[1:count + 1]], dtype=float)
    ids = table[:, 0].astype(int)
    index = np.full(ids.max() + 1, -1)
    index[ids] = np.arange(count)
    cells, cell_labels, faces, labels = [], [], [], []
    body_type, face_type = (2, 1) if dimension == 2 else (4, 2)
    elements = section(lines, "Elements")
    for row in elements[1:int(elements[0]) + 1]:
        words = [int(w) for w in row.split()]
        kind, ntags = words[1], words[2]
        vertices = index[words[3 + ntags:3 + ntags + NODES_OF_TYPE[kind]]]
        if kind == body_type:
            cells.append(vertices)
            cell_labels.append(words[3])
        elif kind == face_type:
            faces.append(vertices)
            labels.append(words[3])
    if not cells:
        raise ValueError(f"no {'triangles' if dimension == 2 else 'tetrahedra'}")
    return MshMesh(table[:, 1:4], np.array(cells), np.array(faces).reshape(-1, dimension), np.array(labels, dtype=int),
                   np.array(cell_labels, dtype=int))


def getfem_mesh(gf, msh: MshMesh, dimension: int):  # noqa: ANN001, ANN201 (GetFEM objects)
    """The GetFEM mesh of `msh`, with region <label> holding the (convex, face) pairs of
    every boundary facet of that label, and region CELL_REGION + t the cells tagged t."""
    points = msh.points[:, :dimension]
    mesh = gf.Mesh("empty", dimension)
    kind = "GT_PK(2,1)" if dimension == 2 else "GT_PK(3,1)"
    # add_convex takes coordinates: (dim, nodes per cell, cells).
    ids = np.asarray(mesh.add_convex(gf.GeoTrans(kind), np.transpose(points[msh.cells], (2, 1, 0))), dtype=int)
    for tag in np.unique(msh.cell_labels):
        mesh.set_region(CELL_REGION + int(tag), ids[msh.cell_labels == tag].reshape(1, -1))
    pid = np.asarray(mesh.pid_from_coords(points.T), dtype=int)
    if (pid < 0).any() or len(set(pid.tolist())) != len(points):
        raise MeshFileError("GetFEM merged or lost mesh nodes")
    label_of = {tuple(sorted(pid[f].tolist())): label for f, label in zip(msh.faces, msh.labels)}
    outer = mesh.outer_faces()
    by_label: dict[int, list[tuple[int, int]]] = {}
    for cv, face in zip(outer[0], outer[1]):
        key = tuple(sorted(np.asarray(mesh.pid_in_faces(np.array([[cv], [face]])), dtype=int).tolist()))
        if key in label_of:
            by_label.setdefault(label_of[key], []).append((int(cv), int(face)))
    if sum(len(v) for v in by_label.values()) != len(msh.faces):
        raise MeshFileError("a labelled boundary facet of the mesh file is not on the mesh's boundary")
    for label, pairs in by_label.items():
        mesh.set_region(label, np.array(pairs, dtype=int).T)
    return mesh
