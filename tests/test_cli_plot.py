"""`python -m harness plot RESULTS_DIR [--out PNG]`: the picture of a real run, 2D and 3D,
from a level's directory or a scene's (its finest level); a directory with no run, or a
view the run cannot have, is one line and exit code 2."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import imread

from harness.cli import main
from harness.core.contract import ExitCode

CASES = Path(__file__).parents[1] / "cases"


def plot(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(["plot", *argv])
    out, err = capsys.readouterr()
    return code, out, err


def drawn(path: Path, size: tuple[int, int]) -> None:
    """A picture of the figure's size with contour fills in it: many colours, not a blank page."""
    image = imread(path)
    assert image.shape[:2] == size
    colours = np.unique((image[..., :3] * 255).astype(np.uint8).reshape(-1, 3), axis=0)
    assert len(colours) > 100, len(colours)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """A 2D device and a 3D box, each solved at its coarsest level."""
    root = tmp_path_factory.mktemp("plot")
    for case, n in (("strip_actuator", 2), ("paper3d", 2)):
        assert main(["solve", str(CASES / f"{case}.toml"), "--n", str(n), "--results", str(root),
                         "--set", 'scene.initial_guess="zero"']) == 0
    return root


def test_a_2d_device_from_its_scenes_directory(capsys, runs, tmp_path):
    out = tmp_path / "strip.png"
    code, text, err = plot(capsys, str(runs / "strip_actuator"), "--out", str(out))
    assert code == 0, err
    assert text.strip() == f"wrote {out}"
    drawn(out, (750, 1100))  # figsize 11 x 7.5 in at 100 dpi (harness/report/device_plot.py)


def test_a_3d_run_in_both_views_beside_its_levels_by_default(capsys, runs, tmp_path):
    code, _, err = plot(capsys, str(runs / "paper3d" / "n2"))
    assert code == 0, err
    drawn(runs / "paper3d" / "fields.png", (750, 1100))
    out = tmp_path / "section.png"
    code, _, err = plot(capsys, str(runs / "paper3d" / "n2"), "--view", "section", "--out", str(out),
                        "--case", str(CASES / "paper3d.toml"))
    assert code == 0, err
    drawn(out, (715, 1210))  # figsize 11 x 6.5 in at 110 dpi (harness/report/plot3d.py)


def test_a_directory_without_a_run_is_one_line(capsys, tmp_path):
    code, _, err = plot(capsys, str(tmp_path))
    assert code == ExitCode.INPUT
    [line] = err.strip().splitlines()
    assert line.startswith("error: ") and "solution.vtu" in line


def test_a_section_of_a_2d_run_is_one_line(capsys, runs, tmp_path):
    code, _, err = plot(capsys, str(runs / "strip_actuator" / "n2"), "--view", "section", "--out", str(tmp_path / "x.png"))
    assert code == ExitCode.INPUT
    [line] = err.strip().splitlines()
    assert "3D" in line and not (tmp_path / "x.png").exists()
