"""run.linear_solver = "petsc" (freefem/petsc_solver.cpp, freefem/petsc_linear_solver.idp):
the inexact Newton with PETSc's Krylov solvers reaches the direct solver's solution, for
every effect set of the scenes in cases/, in 2D and 3D, with the Newton iteration count of
the direct solver within one; a bad options string is one line and exit code 2; a plugin
that cannot be built is one line and exit code 4."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from harness.run import petsc_plugin
from harness.scene import petsc_options
from harness.cli import main
from harness.core.contract import ExitCode
from harness.core.errors import EnvironmentFault, SceneError
from harness.core.faults import exit_code
from harness.measure.fields import read_state
from harness.core.layout import Layout
from harness.mesh.mesh import build_mesh, coarser_levels
from harness.run.run import run_level
from harness.scene.scene import load_scene
from harness.scene.unknowns import Unknowns

CASES = Path(__file__).parents[1] / "cases"
# Every scene's effect set (the 2D scenes) and both 3D scenes, at a coarse level.
SCENES = [("elastic", 8), ("electroelastic", 8), ("thermoelastic", 8), ("heated", 8), ("paper", 8),
          ("longcontact", 4), ("paper3d", 4), ("slab3d", 2)]
# Preconditioners of the solver table (docs/solvers.md), on one scene each way.
LU_MUMPS = petsc_options.MUMPS_LU
BLR = LU_MUMPS + " -mat_mumps_icntl_35 2 -mat_mumps_cntl_7 1e-8"


def solve(root: Path, case: str, n: int, solver: str, options: str = "", more: tuple[str, ...] = ()):
    overrides = [f'run.linear_solver="{solver}"', f'scene.name="{case}-{solver}-{abs(hash(options))}"', *more]
    if options:
        overrides.append(f'run.petsc_options="{options}"')
    scene = load_scene(CASES / f"{case}.toml", overrides)
    layout = Layout(results=root)
    mesh = build_mesh(scene.geometry, n, layout.meshes_dir(scene.name)).path
    # A coarsest-level start as the scene's studies make it (zero or pressed).
    guess = scene.sections.scene.coarsest_guess if scene.initial_guess == "coarser" else scene.initial_guess
    scene = load_scene(CASES / f"{case}.toml", [*overrides, f'scene.initial_guess="{guess}"'])
    return run_level(scene, mesh, n, layout)


def assert_same_fields(mine, theirs, rtol: float = 1e-8) -> None:
    for name, a, b in zip(("u", "phi", "theta"), read_state(mine.directory / "state.txt"),
                          read_state(theirs.directory / "state.txt")):
        scale = np.abs(b).max()
        assert np.abs(a - b).max() <= rtol * max(scale, 1e-300), (name, np.abs(a - b).max() / scale)


@pytest.mark.parametrize("case,n", SCENES)
def test_petsc_reaches_the_direct_solution_with_the_same_newton_count(tmp_path, case, n):
    direct = solve(tmp_path, case, n, "mumps")
    petsc = solve(tmp_path, case, n, "petsc")
    # Newton stops at a relative error of 1e-9 per field on either side; 1e-8 is the bound.
    assert_same_fields(petsc, direct)
    assert abs(petsc.record.newton_iterations - direct.record.newton_iterations) <= 1
    assert petsc.record.linear_solver.startswith("PETSc (")
    assert petsc.record.converged


@pytest.mark.parametrize("options", [LU_MUMPS, BLR])
def test_mumps_through_petsc_with_and_without_block_low_rank(tmp_path, options):
    direct = solve(tmp_path, "paper", 8, "mumps")
    assert_same_fields(solve(tmp_path, "paper", 8, "petsc", options), direct)


def test_the_field_split_names_the_scenes_fields(tmp_path):
    """The field split of the solver table, on a scene with one Newton field and on ones with
    two and three: every split it names is a field of the scene's Newton system, and back;
    it reaches the direct solution (its Krylov counts are in results/solvers/)."""
    for case in ("elastic", "heated", "paper"):
        scene = load_scene(CASES / f"{case}.toml")
        fields = tuple(f.name for f in Unknowns(scene.effects, scene.dimension).newton)
        options = petsc_options.field_split_options(fields)
        named = {w.split("_")[1] for w in options.split() if w.startswith("-fieldsplit_")}
        assert named == (set(fields) if len(fields) > 1 else set())
    direct = solve(tmp_path, "paper", 8, "mumps")
    split = solve(tmp_path, "paper", 8, "petsc", petsc_options.field_split_options(("u", "phi", "theta")))
    assert_same_fields(split, direct)


def test_the_default_options_are_the_measured_choice():
    assert load_scene(CASES / "paper.toml", ['run.linear_solver="petsc"']).petsc_options == petsc_options.MUMPS_LU
    given = load_scene(CASES / "paper.toml", ['run.petsc_options=" -pc_type hypre "'])
    assert given.petsc_options == "-pc_type hypre"


def run_cli(capsys, tmp_path, *argv: str) -> tuple[int, list[str]]:
    code = main([*argv, "--results", str(tmp_path / "results")])
    return code, capsys.readouterr().err.strip().splitlines()


@pytest.mark.parametrize("options,words", [
    ("-pc_type nonsense", ["PETSc rejected run.petsc_options", "nonsense"]),
    ("-ksp_type gmres -ksp_typo 3", ["PETSc rejected run.petsc_options", "-ksp_typo", "never used"]),
    ("-pc_type fieldsplit -fieldsplit_groups u,chi", ["PETSc rejected run.petsc_options", "chi"]),
    ("-pc_type ilu0lean -pc_ilu0lean_values half", ["PETSc rejected run.petsc_options", "single or double"]),
])
def test_a_bad_options_string_is_one_line_and_exit_code_input(capsys, tmp_path, options, words):
    code, err = run_cli(capsys, tmp_path, "solve", str(CASES / "paper.toml"), "--n", "2",
                        "--set", 'run.linear_solver="petsc"', "--set", f'run.petsc_options="{options}"')
    assert code == ExitCode.INPUT
    assert len(err) == 1 and err[0].startswith("error: ") and all(w in err[0] for w in words), err


def test_an_options_string_that_is_not_options_is_refused_before_any_run(tmp_path):
    with pytest.raises(SceneError, match="petsc_options"):
        load_scene(CASES / "paper.toml", ['run.petsc_options="pc_type gamg"'])


@pytest.mark.heavy  # 30 s: `make test-heavy`
def test_the_plugin_is_built_once_per_source(tmp_path):
    source = tmp_path / "petsc_solver.cpp"
    source.write_text(petsc_plugin.SOURCE.read_text())
    built = petsc_plugin.library(tmp_path / "build", source)
    assert built.is_file() and petsc_plugin.library(tmp_path / "build", source) == built
    source.write_text(source.read_text() + "\n// edited\n")
    assert petsc_plugin.library(tmp_path / "build", source) != built


def test_a_plugin_that_cannot_be_built_is_one_line_and_exit_code_environment(tmp_path, monkeypatch):
    source = tmp_path / "petsc_solver.cpp"
    source.write_text("#include <petscksp.h>\nint broken(\n")
    with pytest.raises(EnvironmentFault, match=r"^cannot build the PETSc plugin petsc_solver-\w+\.so: .*error") as bad:
        petsc_plugin.library(tmp_path / "build", source)
    assert exit_code(bad.value) == ExitCode.ENVIRONMENT
    assert not list((tmp_path / "build").iterdir())  # no half-written library left
    # PETSc's headers missing (a broken or absent libpetsc-real3.18-dev).
    source.write_text(petsc_plugin.SOURCE.read_text())
    monkeypatch.setenv("PETSC_DIR", str(tmp_path / "no-petsc"))
    with pytest.raises(EnvironmentFault, match="petscksp.h"):
        petsc_plugin.library(tmp_path / "build", source)
    monkeypatch.setenv("MPICXX", "no-such-mpicxx")
    with pytest.raises(EnvironmentFault, match="needs a MPI C\\+\\+ compiler") as missing:
        petsc_plugin.library(tmp_path / "build", source)
    assert exit_code(missing.value) == ExitCode.ENVIRONMENT


def test_the_contact_zone_subdomain_grown_over_the_whole_body_is_the_exact_solve(tmp_path):
    """-pc_type asm gets the contact zone (Gamma_3's dofs grown by -contact_zone_layers
    layers of the matrix graph) as its one subdomain: grown past the whole body at n = 4,
    its LU is the full factorisation, so the first Newton step takes one Krylov iteration."""
    direct = solve(tmp_path, "paper", 4, "mumps")
    zone = solve(tmp_path, "paper", 4, "petsc", "-ksp_type gmres -pc_type asm -sub_pc_type lu -contact_zone_layers 100")
    assert_same_fields(zone, direct)
    assert zone.record.linear_iterations[1] == 1


# ---- geometric multigrid (-pc_type mg over the scene's nested coarser meshes) ----

def test_the_coarser_levels_halve_n_down_to_the_coarsest():
    assert coarser_levels(32, 4) == [16, 8, 4, 2]
    assert coarser_levels(32, 2) == [16, 8]
    assert coarser_levels(64, 4, 8) == [32, 16, 8]
    assert coarser_levels(12, 4) == [6, 3]   # 3 is odd: no mesh below it nests
    assert coarser_levels(2, 4) == [] and coarser_levels(7, 4) == [] and coarser_levels(8, 4, 8) == []


def test_the_3d_default_is_multigrid_and_holds_no_factor_of_the_whole():
    scene = load_scene(CASES / "paper3d.toml")
    assert scene.linear_solver == "petsc" and scene.petsc_options == petsc_options.MULTIGRID
    assert petsc_options.multigrid(scene.petsc_options) and scene.multigrid_levels == 4
    # Its only factorisation is the coarsest level's: the memory guard counts no fill.
    assert not scene.factorises
    assert load_scene(CASES / "paper3d.toml", ['run.linear_solver="mumps"']).multigrid_levels == 0


@pytest.mark.parametrize("case,n,coarsest,levels", [("paper", 32, 8, 3), ("paper3d", 8, 4, 2), ("paper", 8, 8, 1)])
def test_multigrid_reaches_the_direct_solution(tmp_path, case, n, coarsest, levels):
    """The levels' operators are Galerkin products of the tangent over the nested meshes'
    interpolation; at n = 8 there is no coarser mesh (run.multigrid_coarsest) and the coarse
    solve is the whole one."""
    direct = solve(tmp_path, case, n, "mumps")
    mg = solve(tmp_path, case, n, "petsc", petsc_options.MULTIGRID, (f"run.multigrid_coarsest={coarsest}",))
    assert_same_fields(mg, direct)
    assert abs(mg.record.newton_iterations - direct.record.newton_iterations) <= 1
    assert f"multigrid: {levels} levels" in (mg.directory / "stdout.txt").read_text()


def finest_factor_mb(run) -> float:
    """The finest level's smoother factor [MB], from the plugin's -memory_breakdown lines."""
    lines = [line for line in (run.directory / "stdout.txt").read_text().splitlines()
             if line.startswith("memory: level") and "factor" in line]
    return float(lines[0].split("factor")[-1].split()[-2])


@pytest.mark.parametrize("case,n,coarsest", [("paper3d", 8, 4), ("paper", 32, 8)])
def test_the_lean_ilu_is_petscs_ilu_in_a_third_of_its_memory(tmp_path, case, n, coarsest):
    """The plugin's ILU(0) (-pc_type ilu0lean, freefem/lean_ilu.hpp) against PETSc's as the
    multigrid's smoother, from the zero start: with double-precision values it is the same
    factorisation, so the same Newton and Krylov counts and the fields to round-off; with the
    default single-precision values the same Newton count, each step's Krylov count within one
    (measured: equal, paper3d 4 3 7 and 4 3 8 at n = 16 and 32) and the fields within 1e-10;
    its factor, 4 bytes an entry in the operator's own pattern, at most 0.35 of PETSc's 12."""
    more = (f"run.multigrid_coarsest={coarsest}", 'scene.coarsest_guess="zero"')
    breakdown = " -memory_breakdown"
    petsc = solve(tmp_path, case, n, "petsc", petsc_options.MULTIGRID_PETSC_ILU + breakdown, more)
    double = solve(tmp_path, case, n, "petsc",
                   petsc_options.MULTIGRID + breakdown + " -mg_levels_pc_ilu0lean_values double", more)
    single = solve(tmp_path, case, n, "petsc", petsc_options.MULTIGRID + breakdown, more)
    assert petsc.record.converged and len(petsc.record.linear_iterations) >= 3
    assert double.record.linear_iterations == petsc.record.linear_iterations
    assert double.record.newton_iterations == petsc.record.newton_iterations
    # The same products summed in another order (PETSc's factorisation of rows with equal
    # patterns, inodes, groups them): measured 4e-14 at paper3d n = 16.
    assert_same_fields(double, petsc, 1e-12)
    assert single.record.newton_iterations == petsc.record.newton_iterations
    assert all(abs(a - b) <= 1 for a, b in zip(single.record.linear_iterations, petsc.record.linear_iterations))
    assert_same_fields(single, petsc, 1e-10)
    assert finest_factor_mb(single) <= 0.35 * finest_factor_mb(petsc)
    assert finest_factor_mb(double) <= 0.70 * finest_factor_mb(petsc)


def test_multigrid_krylov_iterations_do_not_grow_as_h_shrinks(tmp_path):
    """Mesh independence, the point of a multigrid: from the zero start (every contact node
    switching on in the first step) the Krylov iterations per Newton step at n = 64 (four
    levels) are those at n = 16 (two levels) within two; measured 5 4 5 8 and 5 3 3 7."""
    most = {}
    for n in (16, 64):
        run = solve(tmp_path, "paper", n, "petsc", petsc_options.MULTIGRID, ('scene.coarsest_guess="zero"',))
        its = run.record.linear_iterations
        assert run.record.converged and len(its) >= 3
        most[n] = max(its)
    assert most[16] <= 10 and most[64] <= most[16] + 2, most
