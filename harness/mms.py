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
The material constants are asked of FreeFEM itself (the material file and, when present,
its plane-strain reduction freefem/material.idp), so nothing here repeats them.
"""

from __future__ import annotations

import functools
import math
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping

import numpy as np
import sympy

from harness import freefem
from harness.errors import RunError, SceneError
from harness.layout import Layout

X, Y = sympy.symbols("x y", real=True)
EXACT_KEYS = ("u1", "u2", "phi", "theta")
CONSTANTS = ("f11", "f13", "f33", "f44", "e31", "e33", "e15", "b11", "b33",
             "m11", "m33", "p1", "p3", "k11", "k33")
# The contract with freefem/ (macro name -> derived quantity), all in x, y and SI units.
MACROS = {
    "mmsU1": "u1", "mmsU2": "u2", "mmsPhi": "phi", "mmsTheta": "theta",
    "mmsSig11": "sig11", "mmsSig33": "sig33", "mmsSig13": "sig13",
    "mmsD1": "D1", "mmsD3": "D3", "mmsQ1": "q1", "mmsQ3": "q3",
    "mmsF1": "f1", "mmsF2": "f2", "mmsCharge": "charge", "mmsHeat": "heat",
}
FUNCTIONS = {"sin", "cos", "tan", "exp", "log", "sqrt", "sinh", "cosh", "tanh", "atan"}


@dataclass(frozen=True)
class Exact:
    """Exact displacement [m], potential [V] and temperature [K] as expressions in x, y."""

    u1: sympy.Expr
    u2: sympy.Expr
    phi: sympy.Expr
    theta: sympy.Expr


def parse_exact(texts: Mapping[str, str]) -> Exact:
    """Case-file strings (sympy syntax, `**` for powers) to expressions; a blank one is 0."""
    fields = {}
    for key in EXACT_KEYS:
        text = texts.get(key, "").strip() or "0"
        try:
            expr = sympy.sympify(text, locals={"x": X, "y": Y}, rational=True)
        except (sympy.SympifyError, SyntaxError, TypeError) as exc:
            raise SceneError(f"manufactured.{key} = {text!r} is not an expression: {exc}") from None
        stray = expr.free_symbols - {X, Y}
        if stray:
            raise SceneError(f"manufactured.{key} = {text!r} uses {sorted(map(str, stray))}; only x and y may appear")
        fields[key] = expr
    return Exact(**fields)


def derive(exact: Exact, constants: Mapping[str, float], effects: tuple[str, ...]) -> dict[str, sympy.Expr]:
    """Exact fields, fluxes and sources (keys of MACROS' values) for the effects switched on."""
    c = {k: sympy.Float(constants[k]) if k in constants else sympy.Symbol(k) for k in CONSTANTS}
    piezo, thermal = "piezoelectric" in effects, "thermal" in effects
    if not piezo:
        c["e31"] = c["e33"] = c["e15"] = sympy.Integer(0)
    if "pyroelectric" not in effects:
        c["p1"] = c["p3"] = sympy.Integer(0)
    u1, u2 = exact.u1, exact.u2
    phi = exact.phi if piezo else sympy.Integer(0)
    theta = exact.theta if thermal else sympy.Integer(0)
    d = sympy.diff
    e11, e33, g13 = d(u1, X), d(u2, Y), d(u1, Y) + d(u2, X)
    out = {"u1": u1, "u2": u2, "phi": phi, "theta": theta}
    out["sig11"] = c["f11"] * e11 + c["f13"] * e33 + c["e31"] * d(phi, Y) - c["m11"] * theta
    out["sig33"] = c["f13"] * e11 + c["f33"] * e33 + c["e33"] * d(phi, Y) - c["m33"] * theta
    out["sig13"] = c["f44"] * g13 + c["e15"] * d(phi, X)
    out["D1"] = c["e15"] * g13 - c["b11"] * d(phi, X) - c["p1"] * theta
    out["D3"] = c["e31"] * e11 + c["e33"] * e33 - c["b33"] * d(phi, Y) - c["p3"] * theta
    out["q1"] = -c["k11"] * d(theta, X)
    out["q3"] = -c["k33"] * d(theta, Y)
    out["f1"] = -(d(out["sig11"], X) + d(out["sig13"], Y))
    out["f2"] = -(d(out["sig13"], X) + d(out["sig33"], Y))
    out["charge"] = d(out["D1"], X) + d(out["D3"], Y)
    out["heat"] = d(out["q1"], X) + d(out["q3"], Y)
    return out


def freefem_expr(expr: sympy.Expr) -> str:
    """FreeFEM syntax, fully parenthesised, every number a real literal that round-trips
    its double (so no integer division, no lost digits)."""
    expr = sympy.sympify(expr)
    if expr.is_Symbol:
        if expr not in (X, Y):
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
    if name == "Abs":
        return f"abs({freefem_expr(expr.args[0])})"
    raise ValueError(f"no FreeFEM spelling for {name} in {expr}")


def real_literal(value: float) -> str:
    if not math.isfinite(value):
        raise ValueError(f"{value} in a manufactured solution")
    text = repr(value)
    return f"({text})" if value < 0 else text


def macros(derived: Mapping[str, sympy.Expr]) -> dict[str, str]:
    """The macros a manufactured run passes to harness/script.py's main_script."""
    out = {"MMS": "1"}
    out.update({name: freefem_expr(derived[key]) for name, key in MACROS.items()})
    return out


def scene_macros(scene, layout: Layout) -> dict[str, str]:
    """Macros for a Scene: none unless its case file has a [manufactured] solution."""
    texts = scene.manufactured
    if not texts:
        return {}
    exact = parse_exact(texts)
    return macros(derive(exact, material_constants(scene.material, layout), scene.effects))


def material_constants(material: str, layout: Layout) -> dict[str, float]:
    return dict(_constants(str(layout.material_file(material).resolve()),
                           str(layout.material_reduction_file().resolve())))


@functools.cache
def _constants(material_file: str, reduction_file: str) -> tuple[tuple[str, float], ...]:
    """Include the material as a run does, print the plane-strain constants to 17 digits."""
    includes = [material_file] + [reduction_file] * Path(reduction_file).is_file()
    lines = [f'include "{p}"' for p in includes] + ["cout.precision(17);"]
    lines += [f'cout << "{k} " << {k} << endl;' for k in CONSTANTS]
    with tempfile.TemporaryDirectory(prefix="ff-material-") as tmp:
        script = Path(tmp) / "constants.edp"
        script.write_text("\n".join(lines) + "\n")
        outcome = freefem.invoke(freefem.command(script, []), Path(tmp), timeout_s=60)
        text = (Path(tmp) / "stdout.txt").read_text()
    values = dict(line.split() for line in text.splitlines() if len(line.split()) == 2)
    if outcome.returncode != 0 or set(CONSTANTS) - set(values):
        raise RunError(f"FreeFEM could not print the constants of {material_file}: "
                       f"{freefem.error_detail(text) or 'missing constants'}")
    return tuple((k, float(values[k])) for k in CONSTANTS)


def numeric(derived: Mapping[str, sympy.Expr]) -> dict[str, Callable[[np.ndarray, np.ndarray], np.ndarray]]:
    """numpy functions of (x, y) for each derived quantity (broadcast to the input's shape)."""
    out = {}
    for key, expr in derived.items():
        f = sympy.lambdify((X, Y), expr, "numpy")
        out[key] = lambda x, y, f=f: np.broadcast_to(f(x, y), np.broadcast(x, y).shape).astype(float)
    return out


def fe_errors(points: np.ndarray, triangles: np.ndarray, values: Mapping[str, np.ndarray],
              exact: Mapping[str, sympy.Expr]) -> dict[str, dict[str, float]]:
    """Absolute L2 error and full-gradient H1-seminorm error of P1 nodal fields against
    exact ones (harness/norms.py, exact_errors): an independent check of what FreeFEM
    reports. `values` maps "u" to (N, 2) and "phi"/"theta" to (N,); `exact` holds u1, u2,
    phi, theta."""
    from harness.norms import exact_errors

    out = {}
    for field, nodal in values.items():
        keys = ["u1", "u2"] if nodal.ndim == 2 else [field]
        f = [numeric({"v": exact[k], "dx": sympy.diff(exact[k], X), "dy": sympy.diff(exact[k], Y)}) for k in keys]
        out[field] = exact_errors(points, triangles, nodal, [(g["v"], g["dx"], g["dy"]) for g in f])
    return out
