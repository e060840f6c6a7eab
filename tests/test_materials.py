"""Materials (issue 7): each file in freefem/materials/ is a full 3D set that runs the paper's
scene; freefem/material.idp derives the plane-strain constants from it and stops a bad set
before the solve with one line naming the material, the tensor and the offending value;
a copy of the template is picked up by name."""

from __future__ import annotations

import os
import re
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest

from harness.cli import main
from harness.measure.checks import EPS, NOTHING_FLOWS, floors
from harness.measure.fields import read_fields, read_state
from harness.run.record import RunRecord, read_run_json
from harness.core.freefem import command, invoke

ROOT = Path(__file__).parents[1]
FREEFEM = ROOT / "freefem"
PAPER = ROOT / "tests" / "data" / "paper.toml"
TEMPLATE = FREEFEM / "materials" / "TEMPLATE.idp.txt"
MATERIALS = sorted(p.stem for p in (FREEFEM / "materials").glob("*.idp"))
INVALID_MATERIAL = 14  # material.idp's exit code (harness/core/freefem.py EXIT_REASONS)

# Ouafik (2019) section 4.2, as the scheme used them before materials carried 3D sets.
PAPER_BATIO3 = dict(
    f11=166e9, f13=78e9, f33=162e9, f44=43e9, e31=-4.4, e33=18.6, e15=11.6,
    b11=11.2e-9, b33=12.6e-9, m11=2.24e6, m33=1.89e6, p1=0.0, p3=-1e-4, k11=50.0, k33=75.0,
)


def reduce(material: Path, tmp: Path) -> tuple[int, str, dict[str, float]]:
    """Run material.idp alone on a material file: exit code, output, the 2D constants."""
    script = tmp / "reduce.edp"
    prints = "".join(f'cout << "{name} " << {name} << endl;\n' for name in PAPER_BATIO3)
    script.write_text(f'include "{material.resolve()}"\ninclude "{(FREEFEM / "material.idp").resolve()}"\n'
                      f"cout.precision(17);\n{prints}")
    outcome = invoke(command(script, []), tmp, timeout_s=60)
    out = (tmp / "stdout.txt").read_text() + (tmp / "stderr.txt").read_text()
    printed = dict(line.split(" ", 1) for line in out.splitlines() if line.split(" ")[0] in PAPER_BATIO3)
    return outcome.returncode, out, {name: float(value) for name, value in printed.items()}


def solve(tmp: Path, material: str, freefem: Path = FREEFEM) -> tuple[int, Path]:
    """`python -m harness solve` of the paper's scene at n = 4 with `material`: exit code, run dir."""
    name = f"paper-{material}"
    code = main(["solve", str(PAPER), "--n", "4", "--results", str(tmp), "--freefem", str(freefem),
                 "--set", f"scene.material={material}", "--set", f"scene.name={name}"])
    return code, tmp / name / "n4"


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """run.json of each repository material on the paper's scene, solved once per module."""
    results = tmp_path_factory.mktemp("materials")
    cache: dict[str, dict] = {}

    def record(material: str) -> RunRecord:
        if material not in cache:
            code, directory = solve(results, material)
            assert code == 0, f"{material}: the paper's scene failed (see {directory}.failed)"
            cache[material] = read_run_json(directory)
        return cache[material]

    return record


def freefem_copy(tmp: Path) -> Path:
    """A private copy of freefem/, so a test can add materials the way a user would."""
    tree = tmp / "freefem"
    shutil.copytree(FREEFEM, tree)
    return tree


def variant(tmp: Path, name: str, *edits: tuple[str, str], drop: str = "") -> Path:
    """BaTiO3.idp under another name, with text replacements and optionally one macro removed."""
    text = (FREEFEM / "materials" / "BaTiO3.idp").read_text().replace('"BaTiO3"', f'"{name}"')
    for old, new in edits:
        assert old in text, old
        text = text.replace(old, new)
    if drop:
        text = re.sub(rf"^macro {drop} .*?//\n", "", text, flags=re.MULTILINE | re.DOTALL)
        assert f"macro {drop} " not in text
    path = tmp / f"{name}.idp"
    path.write_text(text)
    return path


def test_the_library_has_batio3_and_at_least_three_more():
    assert "BaTiO3" in MATERIALS and len(MATERIALS) >= 4, MATERIALS


