"""PETSc across MPI ranks (run.ranks > 1 with run.linear_solver = "petsc": freefem/petsc_ranks.idp and the
plugin's "Distributed solves", freefem/petsc_solver.cpp): the distributed matrix summed from the ranks'
subdomains and PETSc's Krylov method and preconditioner across them give the one-rank PETSc solution to
round-off, on 2 and 4 ranks, in 2D and 3D, for every effect set (a staggered theta included) and both branches, and the ranks
write what a one-rank run writes (run.json's checks, estimates and extremes, solution.vtu, state.txt) to
round-off with no sequential pass after them; a bad option string and a PETSc error inside the Krylov solve
are one line, their exit code and no process left."""

from __future__ import annotations

import json
from pathlib import Path

import meshio
import numpy as np
import pandas as pd
import pytest

from harness.cli import main
from harness.core.contract import ExitCode
from harness.core.layout import Layout
from harness.measure.fields import read_fields, read_state
from harness.measure.run_checks import judge
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
        # One rank's 2D default factorises (MUMPS's LU), the ranks' iterate to the forcing term's eta: Newton's
        # path may differ by a step, as with PETSc against the direct solver (test_petsc.py).
        assert abs(many.record.newton_iterations - one.record.newton_iterations) <= 1
        # The ranks solve each step to one rank's forcing term (freefem/forcing.idp, within [etaMin, etaMax] =
        # [1e-10, 1e-4]; run.json's krylov_tolerance is the last step's), not to run.krylov_rtol (1e-11).
        assert 1e-10 <= many.record.parallel["krylov_tolerance"] <= 1e-4
        assert many.record.active_nodes[-1] == one.record.active_nodes[-1]
        for name, a, b in zip(("u", "phi", "theta"), read_state(one.directory / "state.txt"),
                              read_state(many.directory / "state.txt")):
            scale = max(np.abs(a).max(), 1e-300)
            assert np.abs(a - b).max() <= AGREE * scale, (case, count, name, np.abs(a - b).max() / scale)
        # The ranks wrote the outputs themselves: no sequential pass ran after them.
        assert many.record.post_pass_peak_rss_mb is None and not (many.directory / "ranks_record.txt").exists()
        assert_lean_ranks(many.directory, count)
        assert_one_rank_outputs(one.directory, many.directory)
        scene = load_scene(CASES / f"{case}.toml")
        verdicts = [judge(run.record, scene) for run in (one, many)]
        assert verdicts[0].failed == verdicts[1].failed and verdicts[0].missing == verdicts[1].missing


def assert_lean_ranks(directory: Path, ranks: int) -> None:
    """Each rank's subdomain K was taken over by the distributed matrix (held once), the contact terms
    came from the plugin's kernel (no note that the varfs assembled them; the ranks' checks' integrals
    are then the kernel's, weighted by the partition of unity, which assert_one_rank_outputs compares
    with one rank's), and run.json has every profile piece's wall time on every rank."""
    stdout = (directory / "stdout.txt").read_text()
    assert "ranks: K held once, in the distributed matrix" in stdout
    assert "note: the contact kernel" not in stdout
    run = json.loads((directory / "run.json").read_text())
    walls = run["parallel"]["profile_wall_s"]
    assert list(walls) == list(run["profile"])
    assert all(len(w) == ranks and min(w) >= 0 for w in walls.values())
    # The pieces are consecutive (each starts where the last ended): on every rank they add up to the
    # run's wall from the first piece on, which is within the whole run's.
    totals = np.sum([w for w in walls.values()], axis=0)
    assert np.all(totals <= run["parallel"]["wall"]["total_s"] + 0.5)


