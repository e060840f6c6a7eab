"""Manufactured solutions (issue 6): the symbolic derivation is right, and the scheme
converges to the exact fields at the rates of P1 elements, with and without contact.

Requirement: the discrete solution of a manufactured case converges to the exact one in
every field at slope 2 in L2 and 1 in the H1 seminorm; a solution in the P1 space is
reproduced to round-off."""

from __future__ import annotations

import shutil

import numpy as np
import pandas as pd
import pytest
import sympy

from harness.core import freefem
from harness.core.errors import SceneError
from harness.measure.fields import read_fields
from harness.core.layout import REPO, Layout
from harness.measure.norms import fe_errors
from harness.scene.mms import MACROS, X, Y, derive, macros, material_constants, numeric, parse_exact
from harness.measure.norm_table import MMS_NORMS
from harness.scene.scene import load_scene
from harness.run.script import main_script
from harness.study.verification import BANDS, MMS_CASES, mms_errors, mms_rates

COMMITTED = REPO / "tests" / "gold" / "mms_levels.csv"  # `make gold` refreshes it from `make verify`

ALL_BULK = ("piezoelectric", "thermal", "pyroelectric")
# The paper's plane-strain BaTiO3 constants (docs/model.md section 5), typed here independently of
# freefem/materials and freefem/material.idp.
PAPER_BATIO3 = dict(f11=166e9, f13=78e9, f33=162e9, f44=43e9, e31=-4.4, e33=18.6, e15=11.6,
                    b11=11.2e-9, b33=12.6e-9, m11=2.24e6, m33=1.89e6, p1=0.0, p3=-1e-4,
                    k11=50.0, k33=75.0)


@pytest.fixture(scope="module")
def contact_scene():
    return load_scene(MMS_CASES["contact"])


@pytest.fixture(scope="module")
def derived(contact_scene):
    return derive(parse_exact(contact_scene.manufactured), PAPER_BATIO3, ALL_BULK)


def test_freefem_reduces_the_material_file_to_the_papers_constants():
    constants = material_constants("BaTiO3", Layout())
    assert {k: constants[k] for k in PAPER_BATIO3} == pytest.approx(PAPER_BATIO3, rel=1e-15, abs=0.0)
    # and the out-of-plane constants of the 3D law (transverse isotropy: C22 = C11, C23 = C13, ...)
    assert (constants["fC22"], constants["fC23"], constants["f2323"], constants["e24"]) == (166e9, 78e9, 43e9, 11.6)


def law(eps, grad_phi, theta):
    """Stress, electric displacement from Voigt strain (e11, e33, 2e13), in numpy, written from
    docs/model.md section 2's matrices: sigma = F eps - E^T E(phi) - theta M with E(phi) = -grad phi."""
    c = PAPER_BATIO3
    F = np.array([[c["f11"], c["f13"], 0], [c["f13"], c["f33"], 0], [0, 0, c["f44"]]])
    E = np.array([[0, 0, c["e15"]], [c["e31"], c["e33"], 0]])
    beta = np.diag([c["b11"], c["b33"]])
    M, P = np.array([c["m11"], c["m33"], 0]), np.array([c["p1"], c["p3"]])
    sigma = F @ eps + E.T @ grad_phi - theta * M
    D = E @ eps - beta @ grad_phi - theta * P
    return sigma, D


