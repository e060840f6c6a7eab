"""The branch-stability study (`make stability`) in pieces: the jitter moves only interior
nodes and by at most 1e-9 of their shortest edge, its mesh is keyed as another mesh, the loads
are scaled by exactly what the perturbation says, and the comparison calls a case sensitive
exactly when a field, a resultant, a status or a verdict moves; then one tiny case end to end.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from harness.cli import main
from harness.core import freefem
from harness.core.contract import BODY_LABEL, Failure
from harness.core.layout import REPO, Layout
from harness.measure import agreement
from harness.measure.fields import Fields
from harness.mesh.jitter import Jitter, fixed_nodes, jittered, shortest_edges
from harness.mesh.mesh import build_mesh, checked_level
from harness.mesh.simplex import SimplexMesh, positively_oriented, signed_measures
from harness.run.cache import run_inputs
from harness.run.record import RunRecord
from harness.scene.scene import load_scene
from harness.study import stability as st
from harness.study.engine import LevelOutcome

PAPER = REPO / "cases" / "paper.toml"


def grid(k: int = 5, regions: bool = False) -> SimplexMesh:
    """The unit square as a k x k lattice of nodes, two triangles a square; with `regions`
    the cells left of x = 1/2 in region 1, the others in region 2."""
    x, y = np.meshgrid(np.linspace(0, 1, k), np.linspace(0, 1, k))
    points = np.column_stack([x.ravel(), y.ravel()])
    at = lambda i, j: j * k + i
    cells = []
    for j in range(k - 1):
        for i in range(k - 1):
            cells += [[at(i, j), at(i + 1, j), at(i + 1, j + 1)], [at(i, j), at(i + 1, j + 1), at(i, j + 1)]]
    cells = positively_oriented(points, np.array(cells))
    bottom = np.array([[at(i, 0), at(i + 1, 0)] for i in range(k - 1)])
    labelled = np.full(len(cells), BODY_LABEL)
    if regions:
        labelled = np.where(points[cells].mean(axis=1)[:, 0] < 0.5, 1, 2)
    return SimplexMesh(points, cells, bottom, np.ones(len(bottom), dtype=int), labelled if regions else None)


def test_the_jitter_moves_interior_nodes_only_and_by_at_most_1e_9_of_their_shortest_edge():
    level = grid(7)
    moved = jittered(level, Jitter(1e-9, 1))
    step = np.linalg.norm(moved.points - level.points, axis=1)
    interior = (level.points > 0).all(axis=1) & (level.points < 1).all(axis=1)
    assert (step[~interior] == 0).all()  # the boundary, the contact part among it, stays
    assert (step[interior] > 0).all()
    assert (step <= 1e-9 * shortest_edges(level) * (1 + 1e-12)).all()
    assert step.max() <= 1e-9 / 6  # h = 1/6: within 1e-9 h
    assert (signed_measures(moved.points, moved.cells) > 0).all()
    assert (moved.cells == level.cells).all() and (moved.facets == level.facets).all()


def test_the_jitter_is_the_same_for_a_seed_and_another_for_another_seed():
    level = grid(7)
    one, again, two = (jittered(level, Jitter(1e-9, s)) for s in (1, 1, 2))
    assert (one.points == again.points).all()
    assert not np.allclose(one.points - level.points, two.points - level.points, rtol=0, atol=1e-13)


def test_the_jitter_keeps_an_interface_between_material_regions():
    level = grid(5, regions=True)
    fixed = fixed_nodes(level)
    on_interface = np.isclose(level.points[:, 0], 0.5) & (level.points[:, 1] > 0) & (level.points[:, 1] < 1)
    assert on_interface.sum() == 3 and fixed[on_interface].all()
    step = np.linalg.norm(jittered(level, Jitter(1e-9, 3)).points - level.points, axis=1)
    assert (step[on_interface] == 0).all() and (step[~fixed] > 0).all()


def test_a_jittered_mesh_file_holds_the_jitter_and_keys_another_run(tmp_path):
    geometry = load_scene(PAPER).geometry
    plain = build_mesh(geometry, 4, tmp_path / "plain").path
    shaken = build_mesh(geometry, 4, tmp_path / "shaken", jitter=Jitter(1e-9, 1)).path
    level, _, _ = checked_level(geometry, 4, warn=False)
    written = np.array([[float(v) for v in line.split()[1:3]]
                        for line in shaken.read_text().split("$Nodes\n")[1].split("$EndNodes")[0].splitlines()[1:]])
    expected = jittered(level, Jitter(1e-9, 1)).points
    assert np.abs(written - expected).max() <= 1e-15 * 4  # %.16g of coordinates up to 4
    assert np.abs(written - level.points).max() > 1e-12  # the jitter survives the file
    key = lambda mesh: run_inputs(mesh, {}, Layout().freefem, "v", 4)["key"]
    assert key(plain) != key(shaken)


def test_the_loads_are_scaled_by_the_perturbation_exactly_and_reach_freefem_whole():
    paper = load_scene(PAPER)
    up = st.PERTURBATIONS[0]
    scaled = load_scene(PAPER, up.overrides(paper))
    assert scaled.table["loads"]["traction_y"] == -100.0 * (1 + 1e-12) != -100.0
    assert {k: v for k, v in scaled.table["loads"].items() if k != "traction_y"} == \
        {k: v for k, v in paper.table["loads"].items() if k != "traction_y"}  # zeros stay zero
    options = freefem.scene_options(scaled.solver_parameters(), "zero")
    assert float(options[options.index("-loads.traction_y") + 1]) == -100.0 * (1 + 1e-12)


def test_the_tilting_perturbation_alternates_its_sign_over_the_loads():
    coulomb = load_scene(REPO / "cases" / "coulomb.toml")
    tilt = next(p for p in st.PERTURBATIONS if p.slug == "loads_tilt")
    tilted = load_scene(coulomb.source, tilt.overrides(coulomb)).table["loads"]
    assert tilted["traction_x"] == 30.0 * (1 + 2e-12) and tilted["traction_y"] == -100.0 * (1 - 2e-12)


def test_five_perturbations_each_with_its_own_results_folder():
    assert len(st.PERTURBATIONS) == 5
    config = st.configs_of(PAPER, cold=False)[0]
    names = {config.scene(p).name for p in (st.UNPERTURBED, *st.PERTURBATIONS)}
    assert len(names) == 6
    assert config.levels == (2, 4, 8) and config.n == 8


def test_a_difference_is_relative_to_the_larger_value_or_its_floor():
    assert agreement.relative(1.0, 1.0 + 1e-9, 0.0) == pytest.approx(1e-9, rel=1e-6)
    assert agreement.relative(0.0, 0.0, 0.0) == 0.0
    # the barely touching branch's contact force, moved by 1e-12 of the 200 N/m it balances
    assert agreement.relative(3.7e-6, 3.7e-6 + 2e-10, 200.0) == pytest.approx(1e-12)
    assert agreement.relative(3.7e-6, 200.0, 200.0) > 0.99  # the pressed branch instead


def square_fields(u: np.ndarray, theta: np.ndarray) -> Fields:
    level = grid(5)
    return Fields(level.points, level.cells, {"u": u, "theta": theta}, Path("synthetic.vtu"))


def test_the_field_difference_is_each_fields_relative_difference_in_its_norm():
    level = grid(5)
    u = np.column_stack([level.points[:, 0], np.zeros(len(level.points))])
    theta = level.points[:, 1] ** 2
    base = square_fields(u, theta)
    other = square_fields(u * (1 + 1e-9), theta + 3e-8 * level.points[:, 0])
    scales = {"U": 1.0, "Theta": 1.0}
    out = agreement.field_differences(base, other, scales)
    assert out["u"] == pytest.approx(1e-9, rel=1e-6)
    grad_theta = agreement.norm_of(base, theta, "theta")
    assert out["theta"] == pytest.approx(3e-8 / grad_theta, rel=1e-3)


def test_a_jittered_solution_is_compared_as_a_function_not_node_by_node():
    """A slender bender's u is mostly rotation: the same solution on nodes moved by 1e-9 h,
    compared at the same node index, would differ by the rotation times the moves' gradient
    (1e-9 / 1e-3 here, as 4e-8 on the bimorph); at the same point it is the same function."""
    level = grid(7)
    moved = jittered(level, Jitter(1e-9, 1)).points
    solution = lambda p: np.column_stack([-p[:, 1] + 1e-3 * p[:, 0], p[:, 0]])  # rotation + small strain
    theta = lambda p: 1.0 + p[:, 0]
    base = Fields(level.points, level.cells, {"u": solution(level.points), "theta": theta(level.points)}, Path("a"))
    other = Fields(moved, level.cells, {"u": solution(moved), "theta": theta(moved)}, Path("b"))
    out = agreement.field_differences(base, other, {"U": 1.0, "Theta": 1.0})
    assert out["u"] < 1e-11 and out["theta"] < 1e-11
    by_index = agreement.norm_of(base, other.field("u") - base.field("u"), "u") / agreement.norm_of(base, base.field("u"), "u")
    assert by_index > 1e-7  # what the comparison node by node would call a switch


def test_a_resultant_within_its_balances_round_off_is_not_a_switch():
    """The bimorph's contact force, 3.83 N/m, moved by 4.5e-8 N/m (1.2e-8 of itself) under 1e-12
    of its load, where its force balance sums terms of 3.8e10 N/m (1000 eps of them: 8.4e-3 N/m);
    the paper's barely touching 3.7e-6 N/m against its pressed 200 N/m is a switch."""
    bimorph = lambda force: RunRecord(contact_force=force, checks={"applied_load": [0, 0], "force_reading": 3.803e10})
    assert agreement.resultant_differences(bimorph(3.8318448337577777), bimorph(3.831844879241212))["contact_force"] < 1e-8
    paper = lambda force: RunRecord(contact_force=force, checks={"applied_load": [0, -200.0], "force_reading": 1.2e5})
    assert agreement.resultant_differences(paper(3.7e-6), paper(200.0))["contact_force"] > 0.99
    assert agreement.resultant_differences(paper(3.7e-6), paper(3.7e-6 + 2e-10))["contact_force"] < 1e-11
    heat = lambda flow: RunRecord(heat_in_contact=flow, checks={"heat_reading": 1e-2, "heat_contact_reading": 1.4e-4})
    assert agreement.resultant_differences(heat(1.38e-4), heat(1.38e-4 * (1 + 2e-8)))["heat_in_contact"] > 1e-8


