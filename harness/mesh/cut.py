"""A level's mesh cut once into one overlapping part per MPI rank, for a PETSc solve across
the ranks (freefem/ranks.idp reads them; docs/scale-out.md "The mesh cut once").

Made in one pass over the whole mesh before FreeFEM starts, so that no rank reads the whole
mesh, partitions it or cuts its overlap out of it (with macro_ddm.idp at 3D h = 1/32 on 2
ranks that took 7.3 s and 864 MiB on rank 0, against one rank's 2.6 s to read its mesh).

- The cells are split by recursive coordinate bisection of their centroids: each cut halves
  the cells (in proportion to the ranks on either side) across the longest side of their box.
- Each node belongs to the lowest-numbered rank one of whose cells holds it; a rank's
  partition of unity D is 1 at its nodes and 0 elsewhere. So D sums to 1 at every node, and
  each row of the Newton system is assembled by one rank alone.
- Part r is every cell holding a node of rank r (one element layer of overlap): the patch of
  each such node is whole on rank r, which is what the distributed matrix and the outputs need
  of a rank where D is non-zero (docs/scale-out.md). Its nodes are written in the order of
  their numbers in the whole mesh, its cells likewise; the whole mesh's labelled facets on its
  cells keep their labels, and the facets it gains where it was cut out are labelled
  ARTIFICIAL_LABEL (macro_ddm's label of an artificial boundary).

Part r is `part<r>.msh` (harness/mesh/msh.py's format, the loaders' own) and `part<r>.txt`,
the node and cell counts of the whole mesh, the neighbouring ranks, then as FreeFEM's arrays
each local node's and cell's number in the whole mesh, D, checksums of the node and cell order
(the weighted sums of the nodes' and the cells' centroids' coordinates, which FreeFEM computes
again from the mesh it read), and for each neighbour the local nodes both parts hold (in the
order of their numbers in the whole mesh, the same on both sides).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from harness.mesh.msh import AS_MESHIO, msh_text, read_msh
from harness.mesh.simplex import FACETS, SimplexMesh

ARTIFICIAL_LABEL = -111111


@dataclass(frozen=True)
class Part:
    """One rank's overlapping part of the whole mesh."""

    mesh: SimplexMesh
    nodes: np.ndarray        # each local node's number in the whole mesh (ascending)
    cells: np.ndarray        # each local cell's number in the whole mesh (ascending)
    share: np.ndarray        # the partition of unity D at each local node (0 or 1)
    neighbours: np.ndarray   # the ranks whose parts share a node with this one
    shared: list[np.ndarray]  # for each neighbour, the local nodes both parts hold


def bisection(centroids: np.ndarray, count: int) -> np.ndarray:
    """Each cell's part (0 .. count - 1) by recursive coordinate bisection of `centroids`."""
    part = np.zeros(len(centroids), dtype=np.int64)
    pending = [(np.arange(len(centroids)), 0, count)]
    while pending:
        cells, first, k = pending.pop()
        if k == 1:
            part[cells] = first
            continue
        points = centroids[cells]
        axis = int(np.argmax(points.max(axis=0) - points.min(axis=0)))
        order = cells[np.argsort(points[:, axis], kind="stable")]
        left = k // 2
        m = len(cells) * left // k
        pending += [(order[:m], first, left), (order[m:], first + left, k - left)]
    return part


def facet_keys(facets: np.ndarray, span: int) -> np.ndarray:
    """One int64 per facet from its sorted vertices (span: above every vertex number)."""
    s = np.sort(facets, axis=1).astype(np.int64)
    key = s[:, 0]
    for j in range(1, s.shape[1]):
        key = key * span + s[:, j]
    return key


def cell_faces(cells: np.ndarray) -> np.ndarray:
    """(M * (d + 1), d): each cell's facets, the one opposite vertex k at row (d + 1) * cell + k."""
    d = cells.shape[1] - 1
    return np.stack([cells[:, list(f)] for f in FACETS[d]], axis=1).reshape(-1, d)


