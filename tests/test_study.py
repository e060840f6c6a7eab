"""Rates from synthetic errors, and a whole study on the stand-in solver: table, slopes,
progress, reuse, and a report that is written whole or not at all."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest

import harness.report.report
from harness.measure.rates import fitted_slope, pairwise_orders
from harness.report.report import write_report
from harness.scene.scene import load_scene
from harness.study.study import run_study, slopes

H = np.array([1 / 2, 1 / 4, 1 / 8, 1 / 16, 1 / 32])


@pytest.mark.parametrize("p, c", [(1.0, 1.0), (1.5, 3.0), (2.0, 1e-9), (0.5, 44.0)])
def test_slope_fit_recovers_the_exponent_of_a_power_law(p, c):
    # Exact data: only round-off of log and lstsq remains.
    assert fitted_slope(H, c * H**p) == pytest.approx(p, abs=1e-12)


def test_slope_fit_is_least_squares_over_all_points():
    errors = H * np.exp([0.1, -0.1, 0.1, -0.1, 0.1])  # scatter around slope 1
    expected = np.polyfit(np.log(H), np.log(errors), 1)[0]
    assert fitted_slope(H, errors) == pytest.approx(expected, abs=1e-12)


def test_slope_fit_has_no_answer_without_two_positive_errors():
    assert math.isnan(fitted_slope(H[:1], [1.0]))
    assert math.isnan(fitted_slope(H[:2], [1.0, 0.0]))
    assert math.isnan(fitted_slope(H[:2], [1.0, math.nan]))


def test_pairwise_orders_are_log2_of_successive_ratios():
    errors = [8.0, 4.0, 1.0, 0.5]
    assert pairwise_orders(H[:4], errors)[1:] == pytest.approx([1.0, 2.0, 1.0], abs=1e-12)
    assert math.isnan(pairwise_orders(H[:4], errors)[0])


def test_window_leaves_out_the_level_next_to_the_reference():
    """The level next to the reference is polluted by the reference's own error; the window
    fit ignores it, the all-levels fit does not."""
    table = pd.DataFrame({"h": [*H, 1 / 64]})
    table["err_u"] = [*(2 * H[:4] ** 1), 0.5 * 2 * H[4], math.nan]
    table["err_total"] = table["err_u"]
    fits = slopes(table, ("u",))
    assert fits["u"]["window"] == pytest.approx(1.0, abs=1e-12)
    assert fits["u"]["all"] > 1.1
    assert fits["total"] == fits["u"]


@pytest.fixture
def stub_study(paper_case, stub_layout):
    lines: list[str] = []
    scene = load_scene(paper_case)
    study = run_study(scene, (16, 2, 8, 4), stub_layout, jobs=2, progress=lines.append)
    return study, lines


def test_a_study_has_one_row_per_level_and_the_reference_has_no_error(stub_study):
    study, _ = stub_study
    table = study.table
    assert table["n"].tolist() == [2, 4, 8, 16] and study.reference == 16
    assert table["h"].tolist() == [0.5, 0.25, 0.125, 0.0625]
    assert table.iloc[-1][["err_u", "err_phi", "err_theta", "err_total"]].isna().all()
    graded = table.iloc[:-1]
    assert (graded[["err_u", "err_phi", "err_theta"]] > 0).all().all()
    np.testing.assert_allclose(graded["err_total"], graded[["err_u", "err_phi", "err_theta"]].sum(axis=1))
    assert table["dofs"].tolist() == [4 * (4 * n + 1) * (n + 1) for n in (2, 4, 8, 16)]


def test_smooth_interpolants_converge_at_about_rate_one(stub_study):
    """The stub writes P1 interpolants of smooth fields: their energy-norm distance to a
    finer interpolant is O(h), with a pre-asymptotic drift of a few percent at h = 1/2."""
    study, _ = stub_study
    for name in ("u", "phi", "theta", "total"):
        assert 0.9 < study.slopes[name]["all"] < 1.2
        assert 0.9 < study.slopes[name]["window"] < 1.2


def test_progress_is_one_line_per_level(stub_study):
    _, lines = stub_study
    assert len(lines) == 4
    assert all(line.startswith(f"[{k}/4] n=") and "Newton its" in line for k, line in enumerate(lines, 1))


def test_a_second_study_reuses_every_run_and_force_reruns(stub_study, stub_layout):
    study, _ = stub_study
    lines: list[str] = []
    again = run_study(study.scene, (2, 4, 8, 16), stub_layout, jobs=2, progress=lines.append)
    assert all(run.reused for run in again.runs.values()) and all("reused" in line for line in lines)
    pd.testing.assert_frame_equal(again.table, study.table)
    forced = run_study(study.scene, (2, 4), stub_layout, jobs=1, force=True, progress=lines.append)
    assert not any(run.reused for run in forced.runs.values())


def test_a_changed_scene_value_is_a_cache_miss(stub_study, paper_case, stub_layout):
    """stub_study has filled the cache; a different contact.S must not hit it."""
    scene = load_scene(paper_case, ["contact.S=0"])
    again = run_study(scene, (2, 4), stub_layout, jobs=1, progress=lambda line: None)
    assert not any(run.reused for run in again.runs.values())


def test_the_report_writes_csv_json_and_png(stub_study, stub_layout):
    study, _ = stub_study
    paths = write_report(study, stub_layout)
    csv = pd.read_csv(paths["csv"])
    for column in ("n", "h", "dofs", "newton_iterations", "wall_s", "err_u", "err_phi", "err_theta",
                   "err_total", "order_total"):
        assert column in csv.columns
    summary = json.loads(paths["summary"].read_text(), parse_constant=lambda c: pytest.fail(c))
    assert summary["verdict"] == "pass" and summary["slope_band"] == [0.8, 1.3]
    assert summary["reference_n"] == 16 and set(summary["runs"]) == {"2", "4", "8", "16"}
    assert summary["scene"]["electric_contact"]["L"] == "inf"
    assert set(summary["tools"]) >= {"freefem", "gmsh", "meshio", "numpy", "python"}
    assert paths["plot"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_failing_report_leaves_the_previous_baseline_whole(stub_study, stub_layout, monkeypatch):
    study, _ = stub_study
    paths = write_report(study, stub_layout)
    before = {kind: path.read_bytes() for kind, path in paths.items()}

    def broken_plot(*args):
        raise RuntimeError("disk full")

    monkeypatch.setattr(harness.report.report, "plot_convergence", broken_plot)
    with pytest.raises(RuntimeError):
        write_report(study, stub_layout)
    assert {kind: path.read_bytes() for kind, path in paths.items()} == before
    assert not [p for p in paths["csv"].parent.iterdir() if p.name.startswith(".")]