def test_a_field_zero_up_to_round_off_is_measured_against_its_floor():
    level = grid(5)
    u = np.column_stack([level.points[:, 0], np.zeros(len(level.points))])
    out = agreement.field_differences(square_fields(u, 1e-118 * level.points[:, 0]),
                               square_fields(u, 2e-118 * level.points[:, 0]), {"U": 1.0, "Theta": 373.0})
    assert out["theta"] < 1e-100 and out["u"] == 0.0


def test_the_verdict_is_sensitive_past_1e_8_or_on_any_change_of_status_or_checks():
    assert not st.Comparison({"u": 5e-9, "phi": 1e-12}, {"contact_force": 1e-9}, 0.0, ()).sensitive
    assert st.Comparison({"u": 2e-8}, {}, 0.0, ()).sensitive
    assert st.Comparison({"u": 0.0}, {"heat_in_contact": 1.1e-8}, 0.0, ()).sensitive
    assert st.Comparison({}, {}, math.nan, ("status converged -> not_unique",)).sensitive
    # a failed solve's answer is its status: the states two failures left are shown, not judged
    assert not st.Comparison({"u": 0.5}, {}, 0.5, (), judged=False).sensitive


def solved(failure: Failure | None, n: int = 8) -> st.Solved:
    outcome = LevelOutcome(n, failure=failure, record=RunRecord(newton_iterations=40))
    return st.Solved(st.UNPERTURBED, load_scene(PAPER), outcome, 8)


