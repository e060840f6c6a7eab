"""The cost-accuracy frontier (issue 5): fits and their inversion with known answers, the
errors FreeFEM measures against a reference (freefem/reference_error.idp) checked against
harness/measure/norms.py, a coarse P2 run against P1, and a whole small cost study."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from harness.report.frontier import (
    Fits,
    add_chain_costs,
    cheapest,
    fit_discretisation,
    frontier_rows,
    next_level,
    run_cost,
    write_outputs,
)
from harness.measure.fields import read_fields
from harness.core.layout import Layout
from harness.mesh.mesh import build_mesh
from harness.measure.norms import error_norms
from harness.scene.scene import load_scene
from harness.study.engine import run_levels, runs_of
from harness.measure.rates import PowerLaw, power_fit

CASE = Path(__file__).parents[1] / "cases" / "paper.toml"
H = np.array([1 / 4, 1 / 8, 1 / 16, 1 / 32, 1 / 64])
COST_KEYS = ("dofs", "newton_iterations", "bulk_assembly_s", "assembly_s", "factorisation_s",
             "first_factorisation_s", "solve_s", "newton_s", "newton_over_linear", "output_s", "total_s",
             "wall_s", "peak_rss_mb", "reference_s", "peak_rss_before_reference_mb")


# ---------------------------------------------------------------- fits, known answers


@pytest.mark.parametrize("c, p", [(2.0, 1.0), (44.0, 1.26), (3e-9, 2.0), (0.5, 0.5)])
def test_power_fit_gives_back_the_constant_and_the_exponent(c, p):
    law = power_fit(H, c * H**p)
    assert law.exponent == pytest.approx(p, abs=1e-12)
    assert law.coefficient == pytest.approx(c, rel=1e-10)
    assert law.points == len(H)


def test_power_fit_skips_missing_errors_and_needs_two_points():
    errors = 3.0 * H
    errors[2] = math.nan
    assert power_fit(H, errors).exponent == pytest.approx(1.0, abs=1e-12)
    assert power_fit(H, errors).points == 4
    assert not power_fit(H[:1], [1.0]).valid
    assert not power_fit(H[:2], [1.0, 0.0]).valid


def test_power_law_inverts_to_the_h_that_reaches_tau():
    law = PowerLaw(coefficient=10.0, exponent=1.5, points=3)
    # 10 h^1.5 = 0.01  <=>  h = (1e-3)^(1/1.5) = 0.01
    assert law.solve(0.01) == pytest.approx(0.01, rel=1e-12)
    assert law(law.solve(0.37)) == pytest.approx(0.37, rel=1e-12)


def synthetic_rows(c: float, p: float, d: float, q: float, g: float, r: float) -> pd.DataFrame:
    n = (1 / H).astype(int)
    rows = pd.DataFrame({"n": n, "h": H, "discretisation": "X", "mesh_s": 0.0})
    for name in ("u", "phi", "theta", "total"):
        rows[f"err_{name}"] = c * H**p
    rows["wall_s"] = d * H**-q  # mesh_s = 0: chain_s is the cumulative sum of these
    rows["peak_rss_mb"] = g * H**-r
    rows = add_chain_costs(rows)
    return rows


def test_fits_of_a_synthetic_study_recover_p_and_the_chain_time():
    rows = synthetic_rows(c=5.0, p=1.0, d=1e-3, q=2.0, g=2.0, r=1.0)
    fit = fit_discretisation(rows, error_levels=[4, 8, 16, 32, 64], cost_min_n=16)
    assert fit.errors["phi"].exponent == pytest.approx(1.0, abs=1e-12)
    assert fit.memory.exponent == pytest.approx(-1.0, abs=1e-12)
    # The chain of a geometric series with ratio 4 is 4/3 of its last term, asymptotically:
    # its exponent is close to -2 (the fit sees the coarse terms' tail).
    assert -fit.time.exponent == pytest.approx(2.0, abs=0.05)
    assert fit.h_range == (1 / 64, 1 / 4)  # the h of the error fits (4..64)


def test_frontier_table_inverts_the_fits():
    fits = {
        "A": Fits({"phi": PowerLaw(10.0, 1.0, 4)}, PowerLaw(1e-3, -2.0, 3), PowerLaw(2.0, -1.0, 3), (1 / 64, 1 / 8)),
        "B": Fits({"phi": PowerLaw(2.0, 1.0, 4)}, PowerLaw(4e-3, -2.0, 3), PowerLaw(4.0, -1.0, 3), (1 / 64, 1 / 8)),
    }
    table = pd.DataFrame(frontier_rows(fits, {"phi": 10.0}, taus_rel=(1e-2,)))
    a = table[table["discretisation"] == "A"].iloc[0]
    b = table[table["discretisation"] == "B"].iloc[0]
    # tau = 0.1: A needs h = 0.01 (n = 100, level 128), B h = 0.05 (n = 20, level 32).
    assert a["tau"] == pytest.approx(0.1)
    assert a["h"] == pytest.approx(0.01) and a["level"] == 128 and a["extrapolated"]
    assert a["time_s"] == pytest.approx(1e-3 * 0.01**-2) and a["memory_mb"] == pytest.approx(200.0)
    assert b["h"] == pytest.approx(0.05) and b["level"] == 32 and not b["extrapolated"]
    assert b["time_s"] == pytest.approx(4e-3 * 0.05**-2)  # 1.6 s against A's 10 s
    assert a["extrapolation"] == pytest.approx(1.5625) and b["extrapolation"] == 1.0
    assert cheapest(table) == {"phi": {"0.01": "B"}}
    # Far outside the data a prediction is not offered, nor counted as the cheapest.
    far = pd.DataFrame(frontier_rows(fits, {"phi": 10.0}, taus_rel=(1e-4,)))
    assert (far["extrapolation"] > 4).all() and cheapest(far) == {}


def test_next_level_is_the_first_power_of_two_at_or_below_h():
    assert next_level(1 / 64) == 64
    assert next_level(1 / 65) == 128
    assert next_level(0.3) == 4
    assert next_level(2.0) == 1


# ---------------------------------------------------------------- FreeFEM


def chain(tmp_path: Path, levels, *overrides):
    scene = load_scene(CASE, overrides)
    layout = Layout(results=tmp_path)
    meshes = {n: build_mesh(scene.geometry, n, layout.meshes_dir(scene.name)).path for n in levels}
    return meshes, runs_of(run_levels(scene, meshes, layout, progress=lambda s: None))


def reference_options(meshes, runs, n: int, element: str) -> list[str]:
    return [f"reference.mesh={json.dumps(str(meshes[n].resolve()))}",
            f"reference.state={json.dumps(str((runs[n].directory / 'state.txt').resolve()))}",
            f"reference.element={element}"]


def test_freefem_reference_errors_of_p1_agree_with_the_harness_norms(tmp_path):
    """P1 against a P1 reference: the norms FreeFEM integrates on the reference mesh are
    the ones harness/measure/norms.py computes from the two VTU files."""
    meshes, ref = chain(tmp_path, (2, 4, 8), "scene.name=ref")
    _, runs = chain(tmp_path, (2, 4), "scene.name=p1", *reference_options(meshes, ref, 8, "P1"))
    fine = read_fields(ref[8].solution)
    for n in (2, 4):
        ours = runs[n].record.reference_errors
        theirs = error_norms(read_fields(runs[n].solution), fine, ["u", "phi", "theta"])
        for name in ("u", "phi", "theta"):
            assert ours[name] == pytest.approx(theirs[name], rel=1e-9), (n, name)
    # The reference against itself: zero (a P1 run at the reference's level).
    _, same = chain(tmp_path, (2, 4, 8), "scene.name=same", *reference_options(meshes, ref, 8, "P1"))
    assert all(v < 1e-12 * max(1.0, abs(same[8].record.reference_norms[k]))
               for k, v in same[8].record.reference_errors.items())


def test_p2_is_more_accurate_than_p1_at_the_same_h_and_reports_its_costs(tmp_path):
    meshes, ref = chain(tmp_path, (2, 4, 8), "scene.name=ref", "scene.element=P2")
    opts = reference_options(meshes, ref, 8, "P2")
    _, p1 = chain(tmp_path, (2, 4), "scene.name=p1", "scene.element=P1", *opts)
    _, p2 = chain(tmp_path, (2, 4), "scene.name=p2", "scene.element=P2", *opts)
    e1, e2 = p1[4].record.reference_errors, p2[4].record.reference_errors
    assert set(e1) == set(e2) == {"u", "phi", "theta"}
    for name in e1:
        assert 0 < e2[name] < 0.5 * e1[name], name
    assert p2[4].record.element == "P2" and p1[4].record.element == "P1"
    assert p2[4].record.dofs == 4 * (2 * 16 + 1) * (2 * 4 + 1)  # P2 nodes of the 16 x 4 cell mesh
    for key in COST_KEYS:
        value = getattr(p2[4].record, key)
        assert isinstance(value, (int, float)) and value >= 0, key
    assert p2[4].record.newton_over_linear > 1


def test_a_small_cost_study_writes_its_table_plots_and_frontier(tmp_path):
    study = run_cost(CASE, (2, 4, 8), ("P1", "P2"), ("P2", 8), (16,), (), tmp_path, progress=lambda s: None)
    written = {p.name for p in write_outputs(study, tmp_path)}
    assert {"cost.csv", "frontier.md", "frontier.csv", "fits.csv", "summary.json", "cost_vs_time.png",
            "cost_vs_dofs.png", "time_split.png", "scaling.png"} <= written
    table = pd.read_csv(tmp_path / "cost.csv")
    for column in ("scene", "discretisation", "n", "dofs", "newton_iterations", "assembly_s", "factorisation_s",
                   "solve_s", "total_s", "peak_rss_mb", "err_u", "err_phi", "err_theta", "err_total",
                   "newton_over_linear", "mesh_s", "startup_s", "wall_s", "chain_s"):
        assert column in table, column
    p1 = table[table["discretisation"] == "P1"].set_index("n")
    assert list(p1.index) == [2, 4, 8, 16]  # the scaling level extends the P1 chain
    assert math.isnan(p1.loc[16, "err_total"])  # finer than the reference: no error
    assert p1.loc[8, "err_total"] > 0  # P1 at the reference's h, against P2: an error
    assert list(table[table["discretisation"] == "P2"]["n"]) == [2, 4]  # never against itself
    assert (p1["chain_s"].diff().dropna() > 0).all()
    assert "to reach E <= tau" in (tmp_path / "frontier.md").read_text()


def test_graded_coordinate_fixes_the_breakpoints_and_packs_towards_the_focus():
    from harness.mesh.mesh import graded_coordinate
    t = np.linspace(0.0, 4.0, 65)
    g = graded_coordinate(t, [1.0, 3.0], 2.0)
    assert np.all(np.diff(g) > 0)  # increasing: triangles keep their orientation
    for fixed in (0.0, 1.0, 2.0, 3.0, 4.0):
        assert g[np.isclose(t, fixed)] == pytest.approx(fixed)
    # s^2 on [1, 2]: the first cell next to x = 1 is h^2, the last one ~2h.
    h = 4.0 / 64
    assert g[17] - g[16] == pytest.approx(h**2)
    assert g[32] - g[31] == pytest.approx(1 - (1 - h) ** 2)
    assert graded_coordinate(t, [1.0, 3.0], 1.0) == pytest.approx(t)
