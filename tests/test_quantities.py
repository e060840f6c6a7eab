"""The quantities an engineer reads (harness/scene/quantities.py's table, docs/quantities.md):
every run writes them into run.json from the keys the table names, a case's probes and averages
read known answers in 2D and 3D, a probe outside the body is refused before anything runs,
contact.csv holds the contact state along Gamma_3, and a study writes each quantity's
convergence, never extrapolating a triple that is not asymptotic."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pandas as pd
import pytest

from harness.cli import main
from harness.measure.quantity_study import (CONVERGED, EXTRAPOLATED, NOT_EXTRAPOLABLE, TOO_FEW, converge)
from harness.scene.quantities import BUILT_IN, read_source
from harness.scene.scene import load_scene
from harness.core.errors import SceneError

ROOT = Path(__file__).parents[1]
DATA = ROOT / "tests" / "data"
PAPER = ROOT / "cases" / "paper.toml"
LINEAR = DATA / "linear_probes.toml"
LINEAR_3D = DATA / "linear_probes3d.toml"
# A P1 solution of a linear (or constant) manufactured field is that field: what is left is the
# direct solve's and Newton's round-off, ~1e-15 of the field (measured: 9e-16 in 2D, 1.3e-14 in 3D).
EXACT = 1e-12


def run_json(results: Path, scene: str, n: int) -> dict:
    return json.loads((results / scene / f"n{n}" / "run.json").read_text())


def test_a_probe_reads_a_linear_field_exactly_and_an_average_a_constant_in_2d(tmp_path):
    assert main(["solve", str(LINEAR), "--n", "4", "--results", str(tmp_path)]) == 0
    q = run_json(tmp_path, "linear_probes", 4)["quantities"]
    assert q["tip_uy"] == pytest.approx(1e-8 * (0.5 * 3.3 - 0.7 + 0.25), rel=EXACT)
    assert q["theta_mid"] == pytest.approx(1e-3 * (0.5 + 1.7 - 0.3 * 0.35), rel=EXACT)
    assert q["phi_top"] == pytest.approx(7.0, rel=EXACT)
    # theta over both clamped sides, x = 0 and x = 4: the mean of 1e-3 (0.5 + x - 0.3 y) is at (2, 0.5)
    assert q["theta_left"] == pytest.approx(1e-3 * (0.5 + 2.0 - 0.15), rel=EXACT)


def test_probes_and_averages_read_known_answers_in_3d(tmp_path):
    assert main(["solve", str(LINEAR_3D), "--n", "2", "--results", str(tmp_path)]) == 0
    q = run_json(tmp_path, "linear_probes3d", 2)["quantities"]
    assert q["uz_inside"] == pytest.approx(1e-8 * (0.3 * 0.65 - 0.2 * 1.3), rel=EXACT)
    assert q["theta_inside"] == pytest.approx(1e-3 * (0.5 + 0.7 - 0.06 + 0.63), rel=EXACT)
    assert q["phi_top"] == pytest.approx(7.0, rel=EXACT)
    assert q["theta_top"] == pytest.approx(1e-3 * (0.5 + 1.0 - 0.15 + 0.7), rel=EXACT)  # z = 1, at the face's centre


def refused(tmp_path: Path, capsys, case: Path, probe: str, n: int = 4) -> str:
    code = main(["solve", str(case), "--n", str(n), "--results", str(tmp_path), "--set", f"quantities.probes=[{probe}]"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and err[0].startswith("error:")
    assert str(case) in err[0] and "'far'" in err[0] and "outside the body" in err[0]
    return err[0]


def test_a_probe_outside_a_rectangle_is_refused_before_anything_runs(tmp_path, capsys):
    refused(tmp_path, capsys, LINEAR, '{name="far", field="u_y", at=[4.5, 0.5]}')
    assert not (tmp_path / "linear_probes").exists()  # nothing meshed, nothing run


def test_a_probe_outside_a_gmsh_body_but_inside_its_bounding_box_is_refused_by_the_mesh(tmp_path, capsys):
    """The block turned by 30 degrees spans (-0.5, 0) to (1.73, 1.87); (1.6, 0.1) lies below its
    base (y = x tan 30 = 0.92 there), outside the body but inside that box. A study's levels run
    side by side (the case starts each from the pressed state): the coarsest level's mesh, made
    in memory by the guards, refuses it before any of them is meshed or run."""
    line = refused(tmp_path, capsys, DATA / "tilted_block.toml", '{name="far", field="u_y", at=[1.6, 0.1]}', n=2)
    assert "mesh of level n=2" in line
    assert not list((tmp_path / "tilted_block").glob("n2*"))  # no run started
    code = main(["convergence", str(DATA / "tilted_block.toml"), "--levels", "2,4,8", "--results", str(tmp_path / "study"),
                 "--set", 'quantities.probes=[{name="far", field="u_y", at=[1.6, 0.1]}]'])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "'far'" in err[0] and "mesh of level n=2" in err[0]
    assert not (tmp_path / "study").exists()  # nothing meshed, nothing run
    # a point of the body itself is read
    assert main(["solve", str(DATA / "tilted_block.toml"), "--n", "2", "--results", str(tmp_path),
                 "--set", 'quantities.probes=[{name="mid", field="u_y", at=[0.5, 0.6]}]']) == 0
    q = run_json(tmp_path, "tilted_block", 2)["quantities"]
    assert math.isfinite(q["mid"])
    # The free block pressed by 100 N/m^2 on its top (tests/data/tilted_block.toml) carries a uniform
    # stress, which P1 represents exactly: the pressure is 100 N/m^2 at every node of its base of
    # length 2, up to what the solve leaves: 1.3e-7 of it measured (Newton stops this case at
    # relative increments of newton.rtol; the tilted mesh's coordinates are rounded), within 1e-6
    assert q["peak_contact_pressure"] == pytest.approx(100.0, rel=1e-6)
    assert q["contact_force_normal"] == pytest.approx(200.0, rel=1e-6)


@pytest.mark.parametrize("probe, complaint", [
    ('{name="p", field="u_z", at=[1.0, 0.5]}', "the scene has no field 'u_z'"),
    ('{name="p", field="u_y", at=[1.0, 0.5, 0.2]}', "must be a point of 2 coordinates"),
    ('{name="max_theta", field="u_y", at=[1.0, 0.5]}', "the name is taken"),
    ('{name="p", field="u_y"}', "needs exactly the keys name, field, at"),
])
def test_a_bad_probe_is_refused_when_the_scene_loads(probe, complaint):
    with pytest.raises(SceneError, match=complaint):
        load_scene(LINEAR, [f"quantities.probes=[{probe}]"])


def test_an_average_on_a_part_the_geometry_lacks_is_refused():
    with pytest.raises(SceneError, match="must be a boundary role the geometry has"):
        load_scene(LINEAR, ['quantities.averages=[{name="a", field="phi", on="contact"}]'])


def test_a_case_without_quantities_keeps_its_scene_table():
    """summary.json's scene table (and so every committed summary) is what it was before the
    section existed."""
    assert "quantities" not in load_scene(PAPER).table
    assert "quantities" in load_scene(LINEAR).table


def test_every_quantity_of_the_paper_scene_is_its_one_source_and_contact_csv_holds_gamma_3(tmp_path):
    assert main(["solve", str(PAPER), "--n", "2", "--results", str(tmp_path)]) == 0
    data = run_json(tmp_path, "paper", 2)
    q = data["quantities"]
    assert set(q) == {x.name for x in BUILT_IN}  # every effect is on; no electrode part
    for quantity in BUILT_IN:  # one name per value: each quantity is its source's number
        assert q[quantity.name] == read_source(quantity.source, data), quantity.name
    table = pd.read_csv(tmp_path / "paper" / "n2" / "contact.csv")
    assert list(table.columns) == ["x", "y", "gap", "contact_pressure", "tangential_traction", "slip",
                                   "electric_conductance", "thermal_conductance"]
    # Gamma_3 = [1, 3] x {0} at h = 1/2: its 5 nodes, ordered by position
    assert table["x"].tolist() == [1.0, 1.5, 2.0, 2.5, 3.0] and (table["y"] == 0).all()
    c_nu, k_e, eps_e = 1e7, 0.1, 1e-6  # cases/paper.toml
    assert table["contact_pressure"].to_numpy() == pytest.approx(c_nu * (-table["gap"]).clip(lower=0).to_numpy(),
                                                                 rel=1e-12)
    conductance = k_e * (-table["gap"] / eps_e).clip(0, 1)
    assert table["electric_conductance"].to_numpy() == pytest.approx(conductance.to_numpy(), rel=1e-12)
    assert q["peak_contact_pressure"] == table["contact_pressure"].max()


def test_a_study_writes_each_quantity_beside_its_convergence(tmp_path):
    assert main(["convergence", str(LINEAR), "--levels", "2,4,8", "--results", str(tmp_path)]) in (0, 1)
    case = tmp_path / "linear_probes"
    values = pd.read_csv(case / "quantities.csv")
    names = [q.name for q in load_scene(LINEAR).quantities]
    assert list(values.columns) == ["n", "h", "dofs", "wall_s", *names]
    assert values["n"].tolist() == [2, 4, 8]
    assert (case / "quantities.png").stat().st_size > 0
    summary = json.loads((case / "summary.json").read_text())["quantities"]
    assert list(summary) == names
    tip = summary["tip_uy"]  # exact on every level: converged to round-off, not extrapolated from noise
    assert tip["status"] == CONVERGED and tip["levels"] == [8, 4, 2] and tip["gci"] == 0.0
    assert tip["extrapolated"] == pytest.approx(1.2e-8, rel=EXACT)
    assert set(tip["relative_errors"]) == {"2", "4", "8"}


def test_a_quantity_converging_as_h_squared_is_extrapolated_to_its_limit():
    values = {n: 3.0 + 5.0 / n**2 for n in (4, 8, 16, 32)}
    q = converge("q", "m", values)
    assert q.status == EXTRAPOLATED and q.levels == (32, 16, 8)
    assert q.order == pytest.approx(2.0, rel=1e-9)
    assert q.extrapolated == pytest.approx(3.0, rel=1e-12)
    # Celik et al. eq. 9: 1.25 |f1 - f2| / |f1| / (r^p - 1)
    f1, f2 = values[32], values[16]
    assert q.gci == pytest.approx(1.25 * abs(f1 - f2) / f1 / 3.0, rel=1e-9)
    assert q.relative_errors[4] == pytest.approx(5.0 / 16 / 3.0, rel=1e-9)


@pytest.mark.parametrize("values, behaviour", [
    ({4: 1.0, 8: 1.2, 16: 1.1, 32: 1.15}, "oscillatory"),   # the differences change sign
    ({4: 1.0, 8: 1.01, 16: 1.03, 32: 1.07}, "divergent"),   # the differences grow
    # the paper scene's friction force on the zero branch at n = 4, 8, 16 [N/m]: monotone, but
    # Richardson's value would be a magnitude below zero
    ({4: 2.412e-4, 8: 8.836e-5, 16: 7.933e-6}, "overshoot"),
])
def test_a_quantity_that_is_not_asymptotic_is_never_extrapolated(values, behaviour):
    q = converge("q", "m", values)
    assert q.status == NOT_EXTRAPOLABLE and q.why.startswith(behaviour)
    assert math.isnan(q.extrapolated) and math.isnan(q.order) and math.isnan(q.gci)
    assert q.relative_errors == {}
    assert q.summary()["extrapolated"] != q.summary()["extrapolated"]  # NaN: written as null in summary.json


def test_two_levels_are_too_few():
    assert converge("q", "m", {4: 1.0, 8: 1.1}).status == TOO_FEW


@pytest.mark.parametrize("solver", ["petsc", "mumps"])
def test_probes_and_contact_csv_on_two_ranks_are_those_of_one(tmp_path, solver):
    """On 2 MPI ranks, with PETSc (the ranks write the outputs, gathering the fields onto rank 0)
    and with the default solver (a sequential pass writes them): the probes are still exact and
    contact.csv is one rank's to round-off (the 2-rank solve's, ~1e-13 of the field measured)."""
    ranks = ["--set", "run.ranks=2", "--set", f"run.linear_solver={solver}"]
    assert main(["solve", str(LINEAR), "--n", "8", "--results", str(tmp_path / "ranks"), *ranks]) == 0
    q = run_json(tmp_path / "ranks", "linear_probes", 8)["quantities"]
    assert q["tip_uy"] == pytest.approx(1e-8 * (0.5 * 3.3 - 0.7 + 0.25), rel=EXACT)
    assert q["theta_left"] == pytest.approx(1e-3 * (0.5 + 2.0 - 0.15), rel=EXACT)
    assert main(["solve", str(PAPER), "--n", "8", "--results", str(tmp_path / "ranks"), *ranks]) == 0
    assert main(["solve", str(PAPER), "--n", "8", "--results", str(tmp_path / "one")]) == 0
    many = pd.read_csv(tmp_path / "ranks" / "paper" / "n8" / "contact.csv")
    one = pd.read_csv(tmp_path / "one" / "paper" / "n8" / "contact.csv")
    assert list(many.columns) == list(one.columns) and len(many) == len(one) == 17
    for column in one.columns:
        assert many[column].to_numpy() == pytest.approx(one[column].to_numpy(), rel=1e-9, abs=1e-9 * one[column].abs().max())


def test_plot_draws_the_pressure_along_the_contact_and_refuses_a_run_without_one(tmp_path, capsys):
    assert main(["solve", str(PAPER), "--n", "2", "--results", str(tmp_path)]) == 0
    assert main(["plot", str(tmp_path / "paper"), "--view", "contact"]) == 0
    assert (tmp_path / "paper" / "contact.png").read_bytes()[:4] == b"\x89PNG"
    assert main(["solve", str(LINEAR), "--n", "2", "--results", str(tmp_path)]) == 0
    capsys.readouterr()
    assert main(["plot", str(tmp_path / "linear_probes"), "--view", "contact"]) == 2  # input: a run without contact
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no contact.csv" in err[0]


def test_a_failed_study_puts_back_the_earlier_quantities(tmp_path):
    """quantities.csv and quantities.png are the study's files like convergence.csv: a study that
    fails after writing them leaves the earlier ones (harness/core/atomic.py REPORT_FILES)."""
    from harness.core.atomic import StudyTransaction

    case = tmp_path / "paper"
    case.mkdir()
    for name in ("convergence.csv", "quantities.csv", "quantities.png"):
        (case / name).write_text("earlier")
    with pytest.raises(RuntimeError):
        with StudyTransaction(case):
            for name in ("convergence.csv", "quantities.csv", "quantities.png"):
                (case / name).unlink()
                (case / name).write_text("half of a later study")
            raise RuntimeError("the later study failed")
    assert all((case / name).read_text() == "earlier" for name in ("convergence.csv", "quantities.csv", "quantities.png"))


def test_contact_csv_in_3d_has_a_row_per_node_of_gamma_3(tmp_path):
    assert main(["solve", str(ROOT / "cases" / "paper3d.toml"), "--n", "2", "--results", str(tmp_path)]) == 0
    table = pd.read_csv(tmp_path / "paper3d" / "n2" / "contact.csv")
    assert list(table.columns) == ["x", "y", "z", "gap", "contact_pressure", "tangential_traction", "slip",
                                   "electric_conductance", "thermal_conductance"]
    # Gamma_3 = [1, 3] x [0, 1] x {0} at h = 1/2: 5 x 3 nodes, ordered by x, then y
    assert len(table) == 15 and (table["z"] == 0).all()
    assert list(zip(table["x"], table["y"]))[:4] == [(1.0, 0.0), (1.0, 0.5), (1.0, 1.0), (1.5, 0.0)]
    q = run_json(tmp_path, "paper3d", 2)["quantities"]
    assert q["peak_contact_pressure"] == table["contact_pressure"].max()
    assert (table["tangential_traction"] >= 0).all()  # a magnitude in 3D


def test_each_electrode_is_a_quantity_named_by_its_role(tmp_path):
    """The driven electrode's charge and each floating electrode's are the checks' own readings
    (freefem/checks.idp, freefem/floating.idp), under electrode_charge.<role>."""
    assert main(["solve", str(DATA / "floating_pair.toml"), "--n", "4", "--results", str(tmp_path)]) == 0
    data = run_json(tmp_path, "floating_pair", 4)
    q, checks = data["quantities"], data["checks"]
    assert [k for k in q if k.startswith("electrode_charge.")] == ["electrode_charge.floating", "electrode_charge.floating_2"]
    assert [q["electrode_charge.floating"], q["electrode_charge.floating_2"]] == checks["floating_charge"]
    assert q["electrode_charge.floating"] == pytest.approx(1e-6, rel=1e-9)  # the given charge, as solved
    strip = ROOT / "cases" / "strip_actuator.toml"
    assert main(["solve", str(strip), "--n", "2", "--results", str(tmp_path)]) == 0
    data = run_json(tmp_path, "strip_actuator", 2)
    assert data["quantities"]["electrode_charge.electrode"] == data["checks"]["electrode_charge"] != 0