def test_sources_satisfy_the_strong_form_by_finite_differences(contact_scene, derived):
    """Independent of sympy's algebra: exact fields only, differentiated by central
    differences; -div sigma = f0, div D = phi0, div q = vartheta0 at scattered points."""
    exact = parse_exact(contact_scene.manufactured)
    f = numeric({"u1": exact.u1, "u2": exact.u2, "phi": exact.phi, "theta": exact.theta})
    d = 1e-4  # truncation ~d^2 |f''''| ~ 1e-8, round-off ~1e-16/d^2 ~ 1e-8, relative

    def grad(g, x, y):
        return np.array([(g(x + d, y) - g(x - d, y)) / (2 * d), (g(x, y + d) - g(x, y - d)) / (2 * d)])

    def fluxes(x, y):
        (u1x, u1y), (u2x, u2y) = grad(f["u1"], x, y), grad(f["u2"], x, y)
        eps = np.array([u1x, u2y, u1y + u2x])
        sigma, D = law(eps, grad(f["phi"], x, y), f["theta"](x, y))
        q = -np.array([PAPER_BATIO3["k11"], PAPER_BATIO3["k33"]]) * grad(f["theta"], x, y)
        return sigma, D, q  # sigma = (s11, s33, s13)

    def div(component, x, y):
        return lambda ix, iy: ((fluxes(x + d, y)[component][ix] - fluxes(x - d, y)[component][ix]) / (2 * d)
                               + (fluxes(x, y + d)[component][iy] - fluxes(x, y - d)[component][iy]) / (2 * d))

    sources = numeric({k: derived[k] for k in ("f1", "f2", "charge", "heat", "sig11", "sig33", "sig13", "D1", "D3")})
    rng = np.random.default_rng(6)
    for x, y in zip(rng.uniform(0, 4, 12), rng.uniform(0, 1, 12)):
        sigma, D, q = fluxes(x, y)
        checks = {
            "sig11": (sigma[0], 2e3), "sig33": (sigma[1], 2e3), "sig13": (sigma[2], 2e3),
            "D1": (D[0], 5e-7), "D3": (D[1], 5e-7),
            "f1": (-div(0, x, y)(0, 2), 5e3), "f2": (-div(0, x, y)(2, 1), 5e3),
            "charge": (div(1, x, y)(0, 1), 1e-6), "heat": (div(2, x, y)(0, 1), 0.5),
        }
        for key, (value, scale) in checks.items():
            # 1e-5 of the quantity's size on Omega: far above the FD error, far below any
            # wrong sign or factor (every term is >= 5 % of its sum: cases/mms/contact.toml).
            assert abs(sources[key](x, y) - value) < 1e-5 * scale, (key, x, y)


def test_every_coupling_term_is_of_the_order_of_the_others(derived):
    """The premise of a manufactured solution that checks the couplings: no term is
    negligible. Each term's largest value on a grid, against its equation's largest."""
    c = PAPER_BATIO3
    ex = {k: derived[k] for k in ("u1", "u2", "phi", "theta")}
    terms = {
        "sigma33": {"elastic": c["f13"] * sympy.diff(ex["u1"], X) + c["f33"] * sympy.diff(ex["u2"], Y),
                    "piezo": c["e33"] * sympy.diff(ex["phi"], Y), "thermal": c["m33"] * ex["theta"]},
        "D3": {"piezo": c["e31"] * sympy.diff(ex["u1"], X) + c["e33"] * sympy.diff(ex["u2"], Y), "dielectric": c["b33"] * sympy.diff(ex["phi"], Y),
                   "pyro": c["p3"] * ex["theta"]},
    }
    x, y = np.meshgrid(np.linspace(0, 4, 81), np.linspace(0, 1, 21))
    for equation, parts in terms.items():
        sizes = {name: np.abs(f(x, y)).max() for name, f in numeric(parts).items()}
        assert min(sizes.values()) > 0.1 * max(sizes.values()), (equation, sizes)


def test_the_contact_case_visits_every_branch_of_the_contact_laws(contact_scene):
    """On Gamma_3 = [1,3]x{0}: open and penetrating, slipping and sticking, conductances at
    zero, on the ramp and saturated, potential truncated and not."""
    t = contact_scene.sections
    exact = numeric({k: v for k, v in vars(parse_exact(contact_scene.manufactured)).items()})
    x = np.linspace(1, 3, 2001)
    y = np.zeros_like(x)
    s = -exact["u2"](x, y) - t.contact.gap
    shear = t.contact.c_nu * np.abs(exact["u1"](x, y))
    assert (s < 0).any() and (s > 0).any()
    assert (shear > t.contact.S).any() and (shear < t.contact.S).any()
    for eps in (t.electric_contact.eps_e, t.thermal_contact.eps_c):
        assert ((s > 0) & (s < eps)).any() and (s > eps).any()
    drop = np.abs(exact["phi"](x, y) - t.electric_contact.phi_f)
    assert (drop > t.electric_contact.L).any() and (drop < t.electric_contact.L).any()


