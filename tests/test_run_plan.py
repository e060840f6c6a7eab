"""A level's run plan (harness/run/plan.py) is a value made before anything runs: making it
meshes nothing and builds nothing, the same inputs give the same key and another solver
another key, and the executor runs exactly that plan (its key is the one the run keeps).
The linear solver is one registry entry (harness/scene/linear_solvers.py): no other
module of the harness tests a solver's name."""

from __future__ import annotations

import ast
import json
from pathlib import Path

import pytest

from harness.core import native
from harness.core.layout import Layout
from harness.mesh.mesh import build_mesh
from harness.run.plan import PARALLEL_STATE, make_plan
from harness.run.run import run_level
from harness.scene import petsc_options
from harness.scene.linear_solvers import SOLVERS, Memory
from harness.scene.scene import load_scene

CASES = Path(__file__).parents[1] / "cases"
HARNESS = Path(__file__).parents[1] / "harness"
MULTIGRID = [f'run.linear_solver="petsc"', f'run.petsc_options="{petsc_options.MULTIGRID}"', "run.multigrid_coarsest=2",
             'scene.initial_guess="zero"']


def level_mesh(scene, n: int, layout: Layout) -> Path:
    return build_mesh(scene.geometry, n, layout.meshes_dir(scene.name)).path


@pytest.fixture
def no_builds(monkeypatch):
    """Fail the test if anything compiles native code (the PETSc plugin) while planning."""
    def refuse(spec):
        raise AssertionError(f"planning built {spec.what}")
    monkeypatch.setattr(native, "library", refuse)


@pytest.mark.parametrize("overrides", [MULTIGRID, ["run.ranks=2", 'run.coarse_space="nested"', 'scene.initial_guess="zero"']],
                         ids=["multigrid", "coarse space"])
def test_making_a_plan_meshes_and_builds_nothing(tmp_path, no_builds, overrides):
    layout = Layout(results=tmp_path)
    scene = load_scene(CASES / "paper.toml", overrides)
    mesh = level_mesh(scene, 16, layout)
    before = sorted(mesh.parent.iterdir())
    plan = make_plan(scene, mesh, 16, layout, None)
    assert sorted(mesh.parent.iterdir()) == before == [mesh]
    # The plan names the coarser meshes it needs, finest first, and its options name the
    # coarsest (a multigrid every one of them).
    assert [level for level, _ in plan.main.meshes][:3] == [8, 4, 2]
    assert not any(path.exists() for _, path in plan.main.meshes)
    assert str(plan.main.meshes[-1][1]) in plan.main.options
    assert plan.key == plan.inputs["key"] and len(plan.key) == 64


def test_the_same_inputs_give_the_same_key_and_another_solver_another(tmp_path):
    layout = Layout(results=tmp_path)
    scene = load_scene(CASES / "paper.toml", ['scene.initial_guess="zero"'])
    mesh = level_mesh(scene, 4, layout)
    keys = {name: make_plan(load_scene(CASES / "paper.toml", ['scene.initial_guess="zero"', f'run.linear_solver="{name}"']),
                            mesh, 4, layout, None).key for name in SOLVERS}
    assert make_plan(scene, mesh, 4, layout, None).key == keys["mumps"]
    assert len(set(keys.values())) == len(SOLVERS)


def test_a_distributed_plan_carries_its_sequential_pass(tmp_path):
    layout = Layout(results=tmp_path)
    scene = load_scene(CASES / "paper.toml", ["run.ranks=2", 'run.coarse_space="none"', 'scene.initial_guess="zero"'])
    mesh = level_mesh(scene, 8, layout)
    plan = make_plan(scene, mesh, 8, layout, None)
    # The main script is the scheme's N-rank backend (freefem/ranks.idp), the pass's the one-rank one.
    ranks = "macro PARALLELSCHEME 1 //"
    assert plan.post is not None and ranks in plan.main.script and ranks not in plan.post.script
    work = tmp_path / "work"
    options = plan.post.bound(work)
    assert options[options.index("-init.state") + 1] == str((work / PARALLEL_STATE).resolve())
    assert options[options.index("-out") + 1] == str(work.resolve())
    sequential = make_plan(load_scene(CASES / "paper.toml", ['scene.initial_guess="zero"']), mesh, 8, layout, None)
    assert sequential.post is None