# run.json's quantities the harness reads after a run, each against the scale its physical check judges it
# on (harness/measure/checks.py): a nodal traction or flux and a balance's sum are a residual's parts,
# K x - b at a node, where terms of the reading's size cancel; their round-off is the reading's, not
# their own (max_sigma_nu is -1.4e-7 N/m^2 against a traction reading of 6.8e3 on paper3d at n = 4).
CHECK_SCALES = {
    "applied_load": "force_reading", "clamp_reaction": "force_reading", "contact_force_on_body": "force_reading",
    "max_sigma_nu": "traction_reading", "min_sigma_nu": "traction_reading", "max_abs_sigma_tau": "traction_reading",
    "S": "traction_reading", "heat_source": "heat_reading", "heat_out_dirichlet": "heat_reading",
    "max_heat_flux_contact": "heat_flux_reading", "max_heat_flux_open": "heat_flux_reading",
    "max_heat_flux_open_expected": "heat_flux_reading", "charge_source": "charge_reading",
    "charge_out_dirichlet": "charge_reading", "electrode_charge": "charge_reading",
    "max_charge_flux_contact": "charge_flux_reading", "max_charge_flux_open": "charge_flux_reading",
    "max_charge_flux_open_expected": "charge_flux_reading",
}
# Relative already, and round-off or Newton's last residual (the residual bounds, sqrt(N) ||R|| S), which
# differ with the Newton path, not with where the outputs are made (the residual history differs as much):
# the checks judge them the same way on both sides (judge, below).
NEWTON_CHECKS = ("force_imbalance", "force_residual_bound", "heat_imbalance", "charge_imbalance",
                 "heat_residual_bound", "charge_residual_bound")
# The contact integrals, in a reading's units (checks.idp).
TOP_SCALES = {"contact_force": "force_reading", "friction_force": "force_reading", "friction_total": "force_reading",
              "friction_open": "force_reading", "heat_in_contact": "heat_contact_reading",
              "charge_in_contact": "charge_contact_reading"}


def close(a, b, scale: float = 0.0) -> bool:
    a, b = np.atleast_1d(np.asarray(a, dtype=float)), np.atleast_1d(np.asarray(b, dtype=float))
    bound = AGREE * max(np.abs(a).max(initial=0), np.abs(b).max(initial=0), scale)
    return bool(np.abs(a - b).max(initial=0) <= bound)


def assert_one_rank_outputs(one: Path, many: Path) -> None:
    """The ranks' run.json, solution.vtu and state.txt are the one-rank run's to round-off."""
    a, b = (json.loads((d / "run.json").read_text()) for d in (one, many))
    for key in ("nodes", "dofs", "fields"):
        assert a[key] == b[key], key
    # A staggered theta (one rank) is in the ranks' Newton system (harness/scene/unknowns.py).
    staggered = a["strategy"].startswith("staggered")
    assert b["newton_dofs"] == (a["dofs"] if staggered else a["newton_dofs"])
    ca, cb = a["checks"], b["checks"]
    assert ca["open_nodes"] == cb["open_nodes"]
    for key, value in ca.items():
        if staggered and key.endswith("_reading"):
            # A reading is a round-off scale, sum |K_ii x_i| + |b_i| (checks.idp); a staggered theta's coupling
            # is in b on one rank and in K x on the ranks, which moves it by a few per cent (heated at n = 8:
            # force_reading 2.12e9 against 2.06e9). The checks judge on a multiple of it: same order is enough.
            assert abs(value - cb[key]) <= 0.1 * max(abs(value), abs(cb[key])), (key, value, cb[key])
        elif key not in NEWTON_CHECKS and key != "open_nodes":
            assert close(value, cb[key], ca.get(CHECK_SCALES.get(key, ""), 0.0)), (key, value, cb[key])
    for key, scale in TOP_SCALES.items():
        assert close(a[key], b[key], ca.get(scale, 0.0)), (key, a[key], b[key])
    ranges = [key for key in a if key.startswith(("min_", "max_"))]
    assert "max_abs_u" in ranges
    for key in ranges:
        field = key.split("_", 1)[1]
        scale = max(abs(a.get(f"min_{field}", 0.0)), abs(a.get(f"max_{field}", 0.0)))
        assert close(a[key], b[key], scale), (key, a[key], b[key])
    assert close(a["friction_force_vector"], b["friction_force_vector"], ca["force_reading"])
    for key in ("estimator", "estimator_norms"):
        assert a[key] and a[key].keys() == b[key].keys()
        for field, value in a[key].items():
            assert close(value, b[key][field]), (key, field, value, b[key][field])
    fa, fb = read_fields(one / "solution.vtu"), read_fields(many / "solution.vtu")
    assert np.array_equal(fa.points, fb.points) and np.array_equal(fa.cells, fb.cells)
    assert fa.values.keys() == fb.values.keys() and "error_indicator" not in fa.values  # a cell field
    for name, value in fa.values.items():
        assert close(value, fb.values[name]), name
    ia, ib = (meshio.read(d / "solution.vtu").cell_data["error_indicator"] for d in (one, many))
    assert close(np.concatenate(ia), np.concatenate(ib)), "error_indicator"