def test_switched_off_effects_remove_their_field_or_coupling(contact_scene):
    exact = parse_exact(contact_scene.manufactured)
    elastic = derive(exact, PAPER_BATIO3, ())
    assert elastic["phi"] == 0 and elastic["theta"] == 0 and elastic["charge"] == 0 and elastic["heat"] == 0
    no_pyro = derive(exact, PAPER_BATIO3, ("piezoelectric", "thermal"))
    with_pyro = derive(exact, PAPER_BATIO3, ALL_BULK)
    difference = sympy.simplify(with_pyro["D3"] - no_pyro["D3"] - (-PAPER_BATIO3["p3"] * exact.theta))
    assert abs(float(difference.subs({X: 1.3, Y: 0.4}))) < 1e-20


@pytest.mark.parametrize("text, words", [("1e-8*sin(z)", "only x and y"), ("1e-8*(x", "not an expression")])
def test_a_bad_exact_field_is_a_scene_error_naming_the_key(text, words):
    with pytest.raises(SceneError, match=rf"manufactured\.u1 .*{words}"):
        parse_exact({"u1": text})


def test_freefem_evaluates_the_emitted_expressions_as_sympy_does(tmp_path, derived):
    """The macros as harness/run/script.py writes them, evaluated by FreeFEM at a few points and
    compared with sympy: catches syntax (powers, integer division, precedence) and digits."""
    emitted = macros(derived)
    header = [line for line in main_script("BaTiO3", (), Layout(), macros=emitted).splitlines()
              if line.startswith("macro mms") or line.startswith("macro MMS")]
    points = [(0.3, 0.7), (2.9, 0.05), (3.7, 1.0)]
    body = ["cout.precision(17);"]
    for px, py in points:
        body += [f"x = {px!r}; y = {py!r};"] + [f'cout << "{name} " << {name} << endl;' for name in emitted if name != "MMS"]
    script = tmp_path / "eval.edp"
    script.write_text("\n".join(header + ["real x, y;"] + body) + "\n")
    outcome = freefem.invoke(freefem.command(script, []), tmp_path, 60)
    lines = (tmp_path / "stdout.txt").read_text().split("\n")
    assert outcome.returncode == 0, "\n".join(lines[-10:])
    got = [line.split() for line in lines if len(line.split()) == 2]
    f = numeric(derived)
    expected = [(name, f[MACROS[name]](px, py)) for px, py in points for name in emitted if name != "MMS"]
    assert [name for name, _ in got] == [name for name, _ in expected]
    for (name, value), (_, want) in zip(got, expected):
        # Same double arithmetic in a different order: a few ulp of the largest term.
        assert float(value) == pytest.approx(float(want), rel=1e-12, abs=1e-12 * (abs(float(want)) + 1e-300)), name


# ---- The scheme against exact solutions (FreeFEM runs) ----

LINEAR = {  # in the P1 space; on Gamma_3 it penetrates for x > 1.5 and slips for x < 2
    "u1": "1e-8*(1.6 - 0.4*x + 0.3*y)", "u2": "1e-8*(0.6 - 0.4*x + 0.5*y)",
    "phi": "30 - 12*x + 20*y", "theta": "1e-3*(0.5 + 0.2*x - 0.6*y)",
}


def manufactured_scene(case: str, exact: dict[str, str]):
    return load_scene(MMS_CASES[case], [f'manufactured.{k}="{v}"' for k, v in exact.items()]
                      + [f'scene.name="mms_{case}_linear"'])


