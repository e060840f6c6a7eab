"""The bulk matrix K three ways (freefem/bulk.idp): FreeFEM composing it from its block varfs
(every direct solver); the PETSc plugin receiving one block at a time, each freed before
the next is assembled (run.linear_solver = "petsc" with the script's -debug.bulk_blocks 1);
and the plugin's element kernel, K in one pass from each block's matrix read off its form
(freefem/bulk_kernel.idp, the PETSc path's default for P1 fields of one material). All are
written by the scripts' -debug.bulk_matrix option; they must hold the same entries and the
same values, on a coarse 2D and 3D mesh with every effect on and on a scene whose theta is
solved apart (its blocks stay FreeFEM's)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from harness.core import freefem
from harness.core.layout import Layout
from harness.measure.fields import read_state
from harness.mesh.mesh import build_mesh
from harness.run import contact_forms, petsc_plugin
from harness.run.plan import invocation
from harness.run.run import make_meshes
from harness.scene.scene import load_scene
from harness.scene.unknowns import Unknowns

REPO = Path(__file__).parents[1]
CASES = REPO / "cases"


def bulk_matrix(tmp: Path, case: str, n: int, solver: str, by_blocks: bool = False) -> tuple[tuple[int, int], np.ndarray]:
    """K as FreeFEM's sparse-matrix text gives it: its size and (row, column, value) rows.
    `by_blocks`: the plugin's K from the block varfs, not from its element kernel."""
    scene = load_scene(CASES / f"{case}.toml", [f'run.linear_solver="{solver}"', 'scene.initial_guess="zero"'])
    layout = Layout(results=tmp / "results")
    mesh = build_mesh(scene.geometry, n, layout.meshes_dir(scene.name)).path
    work = tmp / (solver + ("-blocks" if by_blocks else ""))
    work.mkdir()
    run = invocation(scene, mesh, n, layout, "zero", None)
    make_meshes(scene, run)
    if scene.solver.builds_plugin:
        petsc_plugin.library()
    (work / "main.edp").write_text(run.script)
    dump = work / "K.txt"
    outcome = freefem.invoke(freefem.command(work / "main.edp", [*run.bound(work), "-debug.bulk_matrix", str(dump),
                                                                   "-debug.bulk_blocks", "1" if by_blocks else "0"]),
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
    size_petsc, petscs = bulk_matrix(tmp_path, case, n, "petsc", by_blocks=True)
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


def field_offsets(case: str, size: int) -> np.ndarray:
    """The first row of each field of the Newton vector (harness/scene/unknowns.py)."""
    scene = load_scene(CASES / f"{case}.toml")
    counts = [scene.dimension if f.name == "u" else 1 for f in Unknowns(tuple(scene.effects), scene.dimension).newton]
    nodes, rest = divmod(size, sum(counts))
    assert rest == 0
    return np.cumsum([0, *counts[:-1]]) * nodes


def block_of(entries: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Each entry's block, numbered from its row's and its column's field."""
    rows = np.searchsorted(offsets, entries[:, 0], side="right")
    cols = np.searchsorted(offsets, entries[:, 1], side="right")
    return rows * len(offsets) + cols


@pytest.mark.parametrize("case,n", [("paper", 4), ("paper3d", 2), ("heated", 4)])
def test_the_element_kernels_k_is_the_block_assembled_k_entry_by_entry(tmp_path, case, n):
    """The one-pass K (the plugin's element kernel, each block's matrix read off its form)
    against FreeFEM's K composed from its block varfs, every effect of the scene on."""
    size, freefems = bulk_matrix(tmp_path, case, n, "mumps")
    size_kernel, kernels = bulk_matrix(tmp_path, case, n, "petsc")
    assert size == size_kernel
    a, b = sorted_entries(freefems), sorted_entries(kernels)
    # The same entries, zeros of the element matrices too: the kernel's pattern is every
    # pair of vertices sharing an element, in every component pair of every block, as a varf's.
    assert a.shape == b.shape
    assert np.array_equal(a[:, :2], b[:, :2])
    # The same values to round-off, block by block (the fields' scales differ): the kernel sums
    # the same products in another order, |T| Phi_i^T D Phi_j against the varf's terms one by
    # one, so an entry may differ by a few units in the last place of its block's largest
    # (measured: 5e-16 and 8e-16 relative in 3D and 2D; an entry that cancels to 0 in one is
    # 1e-11 of 3e4 in the other); 1e-14 leaves room for that and fails any wrong coefficient.
    offsets = field_offsets(case, size[0])
    assert len(offsets) >= 2
    block = block_of(a, offsets)
    for k in np.unique(block):
        here = block == k
        scale = np.abs(a[here, 2]).max()
        if scale == 0:
            assert np.abs(b[here, 2]).max() == 0
            continue
        assert np.abs(a[here, 2] - b[here, 2]).max() <= 1e-14 * scale, f"block {k}"
    # Not a K of zeros: the largest entries are the elastic stiffness's.
    assert np.abs(b[:, 2]).max() > 0


def petsc_run(tmp: Path, name: str, case: str, n: int, options: list[str], overrides: tuple[str, ...] = (),
              scripts: Path | None = None) -> tuple[dict, list, Path]:
    """One run on the PETSc path from zero with the scripts' extra options (and another copy of
    freefem/, `scripts`): run.json, the fields and the work folder."""
    scene = load_scene(CASES / f"{case}.toml", ['run.linear_solver="petsc"', 'scene.initial_guess="zero"', *overrides])
    layout = Layout(results=tmp / "results", **({"freefem": scripts} if scripts else {}))
    mesh = build_mesh(scene.geometry, n, layout.meshes_dir(scene.name)).path
    work = tmp / name
    work.mkdir()
    run = invocation(scene, mesh, n, layout, "zero", None)
    make_meshes(scene, run)
    petsc_plugin.library()
    (work / "main.edp").write_text(run.script)
    outcome = freefem.invoke(freefem.command(work / "main.edp", [*run.bound(work), *options]), work, 300)
    assert outcome.returncode == 0, (work / "stdout.txt").read_text()[-2000:]
    return json.loads((work / "run.json").read_text()), read_state(work / "state.txt"), work


def assert_same_solve(run0: dict, fields0: list, run1: dict, fields1: list, rtol: float) -> None:
    """The same Newton and Krylov counts, and every field within rtol of its largest value."""
    assert run1["newton_iterations"] == run0["newton_iterations"]
    assert run1["linear_iterations"] == run0["linear_iterations"]
    for name, a, b in zip(("u", "phi", "theta"), fields1, fields0):
        scale = np.abs(b).max()
        assert scale > 0, name
        assert np.abs(a - b).max() <= rtol * scale, name


def solve_with_room(tmp: Path, case: str, n: int, room: bool, overrides: tuple[str, ...] = ()) -> tuple[str, dict, list]:
    """One run on the kernel's path, with or without room made in K for the contact tangent
    (the script's -debug.bulk_room): its stdout, run.json and fields."""
    record, fields, work = petsc_run(tmp, f"room{int(room)}", case, n, ["-debug.bulk_room", str(int(room))], overrides)
    return (work / "stdout.txt").read_text(), record, fields


@pytest.mark.parametrize("case,n,overrides", [
    # 3D with two multigrid levels: the finest level's ILU(0) works on J's pattern, so a pattern
    # that differs by one entry moves the Krylov iterates.
    ("paper3d", 8, ("run.multigrid_coarsest=4",)),
    # 2D, every effect: the (theta, u) and (phi, u) contact blocks.
    ("paper", 8, ()),
])
def test_room_for_the_contact_tangent_gives_the_widened_operators_solution(tmp_path, case, n, overrides):
    """K built with room for T's entries that K lacks (the (theta, u) block on Gamma_3) is the
    operator the first K + T used to widen K into, without the copy: the same Newton and
    Krylov counts and the same fields."""
    before, run0, fields0 = solve_with_room(tmp_path, case, n, False, overrides)
    after, run1, fields1 = solve_with_room(tmp_path, case, n, True, overrides)
    # The run without room widened K at the first K + T; the run with room never did.
    assert "K's pattern widened" in before and "room made in K" not in before
    assert "room made in K" in after and "K's pattern widened" not in after
    # The same matrix entries in the same CSR order, so the same arithmetic: the fields agree
    # bit for bit in practice; 1e-13 of each field's largest value allows a reordered sum.
    assert_same_solve(run0, fields0, run1, fields1, 1e-13)


COULOMB_3D = ('contact.friction_law="coulomb"', "contact.mu=0.3")
# Every contact effect on (but the Coulomb strip's: contact and friction alone); Tresca and
# Coulomb; 2D and 3D; and, over a solve from zero, the states each passes through (run.json's
# counts of closed and slipping Gamma_3 nodes after each step): open and closed, stick and slip.
CONTACT_CASES = [("longcontact", 8, (), {"open", "stick", "slip"}), ("coulomb", 8, (), {"stick", "slip"}),
                 ("paper3d", 4, (), {"open", "stick"}), ("paper3d", 4, COULOMB_3D, {"slip"})]


@pytest.mark.parametrize("case,n,overrides,states", CONTACT_CASES)
def test_the_contact_kernel_is_the_varfs_entry_by_entry(tmp_path, case, n, overrides, states):
    """The plugin's contact residual and tangent (freefem/contact_kernel.idp) against the varfs
    of the same integrands (forms.idp), at every Newton step of a solve from zero, and its
    integrals of the physical checks against FreeFEM's: the same values to round-off, entry by
    entry, with stick and slip, open and closed points."""
    check = tmp_path / "check.csv"
    record, _, _ = petsc_run(tmp_path, "check", case, n, ["-debug.contact_check", str(check)], overrides)
    rows = [line.split(",") for line in check.read_text().splitlines()]
    kinds = {row[0] for row in rows}
    # and, after the solve, the physical checks' integrals over Gamma_3 (checks.idp), one row each
    assert kinds == {"residual", "tangent"} | {f"integral {j}" for j in range(len(contact_forms.CHECKS))}, kinds
    assert max(float(row[3]) for row in rows if row[0] == "residual") > 0
    for kind, _, difference, scale, kernel_entries, varf_entries in rows:
        # The varfs and the kernel sum the same products in another order (FreeFEM evaluates each
        # component pair's coefficient apart; the kernel reads a point's block off the form with
        # unit vectors), so an entry may differ by units in the last place of the largest.
        # (At the zero start s = 0 everywhere: the residual's contact part is 0 in both.)
        assert float(difference) <= 1e-13 * float(scale), (kind, difference, scale)
        # The kernel stores no entry outside the varfs' pattern (they keep zeros it skips).
        assert int(kernel_entries) <= int(varf_entries), (kind, kernel_entries, varf_entries)
    # The states the comparison went through.
    active, slip = record["active_nodes"][1:], record["slip_nodes"][1:]
    met = {"open": any(a < max(active) for a in active), "stick": any(s < a for s, a in zip(slip, active)),
           "slip": max(slip) > 0}
    assert all(met[state] for state in states), (met, active, slip)


# (Not the long strip from zero at n = 8: its Newton path there turns on round-off, 40 iterations
# without converging on the varfs, 6 on the kernel; docs/hard-cases.md's cold starts.)
@pytest.mark.parametrize("case,n,overrides", [("paper", 8, ())] + [case[:3] for case in CONTACT_CASES[1:]])
def test_a_solve_with_the_contact_kernel_is_the_solve_with_the_varfs(tmp_path, case, n, overrides):
    """The same Newton and Krylov counts and the same fields with the kernel as with the varfs
    (the scripts' -debug.contact_varfs 1)."""
    run0, fields0, _ = petsc_run(tmp_path, "varfs", case, n, ["-debug.contact_varfs", "1"], overrides)
    run1, fields1, _ = petsc_run(tmp_path, "kernel", case, n, [], overrides)
    # Round-off in the residual and the tangent, amplified by the problem's conditioning
    # (measured: 9e-15 relative on paper3d's chain to n = 16).
    assert_same_solve(run0, fields0, run1, fields1, 1e-10)


def test_a_law_changed_since_the_header_was_written_goes_to_the_varfs(tmp_path):
    """The kernel serves a script only where its compiled integrands are that script's own
    expansion of contact_forms.idp: a copy of the scripts with the penalty halved in the
    residual runs on the varfs, says so, and solves the changed problem."""
    scripts = tmp_path / "freefem"
    shutil.copytree(REPO / "freefem", scripts)
    forms = scripts / "contact_forms.idp"
    old = "(normalPressure(gapS(u)) * vnu(v)"
    assert old in forms.read_text()
    forms.write_text(forms.read_text().replace(old, "(0.5 * normalPressure(gapS(u)) * vnu(v)", 1))
    changed, _, work = petsc_run(tmp_path, "changed", "paper3d", 2, [], scripts=scripts)
    plain, _, plain_work = petsc_run(tmp_path, "plain", "paper3d", 2, [])
    assert "note: the contact kernel" in (work / "stdout.txt").read_text()
    assert "note: the contact kernel" not in (plain_work / "stdout.txt").read_text()
    # Half the penalty, about twice the penetration under the same load.
    assert changed["contact_force"] == pytest.approx(plain["contact_force"], rel=1e-3)
    assert changed["max_abs_u"] > plain["max_abs_u"]


def test_the_committed_contact_forms_header_is_current():
    """freefem/contact_forms.hpp is `python -m harness.run.contact_forms`'s output from the
    contact macros as they are: a law changed in its .idp file changes the kernel's code too,
    or this fails until the header is written again."""
    assert contact_forms.HEADER.read_text() == contact_forms.header()
