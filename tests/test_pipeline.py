"""The pipelined chain (harness/study/engine.py, freefem/bulk.idp): each level's FreeFEM starts
while the level below is still running and reads that level's state from stdin. It must
give the same solutions as running one level at a time, and a failure must not leave the
early-started process or its directory behind."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from harness.core.errors import RunError
from harness.measure.fields import read_state
from harness.core.layout import Layout
from harness.mesh.mesh import build_mesh
from harness.scene.scene import load_scene
from harness.study.engine import run_levels, runs_of

CASE = Path(__file__).parents[1] / "cases" / "paper.toml"
LEVELS = (2, 4, 8)


def chain(root: Path, pipelined: bool, *overrides: str):
    scene = load_scene(CASE, list(overrides))
    layout = Layout(results=root)
    meshes = {n: build_mesh(scene.geometry, n, layout.meshes_dir(scene.name)).path for n in LEVELS}
    return layout, runs_of(run_levels(scene, meshes, layout, progress=lambda s: None, pipelined=pipelined))


def test_a_pipelined_chain_gives_the_same_solutions_as_one_level_at_a_time(tmp_path):
    _, piped = chain(tmp_path / "piped", True)
    _, single = chain(tmp_path / "single", False)
    for n in LEVELS:
        for a, b in zip(read_state(piped[n].directory / "state.txt"), read_state(single[n].directory / "state.txt")):
            # The same computation on the same data: only the way the state path arrives differs.
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-12 * np.abs(b).max())
        assert piped[n].record.newton_iterations == single[n].record.newton_iterations
    for n in LEVELS[1:]:
        record = piped[n].record
        assert record.pipelined is True and record.waited_s >= 0 and record.wall_s > 0
        assert record.ready_s > 0  # FreeFEM got to the wait: bulk assembled before the state came
        assert single[n].record.pipelined is None and single[n].record.ready_s == -1
    assert piped[LEVELS[0]].record.pipelined is None  # the coarsest level has nobody to wait for


def freefem_processes_under(root: Path) -> list[int]:
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cwd = os.readlink(entry / "cwd")
        except OSError:
            continue
        if cwd.startswith(str(root)):
            found.append(int(entry.name))
    return found


def test_a_failed_level_stops_the_early_started_next_level(tmp_path):
    """n = 2 cannot converge in one Newton step from zero; n = 4, already started and
    waiting for n = 2's state, must be killed and its temporary directory removed."""
    with pytest.raises(RunError, match="n=2"):
        chain(tmp_path, True, "newton.max_iterations=1")
    assert freefem_processes_under(tmp_path) == []
    case_dir = tmp_path / "paper"
    assert [p.name for p in case_dir.glob(".tmp-*")] == []
    assert (case_dir / "n2.failed" / "stdout.txt").is_file()
    assert not (case_dir / "n4").exists()


def test_the_finest_level_starts_with_the_coarsest_and_only_when_it_will_run(tmp_path, monkeypatch):
    """Issue 13, item 6: the finest level's setup overlaps the whole chain below it. Its
    FreeFEM is launched while the coarsest runs, before the next level's; a second,
    cached study launches none (the finest's result is there and is reused)."""
    from harness.run.run import LevelRun

    launched: list[int] = []
    original = LevelRun.launch_early

    def recording(self, coarser_mesh):
        launched.append(self.n)
        original(self, coarser_mesh)

    monkeypatch.setattr(LevelRun, "launch_early", recording)
    _, runs = chain(tmp_path, True)
    assert launched == [8, 4]
    assert runs[8].record.pipelined is True and runs[8].record.ready_s > 0
    launched.clear()
    _, again = chain(tmp_path, True)
    assert launched == [] and all(run.reused for run in again.values())
    assert freefem_processes_under(tmp_path) == []