def test_a_failure_that_changes_its_reason_or_its_level_is_a_change_of_status():
    assert st.verdict_changes(solved(Failure.NOT_UNIQUE), solved(Failure.NOT_UNIQUE)) == ()
    changed = st.verdict_changes(solved(Failure.NOT_UNIQUE), solved(Failure.MAX_ITERATIONS))
    assert changed == ("status not_unique -> max_iterations",)
    assert st.compare(solved(Failure.NOT_UNIQUE), solved(Failure.MAX_ITERATIONS)).sensitive
    assert solved(Failure.DIVERGED, n=4).status == "failed at n=4"


def test_a_case_line_names_its_switching_perturbation_and_a_documented_case_says_so(monkeypatch):
    from harness.studies.stability import summarise

    # No configuration is documented as sensitive today: one, for the rule.
    monkeypatch.setitem(st.KNOWN_SENSITIVE, "paper_free_ends", st.Remedy(
        "paper_free_ends_roller", ('geometry.left="roller_x"',), "a roller on the left end holds the slide"))

    base = {"perturbation": "none", "status": "converged", "newton_iterations": 4, "verdict": "reference"}
    calm = {"perturbation": "p1", "status": "converged", "newton_iterations": 4, "field_difference": 1e-9,
            "resultant_difference": 1e-12, "changed": "", "verdict": "stable"}
    flip = {**calm, "perturbation": "p2", "newton_iterations": 7, "field_difference": 0.4, "verdict": "sensitive"}
    config = st.Config("some_case", PAPER, (), (8,), "zero")
    line = st_line = summarise(config, [base, calm, flip])
    assert line["verdict"] == "sensitive" and line["field_difference"] == 0.4 and line["switched_by"].startswith("p2")
    assert st_line["its"] == "4 (4 7)"
    assert summarise(config, [base, calm])["verdict"] == "stable"
    known = st.Config("paper_free_ends", PAPER, (), (8,), "zero")
    assert summarise(known, [base, flip])["verdict"] == "sensitive (documented)"


def test_every_documented_sensitive_case_is_in_the_table_beside_its_remedy():
    names = {c.name for c in st.all_configs()}
    for name, remedy in st.KNOWN_SENSITIVE.items():
        assert name in names and remedy.name in names and len(remedy.why) > 20
    assert {"paper_free_ends", "paper_free_ends_roller"} <= names  # the once sensitive row, held to stable
    assert {"paper", "gap_open", "gap_open_cold", "paper3d", "unstructured3d"} <= names
    assert "coarsest_cold" not in names  # one level: its cold start is the case itself


def test_an_unknown_case_name_is_one_error_line(tmp_path, capsys):
    assert main(["stability", "--cases", "no_such_case", "--results", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and "no_such_case" in err[0]


def test_the_coarsest_case_is_stable_end_to_end(tmp_path, capsys):
    """n = 2, six solves of about a second: every perturbation within 1e-8 (measured 9e-10)."""
    assert main(["stability", "--cases", "coarsest", "--results", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    line = next(l for l in out.splitlines() if "coarsest" in l and "n=2" in l)
    assert "....." in line and line.rstrip().split("(")[-2].strip().endswith("stable")
    assert not (tmp_path / "stability.csv").exists()  # a part of the table is not the table