def test_batio3_reduces_exactly_to_the_papers_constants(tmp_path):
    # Exact: the plane-strain reduction only picks entries of the 3D set, no arithmetic.
    code, out, constants = reduce(FREEFEM / "materials" / "BaTiO3.idp", tmp_path)
    assert code == 0, out
    assert constants == PAPER_BATIO3


@pytest.mark.parametrize("material", MATERIALS)
def test_every_material_passes_the_checks(material, tmp_path):
    code, out, constants = reduce(FREEFEM / "materials" / f"{material}.idp", tmp_path)
    assert code == 0, out
    assert set(constants) == set(PAPER_BATIO3)


@pytest.mark.parametrize("material", MATERIALS)
def test_every_material_runs_the_papers_scene_and_converges(material, runs):
    record = runs(material)
    assert record.converged is True
    assert record.material == material  # materialName matches the file name


@pytest.mark.parametrize("material", [m for m in MATERIALS if m != "BaTiO3"])
def test_changing_the_material_changes_the_solution(material, runs):
    # 1 %: the materials' moduli differ by tens of per cent, round-off by 1e-12.
    paper, other = runs("BaTiO3"), runs(material)
    changes = [abs(getattr(other, k) / getattr(paper, k) - 1) for k in ("max_abs_u", "min_phi")]
    assert max(changes) > 0.01, changes


BAD_MATERIALS = {
    "not positive definite": (
        [("[77e9, 166e9, 78e9,", "[170e9, 166e9, 78e9,"), ("[[166e9, 77e9,", "[[166e9, 170e9,")], "",
        "elasticity C is not positive definite (Cholesky pivot 2 of 6 = "),
    "missing constant": ([], "materialK", "conductivity k is missing (define macro materialK"),
    "not symmetric": ([("[[166e9, 77e9,", "[[166e9, 76e9,")], "", "elasticity C is not symmetric (C12 = 7.6e+10, C21 = 7.7e+10)"),
    "GPa for Pa": ([("[0, 0, 0, 0, 0, 44.5e9]", "[0, 0, 0, 0, 0, 44.5]")], "",
                   "elasticity C is implausible, expected 1e+08 to 1e+13 Pa on the diagonal (C66 = 44.5)"),
    "relative permittivity": ([("[0, 0, 12.6e-9]", "[0, 0, 1260]")], "", "permittivity beta is implausible"),
    "wrong shape": ([("[0, 0, -1e-4]", "[0, -1e-4]")], "", "pyroelectric p must have 3 entries (it has 2)"),
    "negative conductivity": ([("[0, 0, 75]]", "[0, 0, -75]]")], "", "conductivity k is implausible"),
    "in-plane shear coupling": (
        [("[0, 0, 0, 0, 43e9, 0],", "[1e9, 0, 0, 0, 43e9, 0],"), ("[[166e9, 77e9, 78e9, 0, 0, 0]", "[[166e9, 77e9, 78e9, 0, 1e9, 0]")],
        "", "elasticity C has an in-plane coupling the plane-strain scheme does not model (C15 = 1e+09)"),
    "m and alpha both": ([("macro materialP", "macro materialAlpha [1e-5, 1e-5, 1e-5, 0, 0, 0] //\nmacro materialP")], "",
                         "stress-temperature m is given twice"),
}


