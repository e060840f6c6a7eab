"""Every mesh file the harness writes stays the same bytes: each case of cases/, cases/hard and
cases/mms meshed at levels 2 and 4, a graded level, and the adaptive loop's bisected meshes
in 2D and 3D, compared by sha256 with tests/data/mesh_sha256.json.

The checksums were recorded by this file's own code (`python tests/test_mesh_bytes.py`) on the
commit before the generators shared one mesh record and one MSH writer (e4efc6c): a run's
cache key holds its mesh's checksum, so a changed byte would invalidate every cached run, and
FreeFEM would read another node numbering. A case that meshes differently on purpose
must say so where its checksum is re-recorded.
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from harness.core.layout import REPO
from harness.mesh.mesh import build_graded_mesh, build_mesh
from harness.scene.scene import load_scene
from harness.study import adapt

RECORDED = Path(__file__).parent / "data" / "mesh_sha256.json"
CASES = sorted(str(p.relative_to(REPO / "cases")) for folder in ("", "hard", "mms")
               for p in (REPO / "cases" / folder).glob("*.toml"))
LEVELS = (2, 4)
# The adaptive loop's meshes (study/adapt.py): one Dörfler-like step marking every third
# cell, then the reference's uniform refinement (3D: one shortest-diagonal split), from level 2 of a 2D, a box and a gmsh 3D scene.
ADAPTED = ("paper.toml", "paper3d.toml", "mms/tilted3d.toml")
GRADING = 1.5  # the cost study's P1-graded power (harness/report/frontier.py)


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def case_meshes(case: str, directory: Path) -> dict[str, str]:
    geometry = load_scene(REPO / "cases" / case).geometry
    return {f"{case}:n{n}": sha256(build_mesh(geometry, n, directory / case, warn=False).path) for n in LEVELS}


def graded_meshes(directory: Path) -> dict[str, str]:
    geometry = load_scene(REPO / "cases" / "paper.toml").geometry
    return {f"paper.toml:graded_n4": sha256(build_graded_mesh(geometry, 4, directory / "graded", GRADING))}


def adapted_meshes(case: str, directory: Path) -> dict[str, str]:
    scene = load_scene(REPO / "cases" / case)
    start = build_mesh(scene.geometry, 2, directory / "start" / case, warn=False).path
    refiner = adapt.REFINERS[scene.dimension]
    mesh = adapt.read_start(start, scene.dimension)
    marked = np.arange(len(mesh.cells)) % 3 == 0
    out = {}
    for name, step in (("marked", refiner.refine(mesh, marked)),
                       ("reference", adapt.reference_of(mesh))):
        path = directory / "adapt" / case / f"{name}.msh"
        adapt.write_step(step, path)
        out[f"{case}:adapt_{name}"] = sha256(path)
    return out


def recorded() -> dict[str, str]:
    return json.loads(RECORDED.read_text())


@pytest.mark.parametrize("case", CASES)
def test_every_case_meshes_to_the_recorded_bytes(case, tmp_path):
    assert case_meshes(case, tmp_path) == {k: v for k, v in recorded().items() if k.startswith(f"{case}:n")}


def test_a_graded_level_keeps_its_bytes(tmp_path):
    assert graded_meshes(tmp_path) == {k: v for k, v in recorded().items() if ":graded" in k}


@pytest.mark.parametrize("case", ADAPTED)
def test_the_adaptive_meshes_keep_their_bytes(case, tmp_path):
    assert adapted_meshes(case, tmp_path) == {k: v for k, v in recorded().items() if k.startswith(f"{case}:adapt")}


def test_every_case_has_a_recorded_checksum():
    # A case added to cases/ without its checksums would pass the comparison above vacuously.
    keys = recorded()
    assert {f"{case}:n{n}" for case in CASES for n in LEVELS} <= set(keys)
    # Each case's two levels are different files: a checksum copied from one key to another would show.
    assert all(keys[f"{case}:n2"] != keys[f"{case}:n4"] for case in CASES)


def record(directory: Path) -> dict[str, str]:
    sums: dict[str, str] = {}
    for case in CASES:
        sums.update(case_meshes(case, directory))
    sums.update(graded_meshes(directory))
    for case in ADAPTED:
        sums.update(adapted_meshes(case, directory))
    return sums


if __name__ == "__main__":
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        RECORDED.write_text(json.dumps(record(Path(tmp)), indent=1, sort_keys=True) + "\n")
    sys.stdout.write(f"wrote {RECORDED}\n")