@pytest.mark.parametrize("case", ["bulk", "contact", "wedge"])  # wedge: tilted normal, unstructured mesh
def test_a_solution_in_the_p1_space_is_reproduced_to_round_off(tmp_path, case):
    """Known answer: linear exact fields are P1 functions, and (quadrature exact for the
    linear-times-linear boundary terms, contact terms evaluated at the same state) the
    discrete problem is solved by their interpolant. Any wrong sign or factor in the
    derived data or the scheme's loads leaves an O(1) error instead."""
    scene = manufactured_scene(case, LINEAR)
    table = mms_errors(scene, (4,), Layout(results=tmp_path), jobs=1, progress=lambda line: None)
    # Newton converges quadratically to relative increments below 1e-10 (the case's rtol),
    # so what is left is the LU's round-off (measured 1e-15 ... 1e-13).
    assert (table["relative_error"] < 1e-10).all(), table.to_string()


def quiet(line: str) -> None:
    pass


@pytest.fixture(scope="module")
def coarse_studies(tmp_path_factory):
    """Levels 4, 8, 16 of every 2D manufactured case (the committed table goes on to 1/32)."""
    layout = Layout(results=tmp_path_factory.mktemp("mms"))
    tables = [mms_errors(load_scene(path), (4, 8, 16), layout, jobs=2, progress=quiet).assign(case=case)
              for case, path in MMS_CASES.items()]
    return layout, pd.concat(tables, ignore_index=True)


@pytest.mark.parametrize("case", list(MMS_CASES))
@pytest.mark.parametrize("norm", [n.key for n in MMS_NORMS])
def test_manufactured_errors_converge_at_the_p1_rates(coarse_studies, case, norm):
    """Slopes over h = 1/4 ... 1/16 inside harness/verify.py's BANDS (2 -/+ 0.1 in L2,
    1 -/+ 0.05 in the H1 seminorm), for every field, and a straight log-log line."""
    _, errors = coarse_studies
    assert_p1_rates(errors, case, norm)


def assert_p1_rates(errors: pd.DataFrame, case: str, norm: str) -> None:
    rates = mms_rates(errors)
    selected = rates[(rates["case"] == case) & (rates["norm"] == norm)]
    assert set(selected["field"]) == {"u", "phi", "theta"}
    low, high = BANDS[norm]
    for _, row in selected.iterrows():
        assert low <= row["slope"] <= high, f"{case} {row['field']} {norm}: slope {row['slope']:.3f}"
        # Measured < 0.02: a kink (a term converging at another order) shows here first.
        assert row["slope_stderr"] < 0.05, f"{case} {row['field']} {norm}: stderr {row['slope_stderr']:.3f}"


def test_the_error_levels_are_those_of_the_committed_table(coarse_studies):
    """A right slope with a wrong constant fails too: the errors at h = 1/8 and 1/16 match
    tests/gold/mms_levels.csv (`make verify`'s table, pinned by `make gold`) to 1 % (the runs are deterministic;
    run.json carries 6 significant digits)."""
    _, errors = coarse_studies
    committed = pd.read_csv(COMMITTED).set_index(["case", "n", "field", "norm"])["error"]
    for _, row in errors[errors["n"] >= 8].iterrows():
        want = committed[(row["case"], row["n"], row["field"], row["norm"])]
        assert row["error"] == pytest.approx(want, rel=1e-2), (row["case"], row["n"], row["field"], row["norm"])


@pytest.mark.parametrize("case", list(MMS_CASES))
def test_freefem_errors_agree_with_an_independent_quadrature(coarse_studies, case):
    """FreeFEM's mms_errors against this harness's own quadrature of the VTU fields."""
    layout, errors = coarse_studies
    scene = load_scene(MMS_CASES[case])
    fields = read_fields(layout.level_dir(scene.name, 8) / "solution.vtu")
    exact = dict(vars(parse_exact(scene.manufactured)))
    ours = fe_errors(fields.points, fields.triangles, {f: fields.field(f) for f in scene.fields}, exact)
    theirs = errors[(errors["case"] == case) & (errors["n"] == 8)].set_index(["field", "norm"])["error"]
    for field in scene.fields:
        for norm in (n.key for n in MMS_NORMS):
            # FreeFEM differentiates a P3 interpolant of the exact field, this quadrature the
            # field itself: a relative difference O(h^2), measured <= 2.2e-4 at h = 1/8.
            assert ours[field][norm] == pytest.approx(theirs[(field, norm)], rel=1e-3), (field, norm)