def facet_cells(mesh: SimplexMesh, labelled: np.ndarray, span: int) -> np.ndarray:
    """The cell of each labelled facet (`labelled`: their facet_keys): among the cells with d of
    their vertices on the boundary, the one that has it as a facet."""
    d = mesh.dimension
    on_boundary = np.zeros(len(mesh.points), dtype=bool)
    on_boundary[mesh.facets] = True
    near = np.nonzero(on_boundary[mesh.cells].sum(axis=1) >= d)[0]
    keys = facet_keys(cell_faces(mesh.cells[near]), span)
    order = np.argsort(labelled)
    where = np.searchsorted(labelled, keys, sorter=order).clip(max=len(order) - 1)
    hit = labelled[order[where]] == keys
    found = np.full(len(mesh.facets), -1, dtype=np.int64)
    found[order[where[hit]]] = near[np.nonzero(hit)[0] // (d + 1)]
    if (found < 0).any():
        raise ValueError("a labelled facet is no cell's facet")
    return found


def cut(mesh: SimplexMesh, count: int) -> list[Part]:
    """`mesh` cut into `count` overlapping parts (the module's docstring says how)."""
    d = mesh.dimension
    cells = mesh.cells
    nodes_total = len(mesh.points)
    part = bisection(mesh.points[cells].mean(axis=1), count)
    owner = np.full(nodes_total, count, dtype=np.int64)
    np.minimum.at(owner, cells.ravel(), np.repeat(part, d + 1))
    span = nodes_total + 1
    labelled_keys = facet_keys(mesh.facets, span)
    facet_cell = facet_cells(mesh, labelled_keys, span)
    regions = mesh.cell_labels()
    cell_entities = mesh.cell_entities if mesh.cell_entities is not None else regions
    facet_entities = mesh.facet_entities if mesh.facet_entities is not None else mesh.labels
    holds = []
    for r in range(count):
        own = owner[cells] == r
        local_cells = np.nonzero(own.any(axis=1))[0]
        holds.append((local_cells, np.unique(cells[local_cells]), own[local_cells]))
    parts = []
    for r, (local_cells, local_nodes, own) in enumerate(holds):
        renumber = np.full(nodes_total, -1, dtype=np.int64)
        renumber[local_nodes] = np.arange(len(local_nodes))
        in_part = np.zeros(len(cells), dtype=bool)
        in_part[local_cells] = True
        kept = np.nonzero(in_part[facet_cell])[0]
        # Where the part was cut out: facets of its cells that no other of its cells has and the
        # whole mesh does not label. A facet with a node of rank r has both its cells in the part,
        # so only the facets of the cells with d nodes of other ranks are looked at.
        edge = local_cells[(~own).sum(axis=1) >= d]
        faces = cell_faces(cells[edge])
        faces = faces[(owner[faces] != r).all(axis=1)]
        keys = facet_keys(faces, span)
        _, first, counts = np.unique(keys, return_index=True, return_counts=True)
        once = first[counts == 1]
        artificial = faces[once[~np.isin(keys[once], labelled_keys)]]
        local = SimplexMesh(
            points=mesh.points[local_nodes],
            cells=renumber[cells[local_cells]],
            facets=renumber[np.vstack([mesh.facets[kept], artificial])],
            labels=np.concatenate([mesh.labels[kept], np.full(len(artificial), ARTIFICIAL_LABEL)]),
            regions=regions[local_cells],
            facet_entities=np.concatenate([facet_entities[kept], np.full(len(artificial), ARTIFICIAL_LABEL)]),
            cell_entities=cell_entities[local_cells])
        neighbours, shared = [], []
        for s, (_, other_nodes, _) in enumerate(holds):
            if s == r:
                continue
            common = np.intersect1d(local_nodes, other_nodes, assume_unique=True)
            if len(common):
                neighbours.append(s)
                shared.append(renumber[common])
        parts.append(Part(local, local_nodes, local_cells, (owner[local_nodes] == r).astype(float),
                          np.array(neighbours, dtype=np.int64), shared))
    return parts


def freefem_array(values: np.ndarray, integer: bool) -> str:
    """An array as FreeFEM's `>>` reads it: its size, then its entries."""
    body = " ".join(map(str, values.tolist())) if integer else " ".join(map(repr, values.tolist()))
    return f"{len(values)}\n{body}\n"


def part_text(p: Part, mesh: SimplexMesh) -> str:
    """part<r>.txt: what freefem/ranks.idp reads beside the part's mesh. A header line (the
    whole mesh's node and cell counts, the part's, the neighbour count), the neighbours and the
    sizes of their shared lists, then the arrays (FreeFEM reads an array into one of its size)."""
    xyz = np.zeros((len(mesh.points), 3))  # z = 0 in 2D, as FreeFEM's
    xyz[:, :mesh.dimension] = mesh.points
    weights = np.arange(1, len(p.nodes) + 1, dtype=float)
    node_check = (xyz[p.nodes] * weights[:, None]).sum(axis=0)
    cell_weights = np.arange(1, len(p.cells) + 1, dtype=float)
    cell_check = (xyz[mesh.cells[p.cells]].mean(axis=1) * cell_weights[:, None]).sum(axis=0)
    header = [len(mesh.points), len(mesh.cells), len(p.nodes), len(p.cells), len(p.neighbours)]
    lines = [" ".join(map(str, header)) + "\n",
             " ".join(map(str, p.neighbours.tolist())) + "\n",
             " ".join(str(len(s)) for s in p.shared) + "\n",
             freefem_array(p.nodes, True), freefem_array(p.cells, True), freefem_array(p.share, False),
             freefem_array(node_check, False), freefem_array(cell_check, False)]
    lines += [freefem_array(s, True) for s in p.shared]
    return "".join(lines)


def part_files(directory: Path, rank: int) -> tuple[Path, Path]:
    return directory / f"part{rank}.msh", directory / f"part{rank}.txt"


def cut_files(mesh_file: Path, count: int, directory: Path) -> Path:
    """The parts of `mesh_file` for `count` ranks, written into `directory` (new: a run's own,
    harness/run/run.py); returns it."""
    directory.mkdir(parents=True)
    mesh = read_msh(mesh_file)
    for r, p in enumerate(cut(mesh, count)):
        msh, txt = part_files(directory, r)
        msh.write_text(msh_text(p.mesh, AS_MESHIO))
        txt.write_text(part_text(p, mesh))
    return directory
