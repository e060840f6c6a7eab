"""The case file: the paper's scene loads; every malformed or non-physical value is a
SceneError whose one-line message names the key."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from harness.core.errors import SceneError
from harness.scene.scene import load_scene, parse_value


def edited(paper_case: Path, tmp_path: Path, old: str, new: str) -> Path:
    text = paper_case.read_text()
    assert old in text
    case = tmp_path / "case.toml"
    case.write_text(text.replace(old, new, 1))
    return case


def test_the_paper_case_loads_with_its_values(paper_case):
    scene = load_scene(paper_case)
    assert scene.name == "paper" and scene.material == "BaTiO3"
    assert scene.initial_guess == "zero"
    assert scene.levels == (2, 4, 8, 16, 32, 64)
    assert scene.slope_band == (0.8, 1.3)
    assert scene.timeout_s == 600.0
    assert math.isinf(scene.sections.electric_contact.L)
    assert scene.geometry.role_lengths() == {"clamped": 2.0, "loaded": 2.0, "free": 4.0, "contact": 2.0}
    assert scene.geometry.breakpoints() == (0.0, 1.0, 3.0, 4.0)


def test_solver_parameters_are_the_five_solver_sections(paper_case):
    params = load_scene(paper_case).solver_parameters()
    assert list(params) == ["loads", "contact", "electric_contact", "thermal_contact", "newton"]
    # friction_law and mu: the schema's defaults (Tresca), which paper.toml does not write.
    assert params["contact"] == {"c_nu": 1e7, "gap": 0.0, "S": 8.5, "friction_law": "tresca", "mu": 0.0}


def test_optional_keys_take_their_defaults(paper_case, tmp_path):
    case = edited(paper_case, tmp_path, "[run]\ntimeout_s = 600\n", "")
    case = edited(case, tmp_path, 'initial_guess = "zero"', "")
    scene = load_scene(case)
    assert scene.timeout_s == 600.0 and scene.initial_guess == "coarser"


@pytest.mark.parametrize(
    "override, expected",
    [
        ("contact.S=0", ("contact", "S", 0.0)),
        ("electric_contact.L=inf", ("electric_contact", "L", math.inf)),
        ("scene.initial_guess=pressed", ("scene", "initial_guess", "pressed")),
        ('scene.name="other"', ("scene", "name", "other")),
        ("newton.max_iterations=7", ("newton", "max_iterations", 7)),
        ("study.levels=[2, 4]", ("study", "levels", [2, 4])),
        ("run.timeout_s=5", ("run", "timeout_s", 5.0)),
    ],
)
def test_overrides_replace_values_parsed_as_toml(paper_case, override, expected):
    section, key, value = expected
    assert getattr(getattr(load_scene(paper_case, [override]).sections, section), key) == value


def test_override_values_fall_back_to_bare_strings():
    assert parse_value("pressed") == "pressed"
    assert parse_value("true") is True
    assert parse_value("1e7") == 1e7


@pytest.mark.parametrize("override", ["contact.nope=1", "nope.S=1", "contact=1", "run.S=1"])
def test_overriding_a_key_that_does_not_exist_is_an_error_naming_it(paper_case, override):
    name = override.partition("=")[0]
    with pytest.raises(SceneError, match=f"no such key '{name}'"):
        load_scene(paper_case, [override])


def test_an_override_without_a_value_is_an_error(paper_case):
    with pytest.raises(SceneError, match="expected section.key=value"):
        load_scene(paper_case, ["contact.S"])


def test_an_unknown_key_in_the_file_is_named(paper_case, tmp_path):
    # (mu is a key since Coulomb friction: a static coefficient is not.)
    case = edited(paper_case, tmp_path, "S = 8.5", "S = 8.5\nmu_static = 0.3")
    with pytest.raises(SceneError, match=r"unknown key contact\.mu_static"):
        load_scene(case)


def test_an_unknown_section_is_named(paper_case, tmp_path):
    case = edited(paper_case, tmp_path, "[run]", "[friction]\nmu = 1\n[run]")
    with pytest.raises(SceneError, match=r"unknown section \[friction\]"):
        load_scene(case)


def test_a_missing_required_key_is_named(paper_case, tmp_path):
    case = edited(paper_case, tmp_path, "eps_c = 1e-6", "")
    with pytest.raises(SceneError, match=r"missing key thermal_contact\.eps_c"):
        load_scene(case)


def test_coulomb_needs_no_tresca_bound(tmp_path):
    """contact.S is Tresca's alone: a Coulomb case may leave it out (it used to fail with
    'missing key contact.S'); FreeFEM is then not given one."""
    coulomb = Path(__file__).parent.parent / "cases" / "coulomb.toml"
    case = edited(coulomb, tmp_path, "S = 8.5", "")
    params = load_scene(case).solver_parameters()["contact"]
    assert params["friction_law"] == "coulomb" and params["mu"] == 0.3
    assert "S" not in params


def test_tresca_still_needs_its_bound(tmp_path):
    coulomb = Path(__file__).parent.parent / "cases" / "coulomb.toml"
    case = edited(coulomb, tmp_path, "S = 8.5", "")
    with pytest.raises(SceneError, match=r"missing key contact\.S"):
        load_scene(case, ["contact.friction_law=tresca"])


@pytest.mark.parametrize(
    "override, key",
    [
        ("contact.c_nu=0", "contact.c_nu"),
        ("contact.S=-1", "contact.S"),
        ("electric_contact.eps_e=0", "electric_contact.eps_e"),
        ("thermal_contact.eps_c=-1e-6", "thermal_contact.eps_c"),
        ("electric_contact.k_e=-0.1", "electric_contact.k_e"),
        ("thermal_contact.k_c=-1", "thermal_contact.k_c"),
        ("geometry.width=0", "geometry.width"),
        ("geometry.height=-1", "geometry.height"),
        ("study.levels=[2, 0]", "study.levels"),
        ("study.levels=[2, 4.0]", "study.levels"),
        ("study.levels=[]", "study.levels"),
        ("study.slope_band=[1.3, 0.8]", "study.slope_band"),
        ("newton.max_iterations=0", "newton.max_iterations"),
        ("scene.initial_guess=warm", "scene.initial_guess"),
        ("geometry.diagonals=NE-SW", "geometry.diagonals"),
        ("geometry.left=hinged", "geometry.left"),
        ("scene.name=../escape", "scene.name"),
        ("contact.gap=nan", "contact.gap"),
        # inf is data only where documented (electric_contact.L); elsewhere it used to pass
        # as 1e300 (a contact force of 1e-256, exit 0) or fail late in FreeFEM.
        ("thermal_contact.theta_f=inf", "thermal_contact.theta_f"),
        ("electric_contact.k_e=inf", "electric_contact.k_e"),
        ("loads.traction_y=inf", "loads.traction_y"),
        ("loads.traction_y=-inf", "loads.traction_y"),
        ("contact.c_nu=inf", "contact.c_nu"),
        ("run.timeout_s=inf", "run.timeout_s"),
    ],
)
def test_non_physical_values_are_errors_naming_the_key(paper_case, override, key):
    with pytest.raises(SceneError, match=key.replace(".", r"\.")) as info:
        load_scene(paper_case, [override])
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    "override, key",
    [
        ("contact.S=true", "contact.S"),  # a bool is never a number
        ("newton.max_iterations=2.5", "newton.max_iterations"),
        ("scene.material=3", "scene.material"),
    ],
)
def test_values_of_the_wrong_type_are_named(paper_case, override, key):
    with pytest.raises(SceneError, match=rf"{key.replace('.', '[.]')} .* must be of type"):
        load_scene(paper_case, [override])


@pytest.mark.parametrize(
    "bottom",
    [
        '[[0.0, 1.0, "free"], [1.5, 4.0, "contact"]]',  # a gap
        '[[0.0, 3.0, "free"], [1.0, 4.0, "contact"]]',  # an overlap
        '[[0.0, 1.0, "free"], [1.0, 3.5, "contact"]]',  # short of the width
        '[[0.0, 4.0, "glued"]]',  # no such role
        '[[4.0, 0.0, "free"]]',  # reversed
        "[]",
    ],
)
def test_bottom_segments_must_tile_the_width_with_known_roles(paper_case, bottom):
    with pytest.raises(SceneError, match=r"geometry\.bottom"):
        load_scene(paper_case, [f"geometry.bottom={bottom}"])


def test_a_missing_or_malformed_case_file_is_a_scene_error(tmp_path):
    with pytest.raises(SceneError, match="case file not found"):
        load_scene(tmp_path / "absent.toml")
    broken = tmp_path / "broken.toml"
    broken.write_text("[scene\n")
    with pytest.raises(SceneError, match="malformed case file"):
        load_scene(broken)


def test_the_scene_is_frozen(paper_case):
    scene = load_scene(paper_case)
    with pytest.raises(AttributeError):
        scene.geometry = None  # type: ignore[misc]


def test_study_settings_do_not_enter_the_run_inputs(paper_case):
    """Changing the levels or the band must not invalidate cached runs."""
    a = load_scene(paper_case).run_inputs()
    b = load_scene(paper_case, ["study.levels=[2, 4]", "study.slope_band=[0, 9]"]).run_inputs()
    c = load_scene(paper_case, ["contact.S=0"]).run_inputs()
    assert a == b and a != c


def test_inf_in_a_case_file_is_refused_naming_file_and_key(paper_case, tmp_path):
    case = edited(paper_case, tmp_path, "theta_f = 373.0", "theta_f = inf")
    with pytest.raises(SceneError, match=r"case\.toml: thermal_contact\.theta_f = inf must be a finite number"):
        load_scene(case)


def test_only_the_truncation_may_be_infinite():
    """One rule in the schema: a key takes inf only when it says what inf means."""
    from harness.scene.schema import SCHEMA, unbounded_keys

    assert unbounded_keys() == ["electric_contact.L"]
    assert "no truncation" in SCHEMA["electric_contact"]["L"].unbounded