# One wrong sign or factor per term the manufactured cases check; each still converges
# (Newton finds a solution), but to the solution of another problem.
MUTATIONS = {
    "pyroelectric sign (D3)": ("bulk", "constitutive.idp", "macro DT3(th) (-mat(p3) * Theta * (th))",
                               "macro DT3(th) (mat(p3) * Theta * (th))"),
    "shear piezoelectric sign (D1)": ("bulk", "constitutive.idp", "macro DU1(u) (mat(e15) * eps5(u)",
                                      "macro DU1(u) (-mat(e15) * eps5(u)"),
    "penalty factor": ("contact", "contact_forms.idp", "(normalPressure(gapS(u)) * vnu(v)",
                       "(0.5 * normalPressure(gapS(u)) * vnu(v)"),
    # The residual's own bound halved, spelled with friction.idp's projection (the law's
    # macro set is shared with mms.idp, so the mutation is written out here, in the residual's
    # integrand: contact_forms.idp).
    "Tresca bound": ("contact", "contact_forms.idp", "frictionScaleOf(u) * cnu * U * tauDot(u, v)",
                     "projScale(wNorm(u), 0.5 * frictionBound(normalPressure(gapS(u)))) * cnu * U * tauDot(u, v)"),
    "electric conductance sign": ("contact", "contact_forms.idp", "(electricFlux(gapS(u), Phi * ph - phif) * vp",
                                  "(-electricFlux(gapS(u), Phi * ph - phif) * vp"),
    "thermal conductance factor": ("contact", "contact_forms.idp", "(thermalFlux(gapS(u), Theta * th - thetaf) * vt",
                                   "(0.5 * thermalFlux(gapS(u), Theta * th - thetaf) * vt"),
}


@pytest.mark.parametrize("mutation", list(MUTATIONS))
def test_a_wrong_term_in_the_scheme_fails_the_manufactured_rates(tmp_path, mutation):
    """Mutation: the scheme's residual (not the manufactured data) gets one term wrong; some
    field's error must stop converging, i.e. leave the slope bands. The contact mutations
    are in the residual's integrands, freefem/contact_forms.idp; freefem/mms.idp evaluates the contact laws
    at the exact state with contact.idp's and friction.idp's macros, so a sign error inside those macros
    (shared by both sides) would not show here: tests/test_physics.py checks them."""
    case, name, old, new = MUTATIONS[mutation]
    scripts = tmp_path / "freefem"
    shutil.copytree(REPO / "freefem", scripts)
    text = (scripts / name).read_text()
    assert old in text, f"{name} no longer spells {old!r}: update MUTATIONS"
    (scripts / name).write_text(text.replace(old, new, 1))
    layout = Layout(results=tmp_path / "results", freefem=scripts)
    rates = mms_rates(mms_errors(load_scene(MMS_CASES[case]), (8, 16), layout, jobs=2, progress=quiet).assign(case=case))
    assert not rates["within_band"].all(), rates.to_string()


# Coulomb friction (issue 23, docs/laws.md): the contact case with the slip bound mu c_nu (s)_+.
COULOMB = MMS_CASES["coulomb"]


def test_the_coulomb_case_is_open_slipping_and_sticking_on_gamma3():
    """The exact state against Coulomb's bound mu p(s), p = c_nu (s)_+: no friction where open,
    |c_nu u_tau| above mu p on a closed part (slip) and below it on another (stick)."""
    scene = load_scene(COULOMB)
    c = scene.sections.contact
    assert c.friction_law == "coulomb" and c.mu > 0
    exact = numeric({k: v for k, v in vars(parse_exact(scene.manufactured)).items()})
    x = np.linspace(1, 3, 2001)
    y = np.zeros_like(x)
    s = -exact["u2"](x, y) - c.gap
    bound = c.mu * c.c_nu * np.maximum(s, 0.0)
    shear = c.c_nu * np.abs(exact["u1"](x, y))
    closed = s > 0
    assert (~closed).any()
    assert (closed & (shear > bound)).any() and (closed & (shear < bound)).any()


