"""Manufactured solutions: from exact fields u*, phi*, theta* to the data that make them solve
the model, derived symbolically (sympy) and written as FreeFEM expressions.

The constitutive law is the plane-strain one of freefem/constitutive.idp (docs/model.md section 2,
paper 2.1, 2.2, 2.6; axis 1 = x, axis 3 = y, engineering shear):

    sigma = F eps(u) + E^T grad(phi) - theta M
    D     = E eps(u) - beta grad(phi) - theta P
    q     = -K grad(theta)

and the sources follow the signs of the scheme's weak forms (freefem/forms.idp):
R_u = int sigma:eps(v) - int f0.v gives f0 = -div sigma; R_phi = -int D.grad(xi) -
int phi0 xi gives phi0 = div D; R_theta = -int q.grad(eta) - int vartheta0 eta gives
vartheta0 = div q. An effect a scene leaves off removes its field and couplings (phi* = 0
and E = 0 without piezoelectricity, theta* = 0 without heat, P = 0 without pyroelectricity).
The material constants are asked of FreeFEM itself (harness/scene/material_constants.py), so
nothing here repeats them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Callable, Mapping

import numpy as np
import sympy

from harness.core.errors import SceneError
from harness.core.layout import Layout
from harness.scene.corner import mode1_displacement, plane_strain_poisson
from harness.scene.regions import any_rotated
from harness.scene.material_constants import (CONSTANTS, CONSTANTS_3D, ROTATED, ROTATED_CONDUCTIVITY, ROTATED_ELASTIC,
                                        ROTATED_PERMITTIVITY, ROTATED_PIEZO, ROTATED_STRESS_TEMPERATURE,
                                        material_constants)

X, Y, Z = sympy.symbols("x y z", real=True)
EXACT_KEYS = ("u1", "u2", "u3", "phi", "theta")  # u3: a box scene's (3D) only
CORNER_KEYS = ("williams", "williams_opening")
# The law of a ceramic poled along 3 (class 6mm) in Voigt form (order 11 22 33 23 13 12,
# engineering shears), as freefem/constitutive.idp writes it: C_IJ, e_kI by constant name.
VOIGT_PAIRS = {1: (1, 1), 2: (2, 2), 3: (3, 3), 4: (2, 3), 5: (1, 3), 6: (1, 2)}
ELASTIC = {(1, 1): "f11", (1, 2): "fC12", (1, 3): "f13", (2, 2): "fC22", (2, 3): "fC23", (3, 3): "f33",
           (4, 4): "f2323", (5, 5): "f44", (6, 6): "f1212"}
PIEZO = {(1, 5): "e15", (2, 4): "e24", (3, 1): "e31", (3, 2): "e32", (3, 3): "e33"}
# Material axis -> coordinate: axis 3 (poling) is y in 2D (plane strain in the 1-3 plane), z in 3D.
AXES = {2: {1: X, 3: Y}, 3: {1: X, 2: Y, 3: Z}}
# The contract with freefem/ (macro name -> derived quantity), all in x, y and SI units.
MACROS = {
    "mmsU1": "u1", "mmsU2": "u2", "mmsPhi": "phi", "mmsTheta": "theta",
    "mmsSig11": "sig11", "mmsSig33": "sig33", "mmsSig13": "sig13",
    "mmsD1": "D1", "mmsD3": "D3", "mmsQ1": "q1", "mmsQ3": "q3",
    "mmsF1": "f1", "mmsF2": "f2", "mmsCharge": "charge", "mmsHeat": "heat",
}
# sign: the derivative of Abs, so an exact field may have a kink (at a material interface, where
# the weak form of region_macros needs only the fluxes; tests/test_estimator.py).
FUNCTIONS = {"sin", "cos", "tan", "exp", "log", "sqrt", "sinh", "cosh", "tanh", "atan", "sign"}


@dataclass(frozen=True)
class Exact:
    """Exact displacement [m], potential [V] and temperature [K] as expressions in x, y."""

    u1: sympy.Expr
    u2: sympy.Expr
    phi: sympy.Expr
    theta: sympy.Expr
    u3: sympy.Expr = sympy.Integer(0)
    # Williams' mode-I displacement at a corner (harness/scene/corner.py), not yet in u1, u2:
    # its amplitude [m] and the corner's interior angle [rad]; with_corner_mode adds it.
    williams: sympy.Expr = sympy.Integer(0)
    williams_opening: sympy.Expr = sympy.Integer(0)


def parse_exact(texts: Mapping[str, str], dimension: int = 2) -> Exact:
    """Case-file strings (sympy syntax, `**` for powers) to expressions; a blank one is 0."""
    if dimension == 2 and texts.get("u3", "").strip():
        raise SceneError("manufactured.u3 is for a box scene (3D); a 2D scene has u1 and u2 only")
    fields = {}
    for key in EXACT_KEYS:
        text = texts.get(key, "").strip() or "0"
        try:
            expr = sympy.sympify(text, locals={"x": X, "y": Y, "z": Z}, rational=True)
        except (sympy.SympifyError, SyntaxError, TypeError) as exc:
            raise SceneError(f"manufactured.{key} = {text!r} is not an expression: {exc}") from None
        stray = expr.free_symbols - set(AXES[dimension].values())
        if stray:
            allowed = "x and y" if dimension == 2 else "x, y and z"
            raise SceneError(f"manufactured.{key} = {text!r} uses {sorted(map(str, stray))}; only {allowed} may appear")
        fields[key] = expr
    exact = Exact(**fields)
    corner = {key: texts.get(key, "").strip() for key in CORNER_KEYS}
    if not any(corner.values()):
        return exact
    if dimension != 2:
        raise SceneError("manufactured.williams is a plane-strain (2D) field; a box scene has none")
    if not all(corner.values()):
        raise SceneError("manufactured.williams and manufactured.williams_opening go together: the mode's "
                         "amplitude [m] and the corner's interior angle [rad]")
    values = {}
    for key, text in corner.items():
        try:
            value = sympy.sympify(text, rational=True)
        except (sympy.SympifyError, SyntaxError, TypeError) as exc:
            raise SceneError(f"manufactured.{key} = {text!r} is not an expression: {exc}") from None
        if value.free_symbols or not value.is_real:
            raise SceneError(f"manufactured.{key} = {text!r} must be a real number")
        values[key] = value
    if not sympy.pi < values["williams_opening"] < 2 * sympy.pi:
        # At pi the corner is no corner; at 2 pi (a crack) Q's numerator and denominator vanish.
        raise SceneError(f"manufactured.williams_opening = {corner['williams_opening']!r}: the corner must be "
                         "re-entrant and not a crack, an angle strictly between pi and 2 pi")
    return replace(exact, williams=values["williams"], williams_opening=values["williams_opening"])


def with_corner_mode(exact: Exact, constants: Mapping[str, float]) -> Exact:
    """The exact field with Williams' mode (harness/scene/corner.py) added to u1, u2, for the
    material's Poisson ratio; unchanged without one."""
    if exact.williams == 0:
        return exact
    try:
        nu = plane_strain_poisson(*(constants[k] for k in ("f11", "f13", "f33", "f44")))
    except ValueError as exc:
        raise SceneError(f"manufactured.williams needs an isotropic material, as Williams' field does: {exc}") from None
    mode = mode1_displacement(X, Y, exact.williams_opening, nu, exact.williams)
    return replace(exact, u1=exact.u1 + mode[0], u2=exact.u2 + mode[1], williams=sympy.Integer(0))


