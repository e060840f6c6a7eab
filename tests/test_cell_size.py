"""Real lengths: each level's largest cell h_max (model units) beside n in convergence.csv,
summary.json and the plot's ticks, and a warning for a level with fewer than two cells through
a body's thinnest section (stand-in solver of tests/data/stub_freefem)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from harness.scene.cell_size import Body, cells_through, h_max
from harness.cli import main

STUB = Path(__file__).parent / "data" / "stub_freefem"


def study(capsys, tmp_path: Path, case: Path, *overrides: str) -> tuple[int, list[str], Path]:
    code = main(["convergence", str(case), "--levels", "2,4,8", "--jobs", "1", "--results", str(tmp_path),
                 "--freefem", str(STUB), "--set", "loads.traction_y=-12.5",
                 *[arg for o in overrides for arg in ("--set", o)]])
    return code, capsys.readouterr().err.splitlines(), tmp_path / "paper"


def test_each_level_reports_its_largest_cell_beside_n(capsys, tmp_path, paper_case):
    code, err, out = study(capsys, tmp_path, paper_case)
    assert code == 0, err
    table = pd.read_csv(out / "convergence.csv")
    assert list(table.columns[:3]) == ["n", "h", "h_max"]
    assert list(table["h"]) == [0.5, 0.25, 0.125]  # the existing column keeps its values
    # Right triangles of legs 1/n: the diagonal; 1e-7, solution.vtu's single-precision points.
    assert table["h_max"].to_numpy() == pytest.approx(math.sqrt(2) / table["n"].to_numpy(), rel=1e-7)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["h_max"] == pytest.approx(list(table["h_max"]), rel=1e-9)  # the CSV's 10 digits
    assert summary["warnings"] == [] and not [line for line in err if line.startswith("warning: level")]


def test_a_level_with_one_cell_through_the_thickness_is_named_in_a_warning(capsys, tmp_path, paper_case):
    # A 4 x 0.5 body: n = 2 has one cell through the thickness, n = 4 two, n = 8 four.
    code, err, out = study(capsys, tmp_path, paper_case, "geometry.height=0.5")
    assert code == 0, err
    warned = [line for line in err if line.startswith("warning: level")]
    assert [line.split(":")[1].strip() for line in warned] == ["level n=2"], err
    assert "1.0 cell(s) through the thinnest section of the rectangle (0.5 along y" in warned[0], warned
    assert json.loads((out / "summary.json").read_text())["warnings"] == [w.removeprefix("warning: ") for w in warned]


def test_cells_through_a_layered_strip_count_its_layers():
    # A 10 x 1 strip of k layers of right triangles (legs 1/k): k cells through, h_max the diagonal.
    for k in (1, 2, 3):
        xs, ys = np.meshgrid(np.linspace(0, 10, 10 * k + 1), np.linspace(0, 1, k + 1))
        points = np.column_stack([xs.ravel(), ys.ravel()])
        cols = 10 * k + 1
        cells = []
        for j in range(k):
            for i in range(10 * k):
                a, b, c, d = j * cols + i, j * cols + i + 1, (j + 1) * cols + i, (j + 1) * cols + i + 1
                cells += [(a, b, d), (a, d, c)]
        count, axis, thickness = cells_through(points, np.array(cells), Body("strip", (0.0, 0.0), (10.0, 1.0)))
        assert (count, axis, thickness) == (pytest.approx(k), 1, 1.0)
        assert h_max(points, np.array(cells)) == pytest.approx(math.sqrt(2) / k)


def test_solve_warns_of_a_level_with_one_cell_through_the_thickness(capsys, tmp_path, paper_case):
    code = main(["solve", str(paper_case), "--n", "2", "--results", str(tmp_path), "--freefem", str(STUB),
                 "--set", "loads.traction_y=-12.5", "--set", "geometry.height=0.5"])
    err = capsys.readouterr().err.splitlines()
    assert code == 0, err
    assert [line for line in err if line.startswith("warning: level n=2: 1.0 cell(s) through the thinnest section "
                                                   "of the rectangle")], err


def test_a_gmsh_part_drawn_in_pieces_is_one_part():
    """The cantilever is three surfaces of one physical surface: its thinnest section is the
    20 x 1 mm part's 1 mm, not the 0.5 mm width of its margin piece."""
    from harness.core.layout import REPO
    from harness.scene.scene import load_scene

    [part] = load_scene(REPO / "cases" / "cantilever.toml").geometry.body_parts()
    assert part.name == "cantilever.geo: physical surface 'PZT-5H'"
    assert part.lo == pytest.approx((0.0, 0.0), abs=1e-9) and part.hi == pytest.approx((0.02, 0.001), rel=1e-9)
