"""PETSc across MPI ranks (run.ranks > 1 with run.linear_solver = "petsc": freefem/petsc_ranks.idp and the
plugin's "Distributed solves", freefem/petsc_solver.cpp): the distributed matrix summed from the ranks'
subdomains and PETSc's Krylov method and preconditioner across them give the one-rank PETSc solution to
round-off, on 2 and 4 ranks, in 2D and 3D, for the monolithic effect sets and both branches; a bad option
string and a PETSc error inside the Krylov solve are one line, their exit code and no process left."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from harness.cli import main
from harness.core.contract import ExitCode
from harness.core.layout import Layout
from harness.measure.fields import read_state
from harness.mesh.mesh import build_mesh
from harness.run.run import run_level
from harness.scene import petsc_options
from harness.scene.scene import load_scene
from test_parallel import mpi_missing
from test_pipeline import freefem_processes_under

CASES = Path(__file__).parents[1] / "cases"
# The bound. Measured: 3e-13 at worst (2D n = 32 on 4 ranks); the distributed matrix adds
# the overlap's rows weighted by the partition of unity, which changes K + T by round-off only,
# and Newton stops at 1e-9 per field from both sides of a quadratic phase.
AGREE = 1e-10

pytestmark = pytest.mark.skipif(bool(mpi_missing()), reason=mpi_missing() or "-")


def solve(root: Path, case: str, n: int, ranks: int, guess: str, *more: str):
    """Level n of cases/<case>.toml alone, from `guess`, with PETSc on `ranks` ranks."""
    overrides = ['run.linear_solver="petsc"', f"run.ranks={ranks}", f'scene.initial_guess="{guess}"',
                 f'scene.name="{case}-{guess}-{ranks}"', *more]
    scene = load_scene(CASES / f"{case}.toml", overrides)
    layout = Layout(results=root)
    mesh = build_mesh(scene.geometry, n, layout.meshes_dir(scene.name)).path
    return run_level(scene, mesh, n, layout)


def assert_one_rank_solution(root: Path, case: str, n: int, ranks: tuple[int, ...], guess: str) -> None:
    one = solve(root, case, n, 1, guess)
    for count in ranks:
        many = solve(root, case, n, count, guess)
        assert many.record.ranks == count and many.record.linear_solver.endswith(f"on {count} ranks")
        # One rank's 2D default factorises (MUMPS's LU), the ranks' iterate to run.krylov_rtol: Newton's
        # path may differ by a step, as with PETSc against the direct solver (test_petsc.py).
        assert abs(many.record.newton_iterations - one.record.newton_iterations) <= 1
        assert many.record.active_nodes[-1] == one.record.active_nodes[-1]
        for name, a, b in zip(("u", "phi", "theta"), read_state(one.directory / "state.txt"),
                              read_state(many.directory / "state.txt")):
            scale = max(np.abs(a).max(), 1e-300)
            assert np.abs(a - b).max() <= AGREE * scale, (case, count, name, np.abs(a - b).max() / scale)


# The 2D scenes whose Newton system is monolithic (a staggered theta is refused on ranks,
# test_parallel.py), each from the start its studies use, and the paper scene from both.
@pytest.mark.parametrize("case, guess", [("elastic", "zero"), ("electroelastic", "zero"),
                                         ("thermoelastic", "pressed"), ("paper", "zero"), ("paper", "pressed")])
def test_petsc_on_two_and_four_ranks_gives_the_one_rank_solution_in_2d(tmp_path, case, guess):
    assert_one_rank_solution(tmp_path, case, 8, (2, 4), guess)


def test_petsc_on_ranks_with_multigrid_levels_gives_the_one_rank_solution(tmp_path):
    # n = 16 has the coarsest n = 8 below it: the distributed interpolation onto each rank's
    # subdomain and Galerkin's coarse operator across the ranks (n = 32 adds one between whole
    # coarse meshes: 3.0e-13 from one rank on 4 ranks, 148 s here from zero, docs/scale-out.md).
    assert_one_rank_solution(tmp_path, "paper", 16, (4,), "zero")


# 1 and 2 ranks from zero: 25 s here; 4 ranks and the pressed start each add about as much (heavy).
@pytest.mark.parametrize("guess, ranks", [("zero", (2,)), pytest.param("zero", (4,), marks=pytest.mark.heavy),
                                          pytest.param("pressed", (2,), marks=pytest.mark.heavy)])
def test_petsc_on_ranks_gives_the_one_rank_solution_in_3d(tmp_path, guess, ranks):
    assert_one_rank_solution(tmp_path, "paper3d", 4, ranks, guess)


def test_the_default_on_ranks_is_the_distributed_multigrid_without_the_script_coarse_space():
    scene = load_scene(CASES / "paper.toml", ['run.linear_solver="petsc"', "run.ranks=2"])
    assert scene.solver_options == petsc_options.MULTIGRID_ON_RANKS and scene.multigrid_levels > 0
    assert scene.coarse_levels == 0  # the preconditioner is run.petsc_options' business
    assert "-mg_levels_pc_type ilu" not in petsc_options.MULTIGRID_ON_RANKS  # PETSc's ILU is one rank's
    one = load_scene(CASES / "paper.toml", ['run.linear_solver="petsc"'])
    assert one.solver_options == petsc_options.MUMPS_LU


@pytest.mark.parametrize("options, code, words", [
    ("-pc_type nonsense", ExitCode.INPUT, ["PETSc rejected run.petsc_options", "nonsense"]),
    ("-ksp_typo 3", ExitCode.INPUT, ["PETSc rejected run.petsc_options", "-ksp_typo", "never used"]),
    # An error raised inside KSPSolve on every rank.
    ("-ksp_max_it 1 -ksp_error_if_not_converged", ExitCode.RUN, ["the Krylov solver did not converge",
                                                                 "KSPSolve has not converged"]),
])
def test_a_petsc_fault_on_ranks_is_one_line_its_exit_code_and_no_process_left(capsys, tmp_path, options, code, words):
    results = tmp_path / "results"
    status = main(["solve", str(CASES / "paper.toml"), "--n", "8", "--results", str(results),
                   "--set", 'run.linear_solver="petsc"', "--set", "run.ranks=2",
                   "--set", f'run.petsc_options="{options}"', "--set", "run.timeout_s=120"])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == code
    assert len(err) == 1 and err[0].startswith("error: ") and all(w in err[0] for w in words), err
    assert not freefem_processes_under(results), "a rank outlived the failed run"
    assert (results / "paper").is_dir() and not list((results / "paper").glob(".tmp-*"))
