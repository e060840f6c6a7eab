"""The one MSH 2.2 writer (the only gmsh version FreeFEM's gmshload and gmshload3 read): a
SimplexMesh as ASCII, its facets then its cells, each with its physical tag (the role label,
or the cell's region label) and its elementary tag (gmsh's entity where the mesh has them,
else the physical tag again).

Three styles, because three writers made the files before this one and a run's cache key
holds its mesh's checksum: the rectangle's levels as gmsh.write makes them (coordinates %.16g,
a $PhysicalNames section; tests/test_mesh.py compares with gmsh itself), a graded rectangle
as its level's file with the moved x and y in Python's shortest round-trip form (%r), every
other level as meshio 5's gmsh22 writer made them (coordinates %.16e).
tests/test_mesh_bytes.py holds the files to their bytes.

Each section is one printf-style format over the whole array: meshio's writer formats line by
line and took 0.36 s of the 0.43 s of the rectangle's n = 64 mesh.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from harness.core.atomic import write_atomic
from harness.core.contract import BODY_LABEL, ROLE_LABELS
from harness.mesh.simplex import SimplexMesh

# gmsh's element type of a simplex of each dimension (1: line, 2: triangle, 4: tetrahedron).
ELEMENT_TYPE = {1: 1, 2: 2, 3: 4}


@dataclass(frozen=True)
class MshStyle:
    coordinates: str  # printf format of a node's x, y and z
    names: bool       # a $PhysicalNames section: each role's name, and "body"


AS_GMSH = MshStyle("%.16g %.16g %.16g", names=True)
AS_GRADED = MshStyle("%r %r %.16g", names=True)
AS_MESHIO = MshStyle("%.16e %.16e %.16e", names=False)


def physical_names(mesh: SimplexMesh) -> list[tuple[int, int, str]]:
    """(dimension, tag, name) of every physical tag the file uses, sorted as gmsh writes them."""
    d = mesh.dimension
    facets = [(d - 1, label, role) for role, label in ROLE_LABELS.items() if (mesh.labels == label).any()]
    cells = [(d, int(tag), "body" if tag == BODY_LABEL and mesh.regions is None else f"region_{tag}")
             for tag in np.unique(mesh.cell_labels())]
    return sorted(facets + cells)


def element_lines(first: int, kind: int, physical: np.ndarray, elementary: np.ndarray, nodes: np.ndarray) -> str:
    rows = np.column_stack([np.arange(first, first + len(nodes)), physical, elementary, nodes + 1])
    line = f"%d {kind} 2 %d %d" + " %d" * nodes.shape[1] + "\n"
    return (line * len(rows)) % tuple(rows.ravel().tolist())


def msh_text(mesh: SimplexMesh, style: MshStyle) -> str:
    d = mesh.dimension
    xyz = np.zeros((len(mesh.points), 3))
    xyz[:, :d] = mesh.points
    nodes = np.column_stack([np.arange(1, len(xyz) + 1), xyz])
    cell_tags = mesh.cell_labels()
    facet_entities = mesh.facet_entities if mesh.facet_entities is not None else mesh.labels
    cell_entities = mesh.cell_entities if mesh.cell_entities is not None else cell_tags
    parts = ["$MeshFormat\n2.2 0 8\n$EndMeshFormat\n"]
    if style.names:
        names = physical_names(mesh)
        parts += [f"$PhysicalNames\n{len(names)}\n", "".join(f'{dim} {tag} "{name}"\n' for dim, tag, name in names),
                  "$EndPhysicalNames\n"]
    node_line = f"%d {style.coordinates}\n"
    parts += [f"$Nodes\n{len(nodes)}\n", (node_line * len(nodes)) % tuple(nodes.ravel().tolist()), "$EndNodes\n",
              f"$Elements\n{len(mesh.facets) + len(mesh.cells)}\n",
              element_lines(1, ELEMENT_TYPE[d - 1], mesh.labels, facet_entities, mesh.facets),
              element_lines(len(mesh.facets) + 1, ELEMENT_TYPE[d], cell_tags, cell_entities, mesh.cells),
              "$EndElements\n"]
    return "".join(parts)


def write_msh(mesh: SimplexMesh, path: Path, style: MshStyle = AS_MESHIO) -> None:
    path.write_text(msh_text(mesh, style))


def small_cells_marker(path: Path) -> Path:
    """The file beside a mesh that says it holds triangles too small for FreeFEM's gmshload
    (freefem/dimension.idp), for meshes no level rule describes: the adaptive loop's
    (harness/study/adapt.py). Its presence is the whole message."""
    return path.with_name(path.name + ".small_cells")


def mark_small_cells(path: Path, small: bool) -> None:
    marker = small_cells_marker(path)
    if small:
        marker.touch()
    else:
        marker.unlink(missing_ok=True)


def coarser_marker(path: Path) -> Path:
    """The file beside a mesh that names, one per line and finest first, the coarser meshes
    it is nested in, for a geometric multigrid over meshes no level rule describes: the
    adaptive loop's steps, each a refinement of the ones before (harness/study/adapt.py)."""
    return path.with_name(path.name + ".coarser")


