"""The level runner (harness/study/engine.py) on the stub solver: a LevelOutcome per level with the
failure classified by FreeFEM's exit code, a chain that stops at its first failure, and
independent chains mapped side by side (harness/study/executor.py's `each`) giving what they give
one after the other."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from harness.core.contract import Failure
from harness.study.engine import InlineMeshes, quiet, run_levels, runs_of
from harness.study.executor import each
from harness.core.layout import Layout
from harness.scene.scene import load_scene

DATA = Path(__file__).parent / "data"
STUB = DATA / "stub_freefem"
CASE = DATA / "paper.toml"


def stub_layout(root: Path) -> Layout:
    return Layout(results=root, freefem=STUB)


def test_levels_of_a_converging_scene_are_runs(tmp_path):
    scene = load_scene(CASE, ["scene.initial_guess=zero"])
    layout = stub_layout(tmp_path)
    outcomes = run_levels(scene, InlineMeshes(scene, (2, 4), layout), layout, chain=False, jobs=2, progress=quiet)
    assert list(outcomes) == [2, 4] and all(o.ok and o.failure is None for o in outcomes.values())
    assert runs_of(outcomes)[4].record.n == 4


def test_a_diverging_level_is_an_outcome_classified_by_its_exit_code(tmp_path):
    scene = load_scene(CASE, ["scene.material=Diverge"])
    layout = stub_layout(tmp_path)
    outcomes = run_levels(scene, InlineMeshes(scene, (2, 4, 8), layout), layout, progress=quiet)
    assert list(outcomes) == [2]  # the chain stops at its first failure
    failed = outcomes[2]
    assert not failed.ok and failed.failure is Failure.DIVERGED
    assert failed.directory == layout.failed_dir(scene.name, 2) and "n=2" in failed.detail
    assert failed.record is not None and failed.record.converged is True  # the stub's run.json


def chains(layout):
    """A scene's chain of levels 2, 4: one piece of independent work."""
    return lambda scene: run_levels(scene, InlineMeshes(scene, (2, 4), layout), layout, progress=quiet)


def test_chains_through_an_executor_equal_chains_one_after_the_other(tmp_path):
    scenes = [load_scene(CASE, [f"scene.name={name}"]) for name in ("a", "b")]
    alone = each(None, chains(stub_layout(tmp_path / "alone")), scenes)
    with ThreadPoolExecutor(max_workers=2) as pool:
        side = each(pool, chains(stub_layout(tmp_path / "side")), scenes)
    for one, other in zip(alone, side):
        assert list(one) == list(other) == [2, 4]
        for n in one:
            assert one[n].record.with_(wall_s=None, started_from=None, waited_s=None, pipelined=None, peak_rss_mb=None) == \
                other[n].record.with_(wall_s=None, started_from=None, waited_s=None, pipelined=None, peak_rss_mb=None)