# Its rates over h = 1/4 ... 1/16, its error levels and the independent quadrature are those
# of every case of MMS_CASES above (make verify, h = 1/4 ... 1/32: L2 slopes 1.96-1.99, H1
# 1.00-1.01, standard errors <= 0.011).


def test_a_halved_coulomb_bound_in_the_residual_fails_the_manufactured_rates(tmp_path):
    """Mutation, as MUTATIONS above: the residual's slip bound halved (contact_forms.idp), the
    manufactured loads left with the law's own (mms.idp): the error stops converging."""
    scripts = tmp_path / "freefem"
    shutil.copytree(REPO / "freefem", scripts)
    old, new = MUTATIONS["Tresca bound"][2:]
    text = (scripts / "contact_forms.idp").read_text()
    assert old in text
    (scripts / "contact_forms.idp").write_text(text.replace(old, new, 1))
    layout = Layout(results=tmp_path / "results", freefem=scripts)
    rates = mms_rates(mms_errors(load_scene(COULOMB), (8, 16), layout, jobs=2, progress=quiet).assign(case="coulomb"))
    assert not rates["within_band"].all(), rates.to_string()


# Across a material interface (cases/mms/interface.toml): the rectangle's two named blocks,
# BaTiO3 below and PZT-5H poled along (0.6, 0.8) above, the exact fields of cases/mms/bulk.toml.
INTERFACE = REPO / "cases" / "mms" / "interface.toml"


def interface_errors(layout: Layout, levels: tuple[int, ...]) -> pd.DataFrame:
    return mms_errors(load_scene(INTERFACE), levels, layout, jobs=1, progress=quiet).assign(case="interface")


@pytest.fixture(scope="module")
def interface_study(tmp_path_factory):
    return interface_errors(Layout(results=tmp_path_factory.mktemp("interface")), (4, 8, 16))


@pytest.mark.parametrize("norm", [n.key for n in MMS_NORMS])
def test_a_manufactured_solution_across_a_material_interface_keeps_the_p1_rates(interface_study, norm):
    """u, phi, theta continuous, sigma*, D*, q* jumping with the coefficients (one region rotated):
    slopes in the 2D bands, L2 2 -/+ 0.1 and H1 1 -/+ 0.05 (measured over h = 1/4 ... 1/32:
    u 1.98 and 1.00, phi 2.01 and 1.01, theta 1.99 and 1.00; the mesh has the interface as a line)."""
    rates = mms_rates(interface_study, {"interface": 2})
    assert set(rates["field"]) == {"u", "phi", "theta"}
    low, high = BANDS[norm]
    for _, row in rates[rates["norm"] == norm].iterrows():
        assert low <= row["slope"] <= high, f"{row['field']} {norm}: slope {row['slope']:.3f}"
        assert row["slope_stderr"] < 0.05, f"{row['field']} {norm}: stderr {row['slope_stderr']:.3f}"


def test_without_the_interface_jump_the_manufactured_rates_fail(tmp_path):
    """Mutation: the strong-form loads (each region's sources and boundary fluxes, the one-material
    form) leave out the jumps of sigma*, D*, q* across the interface; some field stops converging."""
    scripts = tmp_path / "freefem"
    shutil.copytree(REPO / "freefem", scripts)
    text = (scripts / "mms.idp").read_text()
    assert "IFMACRO(MMSREGIONS)" in text and "IFMACRO(!MMSREGIONS)" in text
    (scripts / "mms.idp").write_text(text.replace("MMSREGIONS)", "MMSREGIONSOFF)"))
    rates = mms_rates(interface_errors(Layout(results=tmp_path / "results", freefem=scripts), (8, 16)),
                      {"interface": 2})
    assert not rates["within_band"].all(), rates.to_string()
