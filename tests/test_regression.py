"""(e) Slope regression that can fail: a fast study (h = 1/2 ... 1/16 against h = 1/32) must
reproduce the committed baseline tests/gold/paper_fast/ per field: the least-squares slope,
its standard error (the shape of the error curve), and the error level at h = 1/8 (the
error constant: a right slope with a wrong constant fails too). Regenerate the baseline
with `make baseline` only for an intended change of the scheme."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pandas as pd

from harness.cli import main
from harness.measure.rates import SlopeFit, slope_fit

ROOT = Path(__file__).parents[1]
BASELINE = ROOT / "tests" / "gold" / "paper_fast"  # `make baseline` refreshes it
FIELDS = ("u", "phi", "theta", "total")
LEVEL_N = 8
# The study is deterministic up to Newton's stopping test (relative increments 1e-9 after
# quadratic convergence) and the LU's round-off: slopes, standard errors and levels agree
# to ~1e-8. The bands leave room for another sparse solver or BLAS; a wrong sign in a
# coupling term or a 20 % change of a material constant moves them far more (the mutation
# tests below).
SLOPE_TOL = 0.01    # absolute, on the least-squares slope over all non-reference levels
STDERR_TOL = 0.01   # absolute, on that slope's standard error
LEVEL_TOL = 0.01    # relative, on the error at h = 1/8


def fast_study(results: Path, freefem: Path = ROOT / "freefem") -> Path:
    argv = ["convergence", str(ROOT / "cases" / "paper.toml"), "--levels", "2,4,8,16,32",
            "--set", "scene.name=paper_fast", "--results", str(results), "--freefem", str(freefem)]
    # Exit 1 only says the fast study's slope is outside the full study's band: not our check.
    assert main(argv) in (0, 1)
    return results / "paper_fast"


def fits(study: Path) -> tuple[dict[str, SlopeFit], pd.Series]:
    """Per field, the slope fit over the levels with an error, and the errors at h = 1/8."""
    table = pd.read_csv(study / "convergence.csv")
    graded = table[table["err_total"].notna()]
    return ({f: slope_fit(graded["h"], graded[f"err_{f}"]) for f in FIELDS},
            table.set_index("n").loc[LEVEL_N])


def mismatches(study: Path, baseline: Path = BASELINE) -> list[str]:
    (got, got_err), (want, want_err) = fits(study), fits(baseline)
    found = []
    for field in FIELDS:
        g, w = got[field], want[field]
        if abs(g.slope - w.slope) > SLOPE_TOL:
            found.append(f"slope {field}: {g.slope:.4f} ± {g.stderr:.4f} vs baseline {w.slope:.4f} ± {w.stderr:.4f}")
        if abs(g.stderr - w.stderr) > STDERR_TOL:
            found.append(f"slope stderr {field}: {g.stderr:.4f} vs baseline {w.stderr:.4f}")
        column = f"err_{field}"
        if abs(got_err[column] / want_err[column] - 1) > LEVEL_TOL:
            found.append(f"{column} at h=1/{LEVEL_N}: {got_err[column]:.4e} vs baseline {want_err[column]:.4e}")
    return found


def edited_baseline(tmp_path: Path, change) -> Path:
    """A copy of the baseline's table with every error column passed through change(h, e)."""
    copy = tmp_path / "edited"
    copy.mkdir()
    table = pd.read_csv(BASELINE / "convergence.csv")
    for field in FIELDS:
        table[f"err_{field}"] = change(table["h"], table[f"err_{field}"])
    table.to_csv(copy / "convergence.csv", index=False)
    return copy


def test_the_baseline_has_what_the_check_needs():
    fitted, at_level = fits(BASELINE)
    for field in FIELDS:
        assert 0.5 < fitted[field].slope < 2 and 0 <= fitted[field].stderr < 0.5
        assert at_level[f"err_{field}"] > 0


def test_a_changed_error_constant_fails_even_with_the_same_slope(tmp_path):
    """Errors 5 % larger at every level: slope and standard error unchanged to round-off,
    only the error level tells."""
    found = mismatches(edited_baseline(tmp_path, lambda h, e: 1.05 * e))
    assert found and all("at h=1/8" in line for line in found), found


def test_a_changed_slope_fails(tmp_path):
    found = mismatches(edited_baseline(tmp_path, lambda h, e: e * (h / h.iloc[0]) ** 0.05))
    assert any(line.startswith("slope ") for line in found), found


def test_a_bent_error_curve_fails_on_the_standard_error(tmp_path):
    """Same end points, a kink in the middle: the fit's standard error grows."""
    found = mismatches(edited_baseline(tmp_path, lambda h, e: e * (1 + 0.3 * (h == 0.25))))
    assert any(line.startswith("slope stderr") for line in found), found


def test_the_unedited_baseline_matches_itself():
    assert mismatches(BASELINE) == []


def test_fast_study_reproduces_the_committed_baseline(tmp_path):
    assert mismatches(fast_study(tmp_path)) == []


# Ways to flip the sign of the shear piezoelectric term of D1 (e15 gamma13, paper 2.2) in
# the successive layouts of freefem/constitutive.idp.
SIGN_FLIPS = [
    ("macro DU1(u1, u2) (e15 * gam13(u1, u2))", "macro DU1(u1, u2) (-e15 * gam13(u1, u2))"),
    ("(e15 * gam13(u1, u2) - b11", "(-e15 * gam13(u1, u2) - b11"),
    ("macro DU1(u) (e15 * eps5(u))", "macro DU1(u) (-e15 * eps5(u))"),
    ("macro DU1(u) (mat(e15) * eps5(u)", "macro DU1(u) (-mat(e15) * eps5(u)"),
]


def test_regression_check_catches_a_wrong_sign(tmp_path):
    """Mutation: flip the sign of the shear piezoelectric term of D1 (e15 gamma13, paper 2.2),
    a sign error that still converges; the check must report it. (Flipping all of E eps(u)
    in D makes Newton fail, which the study reports by itself.)"""
    scripts = tmp_path / "freefem"
    shutil.copytree(ROOT / "freefem", scripts)
    law = scripts / "constitutive.idp"
    text = law.read_text()
    old, new = next(((o, n) for o, n in SIGN_FLIPS if o in text), (None, None))
    assert old is not None, "no known spelling of the e15 term in constitutive.idp: update SIGN_FLIPS"
    law.write_text(text.replace(old, new, 1))
    assert mismatches(fast_study(tmp_path / "results", scripts)) != []


def test_regression_check_catches_a_perturbed_material_constant_by_the_error_level(tmp_path):
    """Mutation: e33 (the main piezoelectric constant) 20 % larger, set after the plane-strain
    reduction (or in the material file itself where there is none). The solution changes
    size more than shape, so the error level at h = 1/8 must be what catches it."""
    scripts = tmp_path / "freefem"
    shutil.copytree(ROOT / "freefem", scripts)
    last = scripts / "material.idp"
    if not last.is_file():
        last = scripts / "materials" / "BaTiO3.idp"
    text = last.read_text()
    assert re.search(r"\be33\b", text), f"{last} defines no e33"
    last.write_text(text + "\ne33 = 1.2 * e33;  // mutation (tests/test_regression.py)\n")
    found = mismatches(fast_study(tmp_path / "results", scripts))
    assert any(f"at h=1/{LEVEL_N}" in line for line in found), found
