"""A study writes where its user stands: `--results` defaults to ./results under the working
directory, whichever checkout the harness runs from, and the study's first line names the
harness and that folder (stand-in solver of tests/data/stub_freefem)."""

from __future__ import annotations

import shutil
from pathlib import Path

from harness.cli import main
from harness.core.layout import REPO

STUB = Path(__file__).parent / "data" / "stub_freefem"


def test_a_study_run_from_another_directory_writes_only_there(capsys, monkeypatch, tmp_path, paper_case):
    name = "results_location_probe"  # a scene name no committed result uses
    stray = REPO / "results" / name
    here = tmp_path / "elsewhere"
    here.mkdir()
    monkeypatch.chdir(here)
    try:
        code = main(["convergence", str(paper_case), "--levels", "2,4,8", "--jobs", "1", "--freefem", str(STUB),
                     "--set", f"scene.name={name}", "--set", "loads.traction_y=-12.5"])
        out = capsys.readouterr().out.splitlines()
        assert not stray.exists(), f"the study wrote into the checkout's {stray}"
    finally:
        shutil.rmtree(stray, ignore_errors=True)
    assert code == 0
    assert sorted(p.name for p in here.iterdir()) == ["results"]
    assert (here / "results" / name / "convergence.csv").is_file()
    assert out[0] == f"harness {REPO / 'harness'}; results in {here.resolve() / 'results'}"
