"""The sparse direct solver is a scene choice (run.linear_solver; freefem/effects.idp's
LINEARSOLVER): every one FreeFEM offers here gives the same solution, the run says which it
used, and the peak memory reported is FreeFEM's own (freefem/memory.idp)."""

from __future__ import annotations

import resource
from pathlib import Path

import numpy as np
import pytest

from harness.core.errors import SceneError
from harness.measure.fields import read_state
from harness.core.layout import Layout
from harness.mesh.mesh import build_mesh
from harness.run.run import run_level
from harness.scene.scene import load_scene
from harness.scene.linear_solvers import SOLVERS

CASE = Path(__file__).parents[1] / "cases" / "paper.toml"
N = 4


def solve(tmp_path: Path, solver: str):
    scene = load_scene(CASE, [f"run.linear_solver={solver!r}".replace("'", '"'), "scene.initial_guess=\"zero\"",
                              f"scene.name=\"solver-{solver}\""])
    layout = Layout(results=tmp_path)
    mesh = build_mesh(scene.geometry, N, layout.meshes_dir(scene.name)).path
    return run_level(scene, mesh, N, layout)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("solvers")
    return {name: solve(root, name) for name in SOLVERS}


def test_every_linear_solver_gives_the_same_solution(runs):
    reference = read_state(runs["umfpack"].directory / "state.txt")
    for name, run in runs.items():
        assert run.record.linear_solver.startswith(SOLVERS[name].reported + " ")
        for mine, theirs in zip(read_state(run.directory / "state.txt"), reference):
            # Newton stops at a relative error of 1e-9 per field (newton.rtol); two solvers
            # may stop on either side of it.
            np.testing.assert_allclose(mine, theirs, rtol=0, atol=1e-8 * np.abs(theirs).max())


def test_the_default_solver_is_mumps():
    assert load_scene(CASE).linear_solver == "mumps"


def test_an_unknown_linear_solver_is_a_scene_error():
    with pytest.raises(SceneError, match="linear_solver"):
        load_scene(CASE, ['run.linear_solver="pardiso"'])


def test_peak_memory_is_freefems_own_high_water_mark(runs):
    """FreeFEM at n = 4 needs a few tens of MB; wait4's figure for a child forked from this
    test process could not be below this process's own resident size."""
    harness_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    for run in runs.values():
        assert run.record.peak_rss_source == "freefem VmHWM"
        assert 5 < run.record.peak_rss_mb < min(harness_mb, 500)
