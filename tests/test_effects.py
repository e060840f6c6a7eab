"""Effects a scene switches off do not exist in the solve, and switching them off is the
same as zeroing their couplings in the full model (issue 3)."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from harness.cli import main
from harness.run.record import RunRecord, read_run_json
from harness.core.errors import SceneError
from harness.measure.fields import read_fields
from harness.core.layout import REPO
from harness.scene.scene import load_scene

CASES = REPO / "cases"
FULL = ["piezoelectric", "thermal", "pyroelectric", "contact", "friction", "electric_contact", "thermal_contact"]


def uncoupled_freefem(tmp_path: Path, zero: tuple[str, ...]) -> Path:
    """A copy of freefem/ with a material `Uncoupled`: BaTiO3 with the named tensors zeroed."""
    tree = tmp_path / "freefem"
    shutil.copytree(REPO / "freefem", tree)
    text = (tree / "materials" / "BaTiO3.idp").read_text().replace('"BaTiO3"', '"Uncoupled"')
    for macro in zero:
        # Multiply every entry of the macro's array literal by zero, keeping its shape.
        text = re.sub(rf"(macro {macro} )(.*?)( //)", lambda m: m[1] + re.sub(r"-?[\d.]+(e-?\d+)?", "0", m[2]) + m[3],
                      text, flags=re.S)
    (tree / "materials" / "Uncoupled.idp").write_text(text)
    return tree


def run(case: Path, n: int, results: Path, *argv: str) -> tuple[RunRecord, dict[str, np.ndarray]]:
    assert main(["solve", str(case), "--n", str(n), "--results", str(results), *argv]) == 0
    name = next((a.split("=", 1)[1] for a in argv if a.startswith("scene.name=")), load_scene(case).name)
    directory = results / name / f"n{n}"
    record = read_run_json(directory)
    fields = read_fields(directory / "solution.vtu")
    return record, {f: fields.field(f) for f in record.fields}


# (reduced scene, material tensors that vanish with the effects it leaves off, conductance
# that vanishes with them, the initial guess both runs share)
EQUIVALENT = [
    ("elastic", ("materialE", "materialM", "materialP"), ("electric_contact.k_e=0", "thermal_contact.k_c=0"), "zero"),
    ("electroelastic", ("materialM", "materialP"), ("thermal_contact.k_c=0",), "zero"),
    ("thermoelastic", ("materialE", "materialP"), ("electric_contact.k_e=0",), "pressed"),
]


@pytest.mark.parametrize("scene, zero, conductances, guess", EQUIVALENT, ids=[e[0] for e in EQUIVALENT])
def test_a_reduced_scene_equals_the_full_model_with_its_couplings_zeroed(tmp_path, scene, zero, conductances, guess):
    tree = uncoupled_freefem(tmp_path, zero)
    common = ("--freefem", str(tree), "--set", "scene.material=Uncoupled", "--set", f"scene.coarsest_guess={guess}")
    reduced, reduced_fields = run(CASES / f"{scene}.toml", 8, tmp_path / "r", *common)
    full_args = [*common, "--set", "scene.name=full", "--effects", ",".join(FULL)]
    for item in conductances:
        full_args += ["--set", item]
    full, full_fields = run(CASES / "paper.toml", 8, tmp_path / "f", *full_args)
    # The scenes share geometry, loads and contact data with the paper's (asserted, so the
    # comparison is of effects only).
    assert load_scene(CASES / f"{scene}.toml").sections.geometry == load_scene(CASES / "paper.toml").sections.geometry
    assert reduced.unknowns_per_node < full.unknowns_per_node == 4
    for field, values in reduced_fields.items():
        scale = np.abs(full_fields[field]).max()
        # Both Newton runs stop at a relative increment of 1e-9 (newton.rtol) and reach it
        # quadratically, so they agree to far better than 1e-9 of the field's size; 1e-8
        # leaves room for the different block orderings of the two linear systems.
        assert np.abs(values - full_fields[field]).max() <= 1e-8 * scale, field
    # The fields the reduced scene does not have are identically zero in the full model.
    for field in set(full.fields) - set(reduced.fields):
        assert np.abs(full_fields[field]).max() <= 1e-12 * max(1.0, abs(full.scales["Phi"])), field


@pytest.mark.parametrize(
    "case, unknowns, fields, strategy",
    [
        ("paper", 4, ["u", "phi", "theta"], "monolithic Newton on (u, phi, theta)"),
        ("elastic", 2, ["u"], "monolithic Newton on (u)"),
        ("electroelastic", 3, ["u", "phi"], "monolithic Newton on (u, phi)"),
        ("thermoelastic", 3, ["u", "theta"], "monolithic Newton on (u, theta)"),
        ("heated", 4, ["u", "phi", "theta"], "staggered: theta"),
    ],
)
def test_unknowns_per_node_and_fields_follow_the_effects(tmp_path, case, unknowns, fields, strategy):
    record, values = run(CASES / f"{case}.toml", 4, tmp_path)
    assert record.unknowns_per_node == unknowns
    assert record.dofs == unknowns * record.nodes  # P1: one value per node and unknown
    assert record.fields == fields and sorted(values) == sorted(fields)
    assert record.strategy.startswith(strategy)
    assert record.converged


def conductances_off() -> list[str]:
    """Both contact conductances on but zero (their other data are then irrelevant)."""
    values = {"electric_contact": dict(k_e=0, eps_e=1e-6, phi_f=0, L="inf"),
              "thermal_contact": dict(k_c=0, eps_c=1e-6, theta_f=0)}
    return [arg for section, keys in values.items() for key, value in keys.items()
            for arg in ("--set", f"{section}.{key}={value}")]


def test_the_staggered_temperature_is_solved_once_and_exactly(tmp_path):
    """theta without thermal contact is linear and one-way coupled: its residual after the
    single staggered solve is at round-off, and it equals the monolithic solve with k_c = 0."""
    staggered, s_fields = run(CASES / "heated.toml", 8, tmp_path / "s")
    assert staggered.strategy.startswith("staggered")
    # Scaled residual of the heat equation after its one solve. Each node's scaled source
    # load is ~ h^2 * 1e3 / (k11 * Theta) ~ 1e-3 at h = 1/8: 1e-12 of that is round-off.
    assert staggered.staggered_theta_residual <= 1e-15
    monolithic, m_fields = run(CASES / "heated.toml", 8, tmp_path / "m", "--set", "scene.name=mono",
                               "--effects", ",".join(FULL), *conductances_off())
    assert monolithic.strategy.startswith("monolithic")
    for field in ("u", "phi", "theta"):
        scale = np.abs(m_fields[field]).max()
        assert np.abs(s_fields[field] - m_fields[field]).max() <= 1e-8 * scale, field  # as above


@pytest.mark.parametrize(
    "effects, message",
    [
        ('["contact", "magnetic"]', "unknown effect 'magnetic'; valid effects: piezoelectric, thermal"),
        ('["friction"]', "turns on 'friction', which needs 'contact' on too"),
        ('["thermal", "pyroelectric"]', "turns on 'pyroelectric', which needs 'piezoelectric' on too"),
        ('["piezoelectric", "electric_contact"]', "needs 'contact' on too"),
        ('["contact", "thermal_contact"]', "needs 'thermal' on too"),
        ('["contact", "contact"]', "names an effect twice"),
    ],
)
def test_invalid_effects_are_named(effects, message):
    with pytest.raises(SceneError, match=re.escape(message)):
        load_scene(CASES / "paper.toml", [f"scene.effects={effects}"])


def test_data_of_an_effect_that_is_off_is_a_warning_and_not_passed_on():
    scene = load_scene(CASES / "paper.toml", ["scene.effects=[\"contact\"]"])
    assert "electric_contact.k_e is ignored: effect 'electric_contact' is off" in scene.warnings
    assert "contact.S is ignored: effect 'friction' is off" in scene.warnings
    assert scene.solver_parameters()["electric_contact"] == {}
    assert "S" not in scene.solver_parameters()["contact"]
    # ... and a reduced scene file needs none of it.
    assert load_scene(CASES / "elastic.toml").warnings == ()


def test_the_command_line_switches_effects(tmp_path, capsys):
    record, values = run(CASES / "paper.toml", 2, tmp_path, "--effects", "contact,friction")
    assert record.fields == ["u"] and record.unknowns_per_node == 2
    assert "warning: thermal_contact.k_c is ignored" in capsys.readouterr().err


def valid_combinations() -> list[tuple[str, ...]]:
    from itertools import combinations

    from harness.scene.schema import EFFECTS, effect_list

    names = list(EFFECTS)
    return [c for k in range(len(names) + 1) for c in combinations(names, k) if effect_list(list(c)) is None]


@pytest.mark.parametrize("case, n, dimension", [("paper.toml", 2, 2), ("paper3d.toml", 1, 3)])
def test_every_valid_combination_of_effects_compiles_and_solves(tmp_path, case, n, dimension):
    """The scheme is assembled from IFMACRO pieces: each of the valid effect sets must give a
    FreeFEM program that compiles and runs, in 2D and in 3D (the same pieces, freefem/
    dimension.idp). From the pressed start every one of them converges (2D at h = 1/2, 3D at
    h = 1, 24 tetrahedra); a failure names its combination."""
    from harness.core.errors import RunError
    from harness.core.layout import Layout
    from harness.mesh.mesh import build_mesh
    from harness.run.run import run_level

    combos = valid_combinations()
    assert len(combos) == 31  # of the 2^7 subsets: 5 without contact, 26 with (friction x2 on each of 13)
    layout = Layout(results=tmp_path)
    base = load_scene(CASES / case)
    mesh = build_mesh(base.geometry, n, tmp_path / "meshes").path
    failed = []
    for combo in combos:
        scene = load_scene(CASES / case, [f"scene.effects={json.dumps(list(combo))}",
                                                   "scene.initial_guess=pressed"])
        try:
            record = run_level(scene, mesh, n, layout).record
        except RunError as exc:
            failed.append(f"{combo}: {exc}")
            continue
        assert record.unknowns_per_node == dimension + ("piezoelectric" in combo) + ("thermal" in combo)
    assert not failed, "\n".join(failed)