# Every 2D effect set, each from the start its studies use, and the paper scene from both. heated's theta is
# staggered on one rank (thermal without thermal contact) and in the ranks' monolithic Newton system: the same
# discrete equations, so the same solution to round-off.
@pytest.mark.parametrize("case, guess", [("elastic", "zero"), ("electroelastic", "zero"),
                                         ("thermoelastic", "pressed"), ("heated", "zero"), ("paper", "zero"),
                                         ("paper", "pressed")])
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


def test_a_restart_from_the_pressed_state_on_ranks_reads_the_whole_mesh_again(tmp_path):
    # The ranks let the whole mesh go once the start and the numbering are made (ranks.idp); Newton's restart
    # from the pressed state solves its harmonic extensions on the whole mesh, read again. no_piezo at n = 2
    # from zero restarts after step 3 (docs/scale-out.md), on one rank (MUMPS) and on 2 with PETSc.
    layout = Layout(results=tmp_path)
    runs = []
    for ranks, solver in ((1, "mumps"), (2, "petsc")):
        scene = load_scene(CASES / "hard" / "no_piezo.toml", [f'run.linear_solver="{solver}"', f"run.ranks={ranks}",
                                                             'scene.initial_guess="zero"', f'scene.name="restart-{ranks}"'])
        runs.append(run_level(scene, build_mesh(scene.geometry, 2, layout.meshes_dir(scene.name)).path, 2, layout))
    one, two = runs
    assert one.record.restarted_at == two.record.restarted_at > 0 and two.record.converged
    assert_one_rank_outputs(one.directory, two.directory)


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


def test_a_rank_killed_during_a_petsc_solve_is_one_line_exit_3_and_no_process_left(tmp_path):
    """SIGKILL to one of two ranks: the launcher ends the other (or, should it hang with the dead rank
    unreaped, the harness does: test_rank_watch.py), the harness says which signal in one line (a
    half-written run.json of the ranks does not hide it), and the level is not written."""
    import os
    import signal
    import subprocess
    import sys
    import time

    from test_reliability import alive, descendants, one_error, wait_for

    results = tmp_path / "results"
    # One level from zero (no chain of short runs whose ranks come and go): n = 128 on 2 ranks lasts seconds.
    proc = subprocess.Popen([sys.executable, "-m", "harness", "solve", str(CASES / "paper.toml"), "--n", "128",
                             "--set", "run.ranks=2", "--set", 'run.linear_solver="petsc"',
                             "--set", 'scene.initial_guess="zero"', "--results", str(results)],
                            cwd=CASES.parent, stdout=subprocess.PIPE, stderr=subprocess.PIPE)

    def ranks() -> list[int]:
        found = []
        for pid in descendants(proc.pid):
            try:
                if Path(f"/proc/{pid}/comm").read_text().strip() == "FreeFem++-mpi":
                    found.append(pid)
            except OSError:  # ended meanwhile
                pass
        return found

    wait_for(lambda: len(ranks()) == 2 or proc.poll() is not None, timeout=60)
    assert proc.poll() is None, proc.communicate()
    time.sleep(0.5)  # inside the run (the ranks have started MPI)
    alive_ranks = ranks()
    assert len(alive_ranks) == 2 and proc.poll() is None
    tree = descendants(proc.pid)
    os.kill(alive_ranks[-1], signal.SIGKILL)
    _, err = proc.communicate(timeout=60)
    lines = err.decode().strip().splitlines()
    assert proc.returncode == ExitCode.RUN, lines
    one_error(lines, "killed by signal SIGKILL")
    wait_for(lambda: not any(alive(pid) for pid in tree), timeout=10)
    case = results / "paper"
    assert not list(case.glob(".tmp-*")) and not (case / "n128").exists()