@pytest.mark.parametrize("case", BAD_MATERIALS)
def test_a_bad_material_is_one_line_naming_material_tensor_and_value(case, tmp_path):
    edits, drop, message = BAD_MATERIALS[case]
    code, out, _ = reduce(variant(tmp_path, "Bad", *edits, drop=drop), tmp_path)
    assert code == INVALID_MATERIAL, out
    errors = [line for line in out.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and errors[0].startswith("error: material Bad: " + message), out


@pytest.mark.parametrize("case", ["not positive definite", "missing constant"])
def test_the_harness_stops_a_bad_material_before_solving(case, tmp_path, capsys):
    tree = freefem_copy(tmp_path)
    edits, drop, message = BAD_MATERIALS[case]
    variant(tree / "materials", "Bad", *edits, drop=drop)
    code, directory = solve(tmp_path / "results", "Bad", tree)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2  # bad input, refused before FreeFEM solves (it was 3, a failed run)
    # The line names the file now (it read "... invalid material: error: material Bad: ...").
    assert len(err) == 1 and "invalid material" in err[0] and "material Bad: " + message in err[0], err
    assert str(tree / "materials" / "Bad.idp") in err[0], err
    failed = directory.with_name("n4.failed")
    assert not (failed / "run.json").exists() and not (failed / "solution.vtu").exists()
    assert not (tmp_path / "results").exists()  # refused before anything was meshed


def case_with_material(tmp: Path, material: str) -> Path:
    """The paper's case in `tmp`, its scene.material set to `material` as a user writes it."""
    text = PAPER.read_text().replace('material = "BaTiO3"', f'material = "{material}"')
    assert f'material = "{material}"' in text
    case = tmp / "case.toml"
    case.write_text(text)
    return case


def test_a_material_file_outside_the_library_is_read_from_its_path(tmp_path, capsys):
    (tmp_path / "mine").mkdir()
    variant(tmp_path / "mine", "MyOwn", ("[0, 0, 0, 0, 43e9, 0],", "[0, 0, 0, 0, 40e9, 0],"))
    case = case_with_material(tmp_path, "mine/MyOwn.idp")  # relative to the case file, as a .geo
    code = main(["solve", str(case), "--n", "4", "--results", str(tmp_path / "results")])
    assert code == 0, capsys.readouterr().err
    record = read_run_json(tmp_path / "results" / "paper" / "n4")
    assert record.material == "MyOwn" and record.converged is True


def test_a_material_name_that_differs_from_its_file_is_refused(tmp_path, capsys):
    path = variant(tmp_path, "MyOwn")
    path.rename(tmp_path / "Other.idp")
    code = main(["solve", str(case_with_material(tmp_path, "Other.idp")), "--n", "4",
                 "--results", str(tmp_path / "results")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and str(tmp_path / "Other.idp") in err[0] and "'MyOwn'" in err[0] and "'Other'" in err[0], err
    assert not (tmp_path / "results").exists()


# Data FreeFEM cannot read or that material.idp refuses: each ends with exit 2 and one line
# naming the file and the entry, before anything is meshed or solved.
BAD_DATA = {
    "nan": ([("[[166e9, 77e9,", "[[nan, 77e9,")], "", "materialC entry C11 = nan is not a finite number"),
    "overflow": ([("[[166e9, 77e9,", "[[1e999, 77e9,")], "", "materialC entry C11 = 1e999 is not a finite number"),
    "negative": ([("[[166e9, 77e9,", "[[-166e9, 77e9,")], "", "(C11 = -1.66e+11)"),
    "missing": ([], "materialK", "conductivity k is missing (define macro materialK"),
}


@pytest.mark.parametrize("case", BAD_DATA)
def test_invalid_material_data_is_bad_input_named_before_anything_runs(case, tmp_path, capsys):
    edits, drop, message = BAD_DATA[case]
    path = variant(tmp_path, "Bad", *edits, drop=drop)
    code = main(["solve", str(case_with_material(tmp_path, "Bad.idp")), "--n", "4",
                 "--results", str(tmp_path / "results")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and err[0].startswith(f"error: invalid material file {path}: ") and message in err[0], err
    assert not (tmp_path / "results").exists()


def test_thermal_expansion_gives_m_equal_to_c_alpha(tmp_path):
    a1, a3 = 4e-6, 2e-6  # [1/K]
    material = variant(tmp_path, "Expanding", ("macro materialM [2.24e6, 2.24e6, 1.89e6, 0, 0, 0] //",
                                               f"macro materialAlpha [{a1}, {a1}, {a3}, 0, 0, 0] //"))
    code, out, c = reduce(material, tmp_path)
    assert code == 0, out
    # m = C alpha in Voigt form; C12 = 77 GPa is BaTiO3's. 1e-14: three products summed.
    assert c["m11"] == pytest.approx((c["f11"] + 77e9) * a1 + c["f13"] * a3, rel=1e-14)
    assert c["m33"] == pytest.approx(2 * c["f13"] * a1 + c["f33"] * a3, rel=1e-14)


def test_a_copy_of_the_template_is_picked_up_by_name(tmp_path, capsys):
    tree = freefem_copy(tmp_path)
    # What README.md tells a user: copy, name it, replace values.
    text = TEMPLATE.read_text().replace('"MyMaterial"', '"MyCeramic"').replace("[78e9, 78e9, 162e9,", "[78e9, 78e9, 150e9,")
    (tree / "materials" / "MyCeramic.idp").write_text(text)
    code, directory = solve(tmp_path / "results", "MyCeramic", tree)
    assert code == 0, capsys.readouterr().err
    record = read_run_json(directory)
    assert record.material == "MyCeramic" and record.converged is True


def test_the_template_is_not_a_material():
    assert "TEMPLATE" not in MATERIALS and TEMPLATE.is_file()


def test_an_unknown_material_lists_the_available_ones(tmp_path, capsys):
    code, _ = solve(tmp_path, "Unobtainium")
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert "unknown material 'Unobtainium'" in err[0] and "available: " + ", ".join(MATERIALS) in err[0], err


# freefem/materials/Alumina.idp: relative permittivity 8.7 (MakeItFrom.com), eps0 = 8.8541878e-12 F/m.
ALUMINA_BETA = 7.703143e-11  # [C/(V m)]
LAYER = ROOT / "tests" / "data" / "layer.toml"


@pytest.mark.parametrize("n", [2, 4])
def test_an_alumina_layer_is_the_parallel_plate_capacitor(n, tmp_path):
    # tests/data/layer.toml (width 2, thickness 1, 100 V above, earthed below) in alumina: with
    # e = 0 nothing couples phi to u, so phi = V y / t, u = 0, and the electrode's free charge
    # per unit depth is the parallel plate's beta V w / t. Linear in P1 and exact: only
    # round-off is left (1e-10 as the PZT-5H layer's test, tests/test_electrodes.py).
    name = f"alumina-layer-{n}"
    code = main(["solve", str(LAYER), "--n", str(n), "--results", str(tmp_path),
                 "--set", "scene.material=Alumina", "--set", f"scene.name={name}"])
    assert code == 0
    record = read_run_json(tmp_path / name / f"n{n}")
    u, phi, theta = read_state(tmp_path / name / f"n{n}" / "state.txt")
    y = np.round(read_fields(tmp_path / name / f"n{n}" / "solution.vtu").points[:, 1] * n) / n
    assert phi == pytest.approx(100.0 * y, abs=1e-10 * 100.0)
    assert np.abs(u).max() == 0.0 and np.abs(theta).max() == 0.0  # nothing drives them: exact zeros
    assert record.checks["electrode_charge"] == pytest.approx(ALUMINA_BETA * 100.0 * 2.0 / 1.0, rel=1e-10)


def test_alumina_on_the_papers_foundation_balances_its_charge_to_the_resolution_of_phi(tmp_path):
    # n = 8: the level where forming phi - phi_f as Phi (ph - phi_f / Phi) did not help (4.8e-8
    # of the flow; harness/measure/checks.py QUANTA). The contact holds phi within ~1e-8 V of
    # phi_f = -44 V, so the charge balance can only be read to the doubles' resolution of phi
    # there: the imbalance stays below eps int p_e(s) (|phi| + |phi_f|), and every check passes.
    code = main(["solve", str(PAPER), "--n", "8", "--results", str(tmp_path), "--set", "scene.material=Alumina",
                 "--set", "scene.name=paper-Alumina"])
    assert code == 0  # the physical checks passed (a failed check is exit 1)
    checks = read_run_json(tmp_path / "paper-Alumina" / "n8").checks
    flow = abs(checks["charge_out_dirichlet"])
    assert checks["charge_imbalance"] * flow <= EPS * checks["charge_contact_reading"]
    # What makes the floor necessary: the foundation pins phi to phi_f within eps / 1e-8 of the operands.
    assert flow < 2.2e-8 * checks["charge_contact_reading"]


def test_the_contact_reading_sets_the_balance_floors():
    # One eps of the reading, relative to the 1e-8 tolerance; none without a contact reading.
    c = {"charge_contact_reading": 10.0, "heat_contact_reading": 1000.0}
    low = floors(c, 2.0)
    assert low["charge"] == pytest.approx(EPS * 10.0 / 1e-8, rel=1e-15)
    assert low["heat"] == pytest.approx(EPS * 1000.0 / 1e-8, rel=1e-15)
    assert floors({}, 2.0)["charge"] == NOTHING_FLOWS


def alumina_with_beta_in(folder: Path, include: str) -> tuple[Path, Path]:
    """Alumina.idp as Layered.idp in `folder`, its permittivity moved into the file `include`
    names (relative to `folder`, or absolute), which includes the next file down, itself
    holding the value: the material file, and the file that holds beta."""
    text = (FREEFEM / "materials" / "Alumina.idp").read_text().replace('materialName = "Alumina"',
                                                                      'materialName = "Layered"')
    beta = re.search(r"macro materialBeta .*?//", text, re.DOTALL)
    assert beta
    middle = Path(include) if Path(include).is_absolute() else folder / include
    middle.parent.mkdir(parents=True, exist_ok=True)
    # Included by an absolute name: FreeFEM 4.9 looks a relative name up next to its includer
    # only in a file included by an absolute name (harness/scene/materials.py included_files).
    (middle.parent / "beta.idp").write_text(beta.group(0) + "\n")
    middle.write_text(f'// the permittivity, one file down\ninclude "{middle.parent / "beta.idp"}"\n')
    material = folder / "Layered.idp"
    folder.mkdir(parents=True, exist_ok=True)
    material.write_text(text.replace(beta.group(0), f'include "{include}"'))
    return material, middle.parent / "beta.idp"


@pytest.mark.parametrize("include", ["sub/permittivity.idp", "absolute"])
def test_a_file_a_material_includes_is_in_the_runs_key(tmp_path, capsys, include):
    """The alumina capacitor (tests/data/layer.toml) with beta two includes down: doubling beta
    in that file reruns the level (its charge doubles, the parallel plate's beta V w / t), where
    the cache served the old level. Unchanged, the level is reused."""
    given = str(tmp_path / "elsewhere" / "permittivity.idp") if include == "absolute" else include
    material, beta = alumina_with_beta_in(tmp_path / "mine", given)

    def charge() -> tuple[float, bool]:
        code = main(["solve", str(LAYER), "--n", "2", "--results", str(tmp_path / "results"),
                     "--set", f"scene.material={material}", "--set", "scene.name=layered"])
        assert code == 0
        reused = "[reused]" in capsys.readouterr().out
        return read_run_json(tmp_path / "results" / "layered" / "n2").checks["electrode_charge"], reused

    first, reused = charge()
    assert first == pytest.approx(ALUMINA_BETA * 100.0 * 2.0, rel=1e-10) and not reused
    assert charge() == (first, True)
    assert beta.read_text().count("7.703143e-11") == 3
    beta.write_text(beta.read_text().replace("7.703143e-11", "15.406286e-11"))
    second, reused = charge()
    assert not reused
    assert second == pytest.approx(2 * first, rel=1e-10)  # round-off of the linear solve, as above


# A material file that ends FreeFEM, or never ends: FreeFEM reads it when the scene's constants
# are asked for (harness/scene/material_constants.py), before anything is meshed.
RUNAWAY = {
    "exit(0)": ("exit(0);", "ended before it printed the constants, with exit code 0 (does the file call exit?)"),
    "a loop": ("while (1) { int i = 0; }", "timed out after 2 s"),
    "a syntax error": ("real x = ;", "FreeFEM compile error"),
}


@pytest.mark.parametrize("case", RUNAWAY)
def test_a_material_file_that_ends_freefem_or_loops_is_bad_input_named(case, tmp_path, capsys, monkeypatch):
    """One line naming the file, exit 2 (bad input: the file is the user's), and the timeout
    when it loops; nothing meshed, no FreeFEM left running. Before, exit 3 (a failed run) for
    each, without the timeout."""
    from harness.scene import material_constants

    monkeypatch.setattr(material_constants, "READ_TIMEOUT_S", 2.0)  # 60 s in earnest
    scratch = tmp_path / "tmp"  # where FreeFEM runs on the file: this test's own temp dirs
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    line, message = RUNAWAY[case]
    path = variant(tmp_path, "Runaway")
    path.write_text(path.read_text() + f"\n{line}\n")
    code = main(["solve", str(case_with_material(tmp_path, "Runaway.idp")), "--n", "4",
                 "--results", str(tmp_path / "results")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and err[0].startswith(f"error: invalid material file {path}: ") and message in err[0], err
    assert not (tmp_path / "results").exists()
    assert not any(scratch.iterdir())  # its temp dir removed
    assert not [cwd for cwd in process_dirs() if cwd.is_relative_to(scratch)]  # and no FreeFEM left in it


def process_dirs() -> list[Path]:
    """The working directory of every process this user can see."""
    out = []
    for proc in Path("/proc").glob("[0-9]*"):
        try:
            out.append(Path(os.readlink(proc / "cwd")))
        except OSError:  # ended meanwhile, or not ours
            continue
    return out
