"""The exact value of a goal on a manufactured solution (cases/mms/*.toml, harness/scene/mms.py):
the heat and the charge through Gamma_3 of freefem/checks.idp, -int_Gamma_3 p_r(s*) phi_L(d*),
the laws of freefem/contact.idp at the exact fields, integrated by a composite Gauss-Legendre rule
of many panels to 1e-11 relative in 2D and 1e-7 in 3D (what doubling the panels moves the values
of cases/mms/contact.toml and contact3d.toml by): the laws' kinks, where the contact opens or a
ramp saturates, fall inside panels, and a kink costs O(panel^2) there. The goals' effectivity study
(harness/study/goals.py) divides the goal estimate by Q_exact - Q_h with it.

Gamma_3 is read from the geometry: the rectangle's bottom segments of role `contact` (outward
normal -y, u_nu = -u_y), or a box whose face z = 0 is all contact (u_nu = -u_z)."""

from __future__ import annotations

from typing import Callable

import numpy as np
import sympy

from harness.core.errors import SceneError
from harness.scene.mms import X, Y, Z, parse_exact
from harness.scene.scene import Scene

PANELS_2D = 20000
PANELS_3D = (600, 300)
POINTS = 4


def gauss(a: float, b: float, panels: int) -> tuple[np.ndarray, np.ndarray]:
    """A composite Gauss-Legendre rule on [a, b]: points and weights."""
    t, w = np.polynomial.legendre.leggauss(POINTS)
    edges = np.linspace(a, b, panels + 1)
    half = np.diff(edges) / 2
    mid = (edges[:-1] + edges[1:]) / 2
    return (mid[:, None] + half[:, None] * t[None, :]).ravel(), (half[:, None] * w[None, :]).ravel()


def conductance(k: float, eps: float, s: np.ndarray) -> np.ndarray:
    return k * np.clip(s / eps, 0.0, 1.0)


def exact_goal(scene: Scene, goal: str) -> float:
    """Q(x*) of `goal` (heat_through_contact, charge_through_contact) for a manufactured scene."""
    if not scene.manufactured:
        raise SceneError(f"{scene.source}: goal {goal!r} has an exact value only on a manufactured solution")
    exact = parse_exact(scene.manufactured, scene.dimension)
    sections = scene.sections
    truncation = sections.electric_contact.L
    if goal == "heat_through_contact":
        field, k, eps, far = exact.theta, sections.thermal_contact.k_c, sections.thermal_contact.eps_c, \
            sections.thermal_contact.theta_f
    elif goal == "charge_through_contact":
        field, k, eps, far = exact.phi, sections.electric_contact.k_e, sections.electric_contact.eps_e, \
            sections.electric_contact.phi_f
    else:
        raise SceneError(f"{scene.source}: goal {goal!r} has no exact value here (heat or charge through the contact)")
    gap = sections.contact.gap

    def flux(normal_u: sympy.Expr, axes: tuple[sympy.Symbol, ...], face: dict) -> Callable[..., np.ndarray]:
        s = sympy.lambdify(axes, -normal_u.subs(face) - gap, "numpy")
        d = sympy.lambdify(axes, field.subs(face) - far, "numpy")

        def f(*points: np.ndarray) -> np.ndarray:
            shape = np.broadcast(*points).shape
            sv = np.broadcast_to(s(*points), shape)
            dv = np.broadcast_to(d(*points), shape)
            return conductance(k, eps, sv) * np.clip(dv, -truncation, truncation)
        return f

    table = scene.table["geometry"]
    if scene.dimension == 2 and table.get("kind") == "rectangle":
        total = 0.0
        f = flux(exact.u2, (X,), {Y: 0})
        for a, b, role in table["bottom"]:
            if role == "contact":
                xs, ws = gauss(float(a), float(b), PANELS_2D)
                total += float(ws @ f(xs))
        return -total
    if scene.dimension == 3 and table.get("kind") == "box" and table.get("z0") == "contact":
        f = flux(exact.u3, (X, Y), {Z: 0})
        xs, wx = gauss(0.0, float(table["lx"]), PANELS_3D[0])
        ys, wy = gauss(0.0, float(table["ly"]), PANELS_3D[1])
        values = f(xs[:, None], ys[None, :])
        return -float(wx @ values @ wy)
    raise SceneError(f"{scene.source}: an exact goal needs Gamma_3 on a rectangle's bottom or a box's whole z = 0 face")
