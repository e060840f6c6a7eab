"""(e) Slope regression: a fast study (h = 1/2 ... 1/16 against h = 1/32) must reproduce the
committed baseline results/paper_fast/ per field, both the fitted slope and the error level.
Regenerate the baseline with `make baseline` only for an intended change of the scheme."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pandas as pd

from harness.cli import main

ROOT = Path(__file__).parents[1]
BASELINE = ROOT / "results" / "paper_fast"
FIELDS = ("u", "phi", "theta", "total")
# The study is deterministic up to Newton's stopping test (relative increments 1e-9 after
# quadratic convergence) and the LU's round-off: slopes and levels agree to ~1e-8. The bands
# leave room for another sparse solver or BLAS; a wrong sign in a coupling term moves them
# far more (test_regression_check_catches_a_wrong_sign).
SLOPE_TOL = 0.01   # absolute, on the least-squares slope over all levels
LEVEL_TOL = 0.01   # relative, on the error at h = 1/8 (a right slope with a wrong constant)


def fast_study(results: Path, freefem: Path = ROOT / "freefem") -> Path:
    argv = ["convergence", str(ROOT / "cases" / "paper.toml"), "--levels", "2,4,8,16,32",
            "--set", "scene.name=paper_fast", "--results", str(results), "--freefem", str(freefem)]
    # Exit 1 only says the fast study's slope is outside the full study's band: not our check.
    assert main(argv) in (0, 1)
    return results / "paper_fast"


def mismatches(study: Path, baseline: Path = BASELINE) -> list[str]:
    got = json.loads((study / "summary.json").read_text())["slopes"]
    want = json.loads((baseline / "summary.json").read_text())["slopes"]
    got_err = pd.read_csv(study / "convergence.csv").set_index("n").loc[8]
    want_err = pd.read_csv(baseline / "convergence.csv").set_index("n").loc[8]
    found = []
    for field in FIELDS:
        if abs(got[field]["all"] - want[field]["all"]) > SLOPE_TOL:
            found.append(f"slope {field}: {got[field]['all']:.4f} vs baseline {want[field]['all']:.4f}")
        column = f"err_{field}"
        if abs(got_err[column] / want_err[column] - 1) > LEVEL_TOL:
            found.append(f"{column} at h=1/8: {got_err[column]:.4e} vs baseline {want_err[column]:.4e}")
    return found


def test_fast_study_reproduces_the_committed_baseline(tmp_path):
    assert mismatches(fast_study(tmp_path)) == []


def test_regression_check_catches_a_wrong_sign(tmp_path):
    """Mutation: flip the sign of the shear piezoelectric term of D1 (e15 gamma13, paper 2.2),
    a sign error that still converges; the check must report it. (Flipping all of E eps(u)
    in D makes Newton fail, which the study reports by itself.)"""
    scripts = tmp_path / "freefem"
    shutil.copytree(ROOT / "freefem", scripts)
    law = scripts / "constitutive.idp"
    text = law.read_text()
    mutated = text.replace("(e15 * gam13(u1, u2) - b11", "(-e15 * gam13(u1, u2) - b11")
    assert mutated != text
    law.write_text(mutated)
    assert mismatches(fast_study(tmp_path / "results", scripts)) != []
