"""The GetFEM peer against FreeFEM (issue 21): the same discrete problem, solved by two
codes, agrees to round-off; the peer's own known answer; the failures a user can meet.

Tolerance 1e-9 relative per field: both codes stop Newton at a relative increment of 1e-9
per field after quadratic convergence, so the solutions agree far below it (measured
1e-16 ... 1e-13, docs/crosscheck.md); a wrong sign, tensor or quadrature shows as 1e-3 or more."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from harness import cli
from harness.core.contract import ExitCode, ROLE_LABELS
from harness.core.layout import REPO
from harness.mesh.mesh import build_mesh, mesh_path
from harness.scene.materials import values as material_values
from harness.run.peer import RUNNER, SYSTEM_PYTHON, problem, run_peer
from harness.scene.scene import load_scene

CASES = REPO / "cases"
DATA = Path(__file__).parent / "data"
AGREE = 1e-9


def crosscheck(tmp_path: Path, *args: str) -> tuple[int, pd.DataFrame]:
    code = cli.main(["crosscheck", *args, "--results", str(tmp_path / "results"), "--out", str(tmp_path / "out")])
    return code, pd.read_csv(tmp_path / "out" / "crosscheck.csv")


def field_columns(table: pd.DataFrame) -> list[str]:
    return [c for c in table.columns if c.startswith("rel_") and c.split("_")[1] in ("u", "phi", "theta")]


@pytest.mark.parametrize("case, levels", [("paper.toml", "2,4,8"), ("paper3d.toml", "2,4")])
def test_the_peer_equals_freefem_on_both_branches_of_the_paper(tmp_path, case, levels):
    code, table = crosscheck(tmp_path, str(CASES / case), "--levels", levels, "--branches", "zero,pressed")
    assert code == 0
    assert len(table) == 2 * len(levels.split(","))
    assert set(table["branch"]) == {"zero", "pressed"}
    assert (table[field_columns(table)].to_numpy() <= AGREE).all()
    # The contact integrals of both codes, too: force, heat, charge (values of order 1e-6 ... 1e3).
    for key in ("contact_force", "heat_in_contact", "charge_in_contact"):
        assert (table[f"rel_{key}"] <= AGREE).all()
    # The two branches really are different solutions (the pressed one carries ~500 N/m).
    forces = table.groupby("branch")["contact_force_getfem"].max()
    assert forces["pressed"] > 1e6 * forces["zero"]


@pytest.mark.parametrize("case", ["elastic.toml", "heated.toml"])
def test_the_peer_equals_freefem_with_effects_switched_off(tmp_path, case):
    code, table = crosscheck(tmp_path, str(CASES / case), "--levels", "2,4")
    assert code == 0
    assert (table[field_columns(table)].to_numpy() <= AGREE).all()


def test_uniform_pressure_on_a_frictionless_foundation_gives_contact_pressure_equal_to_the_load(tmp_path):
    """The peer alone: a 2x1 block with rollers on its sides pressed by 100 N/m^2 onto a
    frictionless foundation: the contact carries the load, 100 N/m^2 x 2 m, and penetrates
    uniformly by 100/c_nu."""
    scene = load_scene(DATA / "block.toml", ['scene.effects=["contact"]', 'geometry.left="roller_x"',
                                             'geometry.right="roller_x"', 'scene.initial_guess="zero"'])
    build_mesh(scene.geometry, 4, tmp_path)
    spec = problem(scene.table, scene.effects, 2, material_values(REPO / "freefem" / "materials" / "BaTiO3.idp"),
                   mesh_path(tmp_path, 4), "zero")
    record = run_peer(spec, tmp_path / "peer", 120).record
    assert record["contact_force"] == pytest.approx(200.0, rel=1e-12)
    points, u = np.array(record["u_points"]), np.array(record["u"])
    bottom = np.isclose(points[:, 1], 0.0)
    assert -u[bottom, 1] == pytest.approx(np.full(bottom.sum(), 100.0 / 1e7), rel=1e-10)


def test_a_bad_problem_path_gives_one_error_line_and_exit_code_2(tmp_path):
    done = subprocess.run([SYSTEM_PYTHON, str(RUNNER), str(tmp_path / "missing.json"), str(tmp_path / "out.json")],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert done.stderr.startswith("error: ") and done.stderr.count("\n") == 1
    # A mesh that is not there: the same, naming it.
    spec = {"mesh": str(tmp_path / "nowhere.msh"), "dimension": 2, "labels": ROLE_LABELS, "effects": [],
            "material": material_values(REPO / "freefem" / "materials" / "BaTiO3.idp"), "start": "zero",
            **{s: {} for s in ("loads", "contact", "newton")},
            "electric_contact": {"phi_f": -44.0}, "thermal_contact": {"theta_f": 373.0}}
    (tmp_path / "p.json").write_text(json.dumps(spec))
    done = subprocess.run([SYSTEM_PYTHON, str(RUNNER), str(tmp_path / "p.json"), str(tmp_path / "out.json")],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "nowhere.msh" in done.stderr and done.stderr.count("\n") == 1


def test_a_missing_getfem_names_the_package_with_its_own_exit_code(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr("harness.run.peer.SYSTEM_PYTHON", str(tmp_path / "no-python"))
    code = cli.main(["crosscheck", str(CASES / "paper.toml"), "--levels", "2", "--results", str(tmp_path)])
    assert code == ExitCode.NO_PEER == 5
    err = capsys.readouterr().err
    assert err.count("error:") == 1 and "python3-getfem" in err


def test_a_difference_above_the_tolerance_is_exit_code_6_naming_field_and_level(tmp_path, monkeypatch, capsys):
    """A peer that solves a different problem (c_nu doubled on its side only) must be caught."""
    import harness.studies.crosscheck as study

    real = study.problem

    def other(table, *args):  # noqa: ANN001, ANN202
        changed = {**table, "contact": {**table["contact"], "c_nu": 2 * table["contact"]["c_nu"]}}
        return real(changed, *args)

    monkeypatch.setattr(study, "problem", other)
    code = cli.main(["crosscheck", str(CASES / "paper.toml"), "--levels", "2", "--results", str(tmp_path / "r"),
                     "--out", str(tmp_path / "out")])
    assert code == ExitCode.DISAGREE == 6
    err = capsys.readouterr().err
    assert err.count("error:") == 1 and "n=2" in err and "relative" in err


def test_two_branches_reached_from_the_same_start_are_told_apart_from_a_mistake(tmp_path):
    """cases/hard/gap_partial.toml at n = 8 from zero: FreeFEM's Newton ends on the barely
    touching solution, the peer's (after its restart) on the pressed one. Started from
    FreeFEM's solution, the peer's first step is round-off: the same equations, two of their
    solutions (docs/crosscheck.md). Not a disagreement: exit 0, the row says why."""
    code, table = crosscheck(tmp_path, str(CASES / "hard" / "gap_partial.toml"), "--levels", "8")
    assert code == 0
    row = table.iloc[0]
    assert row["status"].startswith("branch: FreeFEM's solution solves GetFEM's equations")
    assert row["contact_force_getfem"] > 1e6 * row["contact_force_freefem"]  # pressed against barely touching


def test_repeat_times_both_codes_as_whole_processes_with_medians_and_ratios(tmp_path):
    code, _ = crosscheck(tmp_path, str(CASES / "paper.toml"), "--levels", "2", "--repeat", "2")
    assert code == 0
    timing = pd.read_csv(tmp_path / "out" / "timing.csv").iloc[0]
    assert timing["repeats"] == 2 and timing["n"] == 2
    for key in ("wall_s", "rss_mb", "assembly_s", "factorisation_s", "newton_s"):
        for code_name in ("freefem", "getfem"):
            column = f"{key}_{code_name}"
            assert 0 < timing[f"{column}_min"] <= timing[column] <= timing[f"{column}_max"]
        assert timing[f"ratio_{key}"] == pytest.approx(timing[f"{key}_freefem"] / timing[f"{key}_getfem"], rel=1e-5)
    assert "| paper | zero | 2 |" in (tmp_path / "out" / "timing.md").read_text()


@pytest.mark.parametrize("case", ["cantilever.toml", "coulomb.toml"])
def test_a_coulomb_scene_is_refused_in_one_line_not_compared_with_tresca(case, tmp_path, capsys):
    """The peer's friction is Tresca's: a Coulomb scene was solved there as Tresca (coulomb
    'agreed' only where every node sticks) or failed on its missing S."""
    code = cli.main(["crosscheck", str(CASES / case), "--levels", "2", "--results", str(tmp_path)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == ExitCode.INPUT and len(err) == 1, err
    assert case in err[0] and "Tresca friction only" in err[0] and "'coulomb'" in err[0]


def test_a_rotated_poling_is_refused_in_one_line_not_compared(tmp_path, capsys):
    """The peer takes the material file's tensors unrotated: a scene poled along x would be
    compared with one poled along y and reported as a disagreement."""
    code = cli.main(["crosscheck", str(CASES / "paper.toml"), "--levels", "2", "--results", str(tmp_path),
                     "--set", 'scene.poling_axis="x"'])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == ExitCode.INPUT and len(err) == 1, err
    assert "paper.toml" in err[0] and "default poling axis only" in err[0] and "'x'" in err[0]
    assert not any(tmp_path.iterdir())