def test_petsc_on_ranks_cuts_the_mesh_and_keys_how(tmp_path):
    """PETSc across the ranks reads the parts the harness cuts (harness/mesh/cut.py) into the run's
    directory; the cut's code is in the key (another cut, another run), its place is not."""
    layout = Layout(results=tmp_path)
    scene = load_scene(CASES / "paper.toml", ["run.ranks=2", 'run.linear_solver="petsc"', 'scene.initial_guess="zero"'])
    mesh = level_mesh(scene, 8, layout)
    plan = make_plan(scene, mesh, 8, layout, None)
    assert plan.main.cut == (mesh.resolve(), 2) and "mesh_cut" in plan.inputs["scene"]
    options = plan.main.bound(tmp_path / "work")
    assert options[options.index("-parallel.parts") + 1] == str((tmp_path / "work" / "parts").resolve())
    assert "-parallel.parts" not in plan.main.keyed_options
    schwarz = make_plan(load_scene(CASES / "paper.toml", ["run.ranks=2", 'run.coarse_space="none"',
                                                         'scene.initial_guess="zero"']), mesh, 8, layout, None)
    assert schwarz.main.cut is None and "-parallel.parts" not in schwarz.main.options and "mesh_cut" not in schwarz.inputs["scene"]


def test_the_executor_runs_the_plan_it_was_given(tmp_path):
    """The key a run is kept under is the plan's, made before it ran; the run is reused under it."""
    layout = Layout(results=tmp_path)
    scene = load_scene(CASES / "paper.toml", ['scene.initial_guess="zero"'])
    mesh = level_mesh(scene, 4, layout)
    plan = make_plan(scene, mesh, 4, layout, None)
    first = run_level(scene, mesh, 4, layout)
    assert not first.reused and first.key == plan.key
    assert json.loads((first.directory / "inputs.json").read_text())["key"] == plan.key
    assert (first.directory / "main.edp").read_text() == plan.main.script
    assert run_level(scene, mesh, 4, layout).reused


def test_every_solver_has_a_memory_model_the_guard_reads():
    assert {s.memory("") for s in SOLVERS.values()} <= set(Memory)
    scene = load_scene(CASES / "paper.toml", ['run.linear_solver="petsc"', f'run.petsc_options="{petsc_options.MULTIGRID}"'])
    assert not scene.factorises and scene.multigrid_levels == scene.sections.run.multigrid_levels
    split = load_scene(CASES / "paper.toml", ['run.linear_solver="petsc"',
                                               f'run.petsc_options="{petsc_options.field_split_options(("u", "phi"))}"'])
    assert split.solver.memory(split.solver_options) is Memory.ITERATIVE and split.multigrid_levels == 0
    for name in ("mumps", "umfpack", "umfpack64"):
        direct = load_scene(CASES / "paper.toml", [f'run.linear_solver="{name}"', f'run.petsc_options="{petsc_options.MULTIGRID}"'])
        assert direct.factorises and direct.multigrid_levels == 0, name  # PETSc's options are not theirs


def solver_name_tests(tree: ast.AST) -> list[int]:
    """Lines comparing something with a solver's name ("petsc" == ..., ... != "mumps", in (...))."""
    names = set(SOLVERS)
    return [node.lineno for node in ast.walk(tree) if isinstance(node, ast.Compare)
            for side in (node.left, *node.comparators)
            if isinstance(side, ast.Constant) and side.value in names
            or isinstance(side, (ast.Tuple, ast.List, ast.Set)) and any(
                isinstance(e, ast.Constant) and e.value in names for e in side.elts)]


def test_no_module_but_the_registry_tests_a_solvers_name():
    found = [f"{path.relative_to(HARNESS.parent)}:{line}" for path in sorted(HARNESS.rglob("*.py"))
             if path.name != "linear_solvers.py" for line in solver_name_tests(ast.parse(path.read_text()))]
    assert not found, found
    assert solver_name_tests(ast.parse('if scene.linear_solver == "petsc": pass'))  # the scan sees one
