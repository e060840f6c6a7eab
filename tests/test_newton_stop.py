"""The Newton stop (freefem/newton.idp): an iterate is accepted when every field's error
after the step, estimated by the increment or, in the quadratic phase, by the contraction
estimate Theta/(1 - Theta) ||dx_k||, is below rtol. Known answer: the accepted state agrees
with a run taken 1000 times further (rtol 1e-12) within rtol."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from harness.measure.fields import read_state
from harness.core.layout import Layout
from harness.mesh.mesh import build_mesh
from harness.run.run import run_level
from harness.scene.scene import load_scene
from harness.study.engine import run_levels, runs_of

CASE = Path(__file__).parents[1] / "cases" / "paper.toml"
RTOL = 1e-9


def test_the_contraction_stop_is_as_accurate_as_rtol_promises(tmp_path):
    scene = load_scene(CASE)
    layout = Layout(results=tmp_path)
    levels = (2, 4, 8, 16)
    meshes = {n: build_mesh(scene.geometry, n, layout.meshes_dir(scene.name)).path for n in levels}
    runs = runs_of(run_levels(scene, meshes, layout, progress=lambda s: None))
    stopped = runs[16].record
    last = stopped.newton_iterations
    increments, estimates = stopped.increments, stopped.error_estimates
    # This level is accepted on the estimate: its last increment alone would not pass.
    assert max(increments[f][last] for f in increments) > RTOL
    assert max(estimates[f][last] for f in estimates) <= RTOL

    tight = load_scene(CASE, ["newton.rtol=1e-12", 'scene.name="tight"'])
    warm = runs[8].warm_start(meshes[8])
    exact = run_level(tight, meshes[16], 16, layout, warm=warm)
    assert exact.record.newton_iterations > last
    for mine, converged in zip(read_state(runs[16].directory / "state.txt"),
                               read_state(exact.directory / "state.txt")):
        scale = np.abs(converged).max()
        assert np.abs(mine - converged).max() <= RTOL * scale