def derive(exact: Exact, constants: Mapping[str, float], effects: tuple[str, ...],
           dimension: int = 2) -> dict[str, sympy.Expr]:
    """Exact fields, fluxes and sources (keys of macro_names' values) for the effects switched
    on, with the Voigt law of freefem/constitutive.idp in material axes (AXES): in 2D the
    axis-2 terms vanish (plane strain) and the keys are sig11, sig33, sig13, D1, D3, q1, q3,
    f1, f2; in 3D every component is there."""
    rotated = any(k in constants for k in ROTATED)
    names = CONSTANTS + CONSTANTS_3D * (dimension == 3) + ROTATED * rotated
    c = {k: sympy.Float(constants[k]) if k in constants else sympy.Symbol(k) for k in names}
    piezo, thermal = "piezoelectric" in effects, "thermal" in effects
    if not piezo:
        for name in (*PIEZO.values(), *(ROTATED_PIEZO.values() if rotated else ())):
            c[name] = sympy.Integer(0)
    if "pyroelectric" not in effects:
        for name in ("p1", "p2", "p3"):
            c[name] = sympy.Integer(0)
    axes = AXES[dimension]
    disp = {1: exact.u1, 2: exact.u2, 3: exact.u3} if dimension == 3 else {1: exact.u1, 3: exact.u2}
    phi = exact.phi if piezo else sympy.Integer(0)
    theta = exact.theta if thermal else sympy.Integer(0)

    def d(f: sympy.Expr, axis: int) -> sympy.Expr:
        return sympy.diff(f, axes[axis]) if axis in axes else sympy.Integer(0)

    def w(axis: int) -> sympy.Expr:
        return disp.get(axis, sympy.Integer(0))

    eps = {I: d(w(a), a) if a == b else d(w(a), b) + d(w(b), a) for I, (a, b) in VOIGT_PAIRS.items()}
    present = [I for I, (a, b) in VOIGT_PAIRS.items() if a in axes and b in axes]

    def entry(table: Mapping, extra: Mapping, key: Any) -> sympy.Expr:
        name = table.get(key) or (extra.get(key) if rotated else None)
        return c[name] if name else sympy.Integer(0)

    def C(I: int, J: int) -> sympy.Expr:
        return entry(ELASTIC, ROTATED_ELASTIC, (min(I, J), max(I, J)))

    def e(k: int, I: int) -> sympy.Expr:
        return entry(PIEZO, ROTATED_PIEZO, (k, I))

    def m(I: int) -> sympy.Expr:
        return entry({J: f"m{J}{J}" for J in (1, 2, 3) if f"m{J}{J}" in c}, ROTATED_STRESS_TEMPERATURE, I)

    def b(k: int, l: int) -> sympy.Expr:
        return c[f"b{k}{k}"] if k == l else entry({}, ROTATED_PERMITTIVITY, (min(k, l), max(k, l)))

    def kappa(k: int, l: int) -> sympy.Expr:
        return c[f"k{k}{k}"] if k == l else entry({}, ROTATED_CONDUCTIVITY, (min(k, l), max(k, l)))

    out = {"u1": exact.u1, "u2": exact.u2, "phi": phi, "theta": theta}
    if dimension == 3:
        out["u3"] = exact.u3
    sig = {I: sum((C(I, J) * eps[J] for J in present), sympy.Integer(0))
           + sum((e(k, I) * d(phi, k) for k in axes), sympy.Integer(0)) - m(I) * theta for I in present}
    D = {k: sum((e(k, I) * eps[I] for I in present), sympy.Integer(0))
         - sum((b(k, l) * d(phi, l) for l in axes), sympy.Integer(0)) - c[f"p{k}"] * theta for k in axes}
    q = {k: -sum((kappa(k, l) * d(theta, l) for l in axes), sympy.Integer(0)) for k in axes}
    for I in present:
        out["sig%d%d" % VOIGT_PAIRS[I]] = sig[I]
    for k in axes:
        out[f"D{k}"], out[f"q{k}"] = D[k], q[k]

    def stress(a: int, b: int) -> sympy.Expr:
        I = next(J for J, pair in VOIGT_PAIRS.items() if pair in ((a, b), (b, a)))
        return sig.get(I, sympy.Integer(0))

    # f0 = -div sigma, one equation per coordinate (the material axes in axis order).
    for i, a in enumerate(axes, start=1):
        out[f"f{i}"] = -sum((d(stress(a, b), b) for b in axes), sympy.Integer(0))
    out["charge"] = sum((d(D[k], k) for k in axes), sympy.Integer(0))
    out["heat"] = sum((d(q[k], k) for k in axes), sympy.Integer(0))
    return out