def mark_coarser(path: Path, coarser: list[Path]) -> None:
    """Name `coarser` beside `path`; an empty list still marks it as a mesh no level rule
    describes (the loop's first steps, nested in none): its multigrid has one level, and its
    ranks follow its own node count (harness/run/launcher.py level_capacity), not its label's.
    Written whole (a study's backup holds the earlier marker as a hard link)."""
    write_atomic(coarser_marker(path), "".join(f"{c.resolve()}\n" for c in coarser))


def marked_coarser(path: Path) -> list[Path] | None:
    """The coarser meshes `mark_coarser` named for `path` (maybe none), or None when it marked
    nothing: a level of the scene's own family."""
    marker = coarser_marker(path)
    return [Path(line) for line in marker.read_text().splitlines() if line] if marker.exists() else None


def node_count(path: Path) -> int:
    """The number of nodes of a mesh file this module wrote, read from its $Nodes header alone."""
    with path.open() as lines:
        for line in lines:
            if line.strip() == "$Nodes":
                return int(next(lines))
    raise ValueError(f"{path}: no $Nodes section")


def read_msh(path: Path) -> SimplexMesh:
    """A mesh file this module wrote, back as a SimplexMesh: its labelled facets then its cells,
    each with its physical and elementary tag (a one-region body's cells keep BODY_LABEL as
    their region). The sections are parsed by numpy in one call each: meshio's reader took
    3.0 s of the 3D h = 1/32 mesh (786,432 cells), this one 0.4 s."""
    text = path.read_text()
    def section(name: str) -> str:
        start = text.index(f"${name}\n") + len(name) + 2
        return text[start:text.index(f"$End{name}", start)]
    nodes = np.fromstring(section("Nodes"), sep=" ")
    count = int(nodes[0])
    xyz = nodes[1:].reshape(count, 4)[:, 1:]
    numbers = np.fromstring(section("Elements"), sep=" ", dtype=np.int64)
    total = int(numbers[0])
    # Facets first (5 + d numbers a line), then cells (6 + d): their counts follow from the total.
    dimension = 3 if numbers[2] == ELEMENT_TYPE[2] else 2
    width = 5 + dimension
    facet_count = total * (width + 1) - (len(numbers) - 1)
    facets = numbers[1:1 + facet_count * width].reshape(facet_count, width)
    cells = numbers[1 + facet_count * width:].reshape(total - facet_count, width + 1)
    if (facets[:, 1] != ELEMENT_TYPE[dimension - 1]).any() or (cells[:, 1] != ELEMENT_TYPE[dimension]).any():
        raise ValueError(f"{path}: not a mesh file of harness/mesh/msh.py (facets, then cells)")
    return SimplexMesh(points=xyz[:, :dimension], cells=cells[:, 5:] - 1, facets=facets[:, 5:] - 1,
                       labels=facets[:, 3], regions=cells[:, 3], facet_entities=facets[:, 4],
                       cell_entities=cells[:, 4])
