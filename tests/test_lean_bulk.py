"""The bulk matrix K two ways (freefem/bulk.idp): FreeFEM composing it from its block varfs
(every direct solver), and the PETSc plugin receiving one block at a time, each freed
before the next is assembled (run.linear_solver = "petsc", freefem/petsc_solver.cpp). Both
are written by the scripts' -debug.bulk_matrix option; they must hold the same entries, the
same values, on a coarse 2D and 3D mesh with every effect on and on a scene whose theta is
solved apart (its blocks stay FreeFEM's)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from harness.core import freefem
from harness.core.layout import Layout
from harness.mesh.mesh import build_mesh
from harness.run import petsc_plugin
from harness.run.plan import invocation
from harness.run.run import make_meshes
from harness.scene.scene import load_scene

CASES = Path(__file__).parents[1] / "cases"


def bulk_matrix(tmp: Path, case: str, n: int, solver: str) -> tuple[tuple[int, int], np.ndarray]:
    """K as FreeFEM's sparse-matrix text gives it: its size and (row, column, value) rows."""
    scene = load_scene(CASES / f"{case}.toml", [f'run.linear_solver="{solver}"', 'scene.initial_guess="zero"'])
    layout = Layout(results=tmp / "results")
    mesh = build_mesh(scene.geometry, n, layout.meshes_dir(scene.name)).path
    work = tmp / solver
    work.mkdir()
    run = invocation(scene, mesh, n, layout, "zero", None)
    make_meshes(scene, run)
    if scene.solver.builds_plugin:
        petsc_plugin.library()
    (work / "main.edp").write_text(run.script)
    dump = work / "K.txt"
    outcome = freefem.invoke(freefem.command(work / "main.edp", [*run.bound(work), "-debug.bulk_matrix", str(dump)]),
                             work, 300)
    assert outcome.returncode == 0, (work / "stdout.txt").read_text()[-2000:]
    rows = [line.split() for line in dump.read_text().splitlines() if not line.startswith("#")]
    n_rows, n_cols, nnz, fortran = int(rows[0][0]), int(rows[0][1]), int(rows[0][2]), int(rows[0][4])
    assert nnz == len(rows) - 1
    entries = np.array([[float(w) for w in row] for row in rows[1:]])
    entries[:, :2] -= fortran   # 1-based indices when FreeFEM says so
    return (n_rows, n_cols), entries


def sorted_entries(entries: np.ndarray) -> np.ndarray:
    return entries[np.lexsort((entries[:, 1], entries[:, 0]))]


@pytest.mark.parametrize("case,n", [("paper", 4), ("paper3d", 2), ("heated", 4)])
def test_the_plugins_k_is_the_block_assembled_k_entry_by_entry(tmp_path, case, n):
    size, freefems = bulk_matrix(tmp_path, case, n, "mumps")
    size_petsc, petscs = bulk_matrix(tmp_path, case, n, "petsc")
    assert size == size_petsc
    a, b = sorted_entries(freefems), sorted_entries(petscs)
    # The same entries: the plugin keeps every entry FreeFEM assembled, zeros too.
    assert a.shape == b.shape
    assert np.array_equal(a[:, :2], b[:, :2])
    # The same values: both copy the blocks' values, so they agree bit for bit; the bound is
    # round-off of the largest entry should a copy ever go through arithmetic.
    assert np.abs(a[:, 2] - b[:, 2]).max() <= 1e-15 * np.abs(a[:, 2]).max()
    # Every block is in: rows of each field and couplings between them, not one block alone.
    assert len(np.unique(a[:, 0])) == size[0]