def macro_names(dimension: int) -> dict[str, str]:
    """The contract with freefem/ (macro name -> derived quantity): MACROS in 2D, every
    component in 3D."""
    if dimension == 2:
        return MACROS
    keys = ["u1", "u2", "u3", "phi", "theta", "sig11", "sig22", "sig33", "sig23", "sig13", "sig12",
            "D1", "D2", "D3", "q1", "q2", "q3", "f1", "f2", "f3", "charge", "heat"]
    return {"mms" + k[0].upper() + k[1:]: k for k in keys}


def freefem_expr(expr: sympy.Expr) -> str:
    """FreeFEM syntax, fully parenthesised, every number a real literal that round-trips
    its double (so no integer division, no lost digits)."""
    expr = sympy.sympify(expr)
    if expr.is_Symbol:
        if expr not in (X, Y, Z):
            raise ValueError(f"symbol {expr} has no value in FreeFEM")
        return str(expr)
    if expr.is_Number or expr.is_NumberSymbol:
        return real_literal(float(expr))
    if expr.is_Add:
        return "(" + " + ".join(freefem_expr(a) for a in expr.args) + ")"
    if expr.is_Mul:
        return "(" + " * ".join(freefem_expr(a) for a in expr.args) + ")"
    if expr.is_Pow:
        base, power = expr.args
        if power == sympy.Rational(1, 2):
            return f"sqrt({freefem_expr(base)})"
        if power.is_Integer and power < 0:
            return f"(1.0 / {freefem_expr(base ** -power)})"
        if power.is_Integer:
            return f"({freefem_expr(base)})^{int(power)}"
        return f"pow({freefem_expr(base)}, {freefem_expr(power)})"
    name = type(expr).__name__
    if name in FUNCTIONS:
        return f"{name}({freefem_expr(expr.args[0])})"
    if name == "atan2":  # FreeFEM's atan2(y, x), the angle of a singular solution (cases/mms/lshape.toml)
        return f"atan2({freefem_expr(expr.args[0])}, {freefem_expr(expr.args[1])})"
    if name == "Abs":
        return f"abs({freefem_expr(expr.args[0])})"
    raise ValueError(f"no FreeFEM spelling for {name} in {expr}")


