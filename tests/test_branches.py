"""Solution branches of the paper's scene (issue 4): Newton from zero and from the pressed
start reach two different solutions, each on every level; `make convergence` shows the one
from zero. Coarse levels here; `make branches` runs 2 ... 64 into results/branches/."""

from __future__ import annotations

import json

import pytest

from harness.report import branch_starts as branches
from harness.core.layout import REPO, Layout
from harness.scene.scene import load_scene


@pytest.fixture(scope="module")
def rows(tmp_path_factory) -> dict[str, dict]:
    layout = Layout(results=tmp_path_factory.mktemp("branches"))
    out = [branches.branch_row(start, (2, 4, 8), layout, jobs=2, force=False)
           for start in ("zero", "pressed", "zero_each", "pressed_each")]
    labels = branches.same_branch(out)
    return {row["start"]: {**row, "branch": labels.get(row["start"])} for row in out}


def test_both_starts_converge_on_every_level_with_the_physical_checks(rows):
    for start, row in rows.items():
        assert row["status"] == "converged", (start, row.get("note"))
        assert row["checks"] == "pass", start


def test_zero_reaches_the_barely_touching_branch(rows):
    """Penetration ~1e-9 m << eps = 1e-6 m: a contact force of ~1e-6 N/m against the 200 N/m
    load (the clamps carry it), micro-kelvins, and phi between phi_f = -44 V and 0."""
    row = rows["zero"]
    assert row["contact_force"] < 1e-4
    assert row["max_theta"] < 1e-5
    assert -44.0 < row["min_phi"] < row["max_phi"] <= 1e-12


def test_pressed_reaches_the_hot_pressed_branch(rows):
    """Gamma_3 pressed beyond eps everywhere: hundreds of N/m of contact force, kelvins, and
    kilovolts from the piezoelectric response to that strain."""
    row = rows["pressed"]
    assert row["contact_force"] > 100.0
    assert row["max_theta"] > 1.0
    assert row["max_phi"] - row["min_phi"] > 1e3


def test_the_two_branches_are_eight_orders_apart(rows):
    """What the committed table (results/branches/, `make branches`, levels 2 ... 64) shows,
    at levels 2 ... 8: the pressed branch carries over a million times the contact force."""
    assert rows["pressed"]["contact_force"] > 1e6 * rows["zero"]["contact_force"]


def test_the_branch_does_not_depend_on_chaining_the_levels(rows):
    assert rows["zero"]["branch"] == rows["zero_each"]["branch"] == "zero"
    assert rows["pressed"]["branch"] == rows["pressed_each"]["branch"] == "pressed"


def test_make_convergence_shows_the_branch_from_zero():
    scene = load_scene(REPO / "cases" / "paper.toml")
    assert scene.initial_guess == "coarser"
    assert scene.sections.scene.coarsest_guess == "zero"


def test_the_paper_drawn_in_gmsh_has_the_same_two_branches(rows, tmp_path):
    """`branches` takes any case: the paper's scene drawn in gmsh (cases/paper_gmsh.toml, the
    same nodes and triangles) reaches both branches with the same quantities as the paper's
    own scene, to round-off (node numbering changes the factorisation's ordering only)."""
    layout = Layout(results=tmp_path)
    for start in ("zero", "pressed"):
        row = branches.branch_row(start, (2, 4, 8), layout, jobs=2, force=False,
                                  case=REPO / "cases" / "paper_gmsh.toml")
        assert row["status"] == "converged" and row["checks"] == "pass", (start, row.get("note"))
        summary = json.loads((tmp_path / start / "summary.json").read_text())
        assert summary["scene"]["geometry"]["kind"] == "gmsh"  # this case ran, not the paper's
        assert row["newton_iterations"] == rows[start]["newton_iterations"]
        for key in branches.FACTS:
            paper = rows[start][key]
            assert abs(row[key] - paper) <= 1e-9 * max(abs(paper), 1e-30) + 1e-30, (start, key, row[key], paper)