def test_a_chain_level_too_small_for_the_ranks_runs_without_their_options(tmp_path, capsys):
    """The distributed multigrid's options, given on 2 ranks: the chain's start n = 1 (10 nodes)
    runs on one rank, whose scheme never reads -matptap_via (only the Galerkin products across
    ranks do); it is not passed there, so PETSc's check of unread options does not blame it
    (it ended in exit 2, "-matptap_via never used"); n = 2 runs on the 2 ranks with it."""
    results = tmp_path / "results"
    code = main(["solve", str(CASES / "paper.toml"), "--n", "2", "--set", "study.levels=[1, 2]",
                 "--set", "run.linear_solver=petsc", "--set", "run.ranks=2",
                 "--set", f'run.petsc_options="{petsc_options.MULTIGRID_ON_RANKS}"', "--results", str(results)])
    assert code == 0, capsys.readouterr().err
    one = json.loads((results / "paper" / "n1" / "run.json").read_text())
    two = json.loads((results / "paper" / "n2" / "run.json").read_text())
    assert one["converged"] and one.get("ranks") in (None, 1) and two["converged"] and two["ranks"] == 2
    given = json.loads((results / "paper" / "n2" / "inputs.json").read_text())
    assert "-matptap_via" in json.dumps(given) and "-matptap_via" not in (results / "paper" / "n1" / "inputs.json").read_text()


def test_adapt_on_two_ranks_in_2d_runs_each_step_on_the_ranks_its_mesh_takes(tmp_path, capsys):
    """`adapt` with PETSc on 2 ranks: step 1 is the case's level 2 (27 nodes, 3 ranks' worth),
    run on the 2 ranks, not on one as the uniform level n = 1 its number once named would be;
    every step and the reference converge (the study ended in exit 2, blaming -matptap_via)."""
    results = tmp_path / "results"
    code = main(["adapt", str(CASES / "paper.toml"), "--steps", "3", "--set", "run.linear_solver=petsc",
                 "--set", "run.ranks=2", "--set", "study.levels=[2, 4]",
                 "--set", "study.adaptive_band=[-10.0, 10.0]", "--results", str(results)])  # 3 steps: no band
    assert code == 0, capsys.readouterr().err
    table = pd.read_csv(results / "adapt" / "paper" / "adapt.csv")
    assert table["step"].tolist() == [1, 2, 3]
    for run in results.glob("adapt/**/run.json"):
        record = json.loads(run.read_text())
        assert record["converged"] and record["ranks"] == 2, run


def test_an_adapted_mesh_takes_the_ranks_of_its_own_nodes_and_one_rank_drops_the_ranks_options(tmp_path):
    """launcher.level_capacity of an adaptive step's mesh (marked by mark_coarser, even nested in
    none) counts its nodes, whatever its label; a uniform level's mesh keeps its level's count.
    Scene.on_ranks(1) drops -matptap_via (and its value) from given options, keeps the rest and
    leaves blank options to the one-rank default."""
    from harness.mesh.msh import mark_coarser
    from harness.run.launcher import level_capacity, level_scene

    scene = load_scene(CASES / "paper.toml", ["run.linear_solver=petsc", "run.ranks=2"])
    level2 = build_mesh(scene.geometry, 2, tmp_path / "meshes", warn=False).path  # 27 nodes
    assert level_capacity(scene, 1, level2) == 1  # unmarked: a level of the family, n = 1's 10 nodes
    step = tmp_path / "meshes" / "adapt_1.msh"
    step.write_bytes(level2.read_bytes())
    mark_coarser(step, [])
    assert level_capacity(scene, 1, step) == 3
    assert level_scene(scene, 1, step).sections.run.ranks == 2
    given = load_scene(CASES / "paper.toml", ["run.linear_solver=petsc", "run.ranks=2",
                                              f'run.petsc_options="{petsc_options.MULTIGRID_ON_RANKS}"'])
    alone = given.on_ranks(1)
    assert alone.petsc_options.split() == [w for w in petsc_options.MULTIGRID_ON_RANKS.split()
                                           if w not in ("-matptap_via", "allatonce")]
    assert alone.table["run"]["petsc_options"] == alone.sections.run.petsc_options
    assert scene.on_ranks(1).petsc_options == petsc_options.MUMPS_LU
