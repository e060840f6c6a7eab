"""The run's profile (freefem/profile.idp, run.json's "profile") and the profile study's table
(harness/studies/profile.py): every piece of a run is charged once, in time and in peak memory."""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd
import pytest

from harness.core.layout import Layout
from harness.mesh.mesh import build_mesh
from harness.run.record import RunRecord
from harness.run.run import run_level
from harness.scene.scene import load_scene
from harness.studies.profile import PEAK, TOTAL, WALL, level_rows, markdown

CASES = Path(__file__).parents[1] / "cases"


def record(profile: dict[str, list[float]], peak: float, wall: float) -> RunRecord:
    return RunRecord(dofs=100, profile=profile, peak_rss_mb=peak, wall_s=wall)


def test_level_rows_take_medians_shares_and_raises_per_piece():
    runs = [record({"bulk": [1.0, 1, 60.0], "krylov": [3.0, 3, 40.0]}, 100.0, 5.0),
            record({"bulk": [2.0, 1, 50.0], "krylov": [2.0, 3, 50.0]}, 100.0, 6.0),
            record({"bulk": [3.0, 1, 70.0], "krylov": [1.0, 3, 30.0], "late": [4.0, 1, 0.0]}, 100.0, 9.0)]
    rows = {r["piece"]: r for r in level_rows(16, runs, [2.0, 4.0, 3.0])}
    assert list(rows) == ["bulk", "krylov", "late", TOTAL, WALL, PEAK]
    assert rows["bulk"]["seconds"] == 2.0 and rows["bulk"]["raised_mb"] == 60.0 and rows["bulk"]["calls"] == 1
    # Shares per run, then their median: 1/4, 2/4, 3/8.
    assert rows["bulk"]["share"] == pytest.approx(3 / 8)
    assert rows["krylov"]["calls"] == 3 and rows["krylov"]["share"] == pytest.approx(1 / 2)
    # A piece one run lacks counts zero in the others.
    assert rows["late"]["seconds"] == 0.0
    assert rows[TOTAL]["seconds"] == 4.0 and rows[TOTAL]["raised_mb"] == 100.0
    assert rows[WALL]["seconds"] == 6.0 and rows[PEAK]["raised_mb"] == 100.0
    assert all(r["load_average"] == 3.0 and r["n"] == 16 for r in rows.values())
    assert math.isnan(rows[WALL]["share"])


def test_markdown_has_a_column_group_per_level_and_a_row_per_piece():
    runs = [record({"bulk": [1.0, 1, 60.0]}, 60.0, 2.0)]
    table = pd.DataFrame(level_rows(16, runs, [1.0]) + level_rows(32, runs, [1.5]))
    text = markdown(table, "paper3d.toml")
    assert "| piece | 1/16 s | 1/16 share | 1/16 MiB raised | 1/32 s | 1/32 share | 1/32 MiB raised |" in text
    assert "| bulk | 1.00 | 100.0 % | 60 |" in text
    assert "load average 1.5" in text


def test_a_run_charges_every_piece_once(tmp_path):
    # The paper's block on the PETSc path at its coarsest level: the script's pieces and the
    # plugin's, their seconds within the run's CPU time, their peak raises summing to the peak.
    scene = load_scene(CASES / "paper3d.toml", ['scene.name="profile-test"', 'scene.initial_guess="zero"'])
    layout = Layout(results=tmp_path)
    mesh = build_mesh(scene.geometry, 2, layout.meshes_dir(scene.name)).path
    run = run_level(scene, mesh, 2, layout).record
    profile = run.profile
    assert profile is not None
    # K comes from the plugin's element kernel on this path (the block varfs' pieces, "bulk block
    # Kuu" ..., only with -debug.bulk_blocks 1 or material regions).
    for piece in ("start-up", "bulk K by the element kernel", "bulk K into PETSc", "contact tangent", "residual: contact",
                  "PETSc: K + T into PETSc", "PETSc: preconditioner set-up", "PETSc: Krylov", "active set codes",
                  "checks: nodal tractions", "estimator", "output: solution.vtu"):
        assert piece in profile, piece
    steps = run.newton_iterations
    assert profile["contact tangent"][1] == steps and profile["active set codes"][1] == steps
    assert all(v[0] >= 0 and v[2] >= 0 for v in profile.values())
    seconds = sum(v[0] for v in profile.values())
    # Only the writing of run.json itself is outside every piece.
    assert 0.9 * run.total_s <= seconds <= run.total_s + 1e-3
    # The raises telescope to the last VmHWM read, which output.idp reads again as the peak.
    assert sum(v[2] for v in profile.values()) == pytest.approx(run.peak_rss_mb, abs=1.0)
