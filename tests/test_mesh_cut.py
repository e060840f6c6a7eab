"""The mesh cut once into the ranks' parts (harness/mesh/cut.py), checked against what the
distributed solve needs of a decomposition (docs/scale-out.md): the partition of unity sums to
1 at every node; where a rank's D is 1 its patch of cells is whole; every cell is on some rank;
the shared lists of two neighbours name the same nodes in the same order; a part's boundary is
the whole mesh's labelled facets on its cells (with their labels) and the artificial facets,
nothing else. The agreement of the solutions with one rank is tests/test_petsc_ranks.py's.
"""

from __future__ import annotations

import numpy as np
import pytest

from harness.core.layout import REPO
from harness.mesh.cut import ARTIFICIAL_LABEL, bisection, cut, cut_files, facet_keys, part_files
from harness.mesh.mesh import build_mesh
from harness.mesh.msh import AS_MESHIO, msh_text, read_msh
from harness.mesh.simplex import boundary_facets
from harness.scene.scene import load_scene

SCENES = ("paper.toml", "paper3d.toml", "bimorph.toml", "strip_actuator.toml")


@pytest.fixture(scope="module", params=SCENES)
def level(request, tmp_path_factory):
    geometry = load_scene(REPO / "cases" / request.param).geometry
    return build_mesh(geometry, 4, tmp_path_factory.mktemp(request.param), warn=False).path


def test_the_reader_reads_what_meshio_reads(level):
    import meshio

    mesh = read_msh(level)
    other = meshio.read(level)
    cell_type, facet_type = {2: ("triangle", "line"), 3: ("tetra", "triangle")}[mesh.dimension]
    assert np.array_equal(mesh.points, other.points[:, :mesh.dimension])
    assert np.array_equal(mesh.cells, other.cells_dict[cell_type])
    assert np.array_equal(mesh.facets, other.cells_dict[facet_type])
    physical = dict(zip((b.type for b in other.cells), other.cell_data["gmsh:physical"]))
    assert np.array_equal(mesh.labels, physical[facet_type]) and np.array_equal(mesh.regions, physical[cell_type])
    if "$PhysicalNames" not in level.read_text():  # written in meshio's style: the same bytes again
        assert msh_text(mesh, AS_MESHIO) == level.read_text()


def test_bisection_splits_the_cells_evenly():
    centroids = np.random.default_rng(1).random((1000, 3)) * [4, 1, 1]
    for count in (2, 3, 5, 8):
        sizes = np.bincount(bisection(centroids, count), minlength=count)
        assert sizes.sum() == 1000 and sizes.max() - sizes.min() <= count  # each cut rounds down once


@pytest.mark.parametrize("count", [2, 3, 4])
def test_the_parts_are_a_decomposition(level, count):
    mesh = read_msh(level)
    parts = cut(mesh, count)
    share = np.zeros(len(mesh.points))
    held = np.zeros(len(mesh.cells), dtype=int)
    for r, p in enumerate(parts):
        share[p.nodes] += p.share
        held[p.cells] += 1
        # Where D_r = 1 every cell holding the node is on rank r.
        mine = np.zeros(len(mesh.points), dtype=bool)
        mine[p.nodes[p.share == 1]] = True
        touching = np.nonzero(mine[mesh.cells].any(axis=1))[0]
        assert np.isin(touching, p.cells).all()
        # The local mesh is the global cells, renumbered.
        assert np.array_equal(p.nodes[p.mesh.cells], mesh.cells[p.cells])
        assert np.array_equal(p.mesh.points, mesh.points[p.nodes])
        # Its boundary: the labelled facets of its cells, with their labels, and the cut's.
        span = len(mesh.points) + 1
        local_boundary = np.sort(facet_keys(p.nodes[boundary_facets(p.mesh.cells)], span))
        written = facet_keys(p.nodes[p.mesh.facets], span)
        assert np.array_equal(np.sort(written), local_boundary)
        labelled = p.mesh.labels != ARTIFICIAL_LABEL
        global_keys = facet_keys(mesh.facets, span)
        order = np.argsort(global_keys)
        where = order[np.searchsorted(global_keys, written[labelled], sorter=order)]
        assert np.array_equal(mesh.labels[where], p.mesh.labels[labelled])
        assert not np.isin(written[~labelled], global_keys).any()
        # Neighbours share the same nodes, listed in the same order on both sides.
        for s, shared in zip(p.neighbours, p.shared):
            q = parts[s]
            back = q.shared[list(q.neighbours).index(r)]
            assert np.array_equal(p.nodes[shared], q.nodes[back])
            assert np.array_equal(p.nodes[shared], np.intersect1d(p.nodes, q.nodes))
    assert np.array_equal(share, np.ones(len(mesh.points)))
    assert (held >= 1).all()


def test_the_part_files_hold_the_cut(level, tmp_path):
    """One mesh file and one array file per rank; each mesh file reads back as its part."""
    target = cut_files(level, 3, tmp_path / "parts")
    parts = cut(read_msh(level), 3)
    for r, p in enumerate(parts):
        msh, txt = part_files(target, r)
        back = read_msh(msh)
        assert np.array_equal(back.points, p.mesh.points) and np.array_equal(back.cells, p.mesh.cells)
        assert np.array_equal(back.labels, p.mesh.labels)
        header = txt.read_text().splitlines()[0].split()
        assert [int(v) for v in header[2:]] == [len(p.nodes), len(p.cells), len(p.neighbours)]
    assert not part_files(target, 3)[0].exists()