def real_literal(value: float) -> str:
    if not math.isfinite(value):
        raise ValueError(f"{value} in a manufactured solution")
    text = repr(value)
    return f"({text})" if value < 0 else text


def macros(derived: Mapping[str, sympy.Expr], dimension: int = 2) -> dict[str, str]:
    """The macros a manufactured run passes to harness/run/script.py's main_script."""
    out = {"MMS": "1"}
    out.update({name: freefem_expr(derived[key]) for name, key in macro_names(dimension).items()})
    return out


def scene_macros(scene, layout: Layout) -> dict[str, str]:
    """Macros for a Scene: none unless its case file has a [manufactured] solution."""
    texts = scene.manufactured
    if not texts:
        return {}
    exact = parse_exact(texts, scene.dimension)
    if scene.regions:
        if exact.williams != 0:
            raise SceneError("manufactured.williams needs one isotropic material; this scene has material regions")
        return region_macros(exact, scene, layout)
    constants = material_constants(scene.material, layout, tuple(scene.poling_macros().items()), scene.dimension,
                                   scene.plane)
    return macros(corner_derived(exact, constants, scene.effects, scene.dimension), scene.dimension)


def corner_derived(exact: Exact, constants: Mapping[str, float], effects: tuple[str, ...],
                   dimension: int = 2) -> dict[str, sympy.Expr]:
    """derive() of an exact field with its corner mode added (with_corner_mode; 2D). The mode's
    fluxes and sources are expanded: sympy's chain rule through atan2 and the radius leaves a
    body force of 7,263 operations (47k characters of FreeFEM) whose terms cancel to round-off;
    expanded, like terms merge and 1,697 remain, and each run's assembly evaluates that many."""
    derived = derive(with_corner_mode(exact, constants), constants, effects, dimension)
    if exact.williams == 0:
        return derived
    return {k: v if k in CONTINUOUS else sympy.expand(v) for k, v in derived.items()}


# The exact fields, one expression over the whole body (continuous across the interfaces); the
# rest (fluxes, sources) is each region's own.
CONTINUOUS = ("u1", "u2", "u3", "phi", "theta")


def off_kinks(expr: sympy.Expr) -> sympy.Expr:
    """A source without the line loads of an exact field's kinks (sympy's DiracDelta, from an
    Abs differentiated twice): a region's own source, off the interface its kink lies on. The
    weak form of region_macros reads only the fluxes, which have none."""
    return expr.replace(lambda e: isinstance(e, sympy.DiracDelta), lambda e: sympy.Integer(0))


def region_macros(exact: Exact, scene, layout: Layout) -> dict[str, str]:
    """Macros of a manufactured solution across material regions: the exact fields are one
    smooth expression, so u, phi and theta are continuous and each region's law makes its own
    sigma*, D*, q*, which jump across an interface by the jump of the coefficients. Each flux and
    source is written as sum_i (region == i) * (region i's expression), and MMSREGIONS has
    freefem/mms.idp load the weak form (int sigma* : eps(v), ...) in place of the strong one:
    that form holds across interfaces as it is, where the strong one would need the flux
    jumps as line loads on them."""
    rotated = any_rotated(scene.regions)
    derived = [derive(exact, material_constants(r.material, layout, tuple(r.poling.macros(always=rotated).items()),
                                                scene.dimension, scene.plane), scene.effects, scene.dimension)
               for r in scene.regions]
    out = {"MMS": "1", "MMSREGIONS": "1"}
    for name, key in macro_names(scene.dimension).items():
        if key in CONTINUOUS:
            out[name] = freefem_expr(derived[0][key])
        else:
            out[name] = "(" + " + ".join(f"(region == {i + 1}) * {freefem_expr(off_kinks(d[key]))}"
                                         for i, d in enumerate(derived)) + ")"
    return out


def numeric(derived: Mapping[str, sympy.Expr]) -> dict[str, Callable[[np.ndarray, np.ndarray], np.ndarray]]:
    """numpy functions of (x, y) for each derived quantity (broadcast to the input's shape)."""
    out = {}
    for key, expr in derived.items():
        f = sympy.lambdify((X, Y), expr, "numpy")
        out[key] = lambda x, y, f=f: np.broadcast_to(f(x, y), np.broadcast(x, y).shape).astype(float)
    return out
