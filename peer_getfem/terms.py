"""The residual of docs/model.md section 2-3 in GetFEM's weak-form language (GWFL), on
dimensionless unknowns.

Unknowns u^ = u/U, phi^ = phi/Phi, theta^ = theta/Theta; each equation divided by its size
(Su, Sphi, Stheta). The scales are the model's (docs/model.md section 4): Phi the largest imposed
potential (the foundation's or an electrode's) and Theta the foundation's temperature (each at
least 1), U = Phi sqrt(beta11/C11), so the blocks
of the tangent are O(1) instead of spanning 1e20. GetFEM differentiates each term
automatically: the tangent is exact, with pos_part's derivative Heaviside(0) = 1 (a point
exactly at the gap counts as closed, as the model's tangent takes it).

Strains and stresses are Voigt vectors along the material axes: in 3D (11, 22, 33, 23, 13,
12) with engineering shears; in 2D the plane-strain reduction to the material's 1-3 plane
drawn as x-y, i.e. rows and columns (11, 33, 13) of C, rows (1, 3) of e, beta, k and p.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Plane strain: the Voigt entries (0-based) and field axes of the 3D material that act in 2D.
PLANE_VOIGT = [0, 2, 4]
PLANE_AXES = [0, 2]

# Role labels (harness/core/contract.py ROLE_LABELS), the GetFEM region numbers.
CLAMPED, LOADED, FREE, CONTACT = "clamped", "loaded", "free", "contact"
# Floating electrodes (open conductors of Gamma_2: loaded by f2, theta = 0 there), and the
# [loads] key of each one's net free charge.
FLOATING = ("floating", "floating_2", "floating_3")
CHARGE_OF = {role: "floating_charge" + role.removeprefix("floating") for role in FLOATING}
# The macros of the contact state (macros()): they read u alone, not phi or theta.
CONTACT_MACROS = ("Pen", "UTau", "SlipBound", "Wt", "Ptau")


@dataclass(frozen=True)
class Scales:
    U: float
    Phi: float
    Theta: float
    Su: float
    Sphi: float
    Stheta: float


def scales(material: dict, phi_f: float, theta_f: float, electrode_v: float = 0.0) -> Scales:
    c0, b0, k0 = material["C"][0][0], material["beta"][0][0], material["k"][0][0]
    phi, theta = max(abs(phi_f), abs(electrode_v), 1.0), max(abs(theta_f), 1.0)
    u = phi * np.sqrt(b0 / c0)
    return Scales(u, phi, theta, c0 * u, b0 * phi, k0 * theta)


def reduced(material: dict, dimension: int, plane: str = "strain") -> dict[str, np.ndarray]:
    """C (nv x nv), e (d x nv), beta and k (d x d), m (nv), p (d) for the dimension. In plane
    stress (2D) the out-of-plane normal stress sigma_22 = 0 is condensed out first: eps_22 solved
    from it and put back into the other rows (docs/model.md section 8)."""
    c, e = np.array(material["C"], float), np.array(material["e"], float)
    beta, k = np.array(material["beta"], float), np.array(material["k"], float)
    m, p = np.array(material["m"], float), np.array(material["p"], float)
    if dimension == 2 and plane == "stress":
        # sigma = C eps + e^T grad(phi) - theta m, D = e eps - beta grad(phi) - theta p, with
        # eps_22 = -(C[1] . eps + e[:, 1] . grad(phi) - m[1] theta) / C[1, 1] (row 1 of the Voigt set).
        c22, c2, e2, m2 = c[1, 1], c[:, 1].copy(), e[:, 1].copy(), m[1]
        c, e = c - np.outer(c2, c2) / c22, e - np.outer(e2, c2) / c22
        beta, m, p = beta + np.outer(e2, e2) / c22, m - c2 * m2 / c22, p - e2 * m2 / c22
    if dimension == 3:
        return {"C": c, "e": e, "beta": beta, "k": k, "m": m, "p": p}
    v, a = PLANE_VOIGT, PLANE_AXES
    return {"C": c[np.ix_(v, v)], "e": e[np.ix_(a, v)], "beta": beta[np.ix_(a, a)], "k": k[np.ix_(a, a)],
            "m": m[v], "p": p[a]}


def num(x: float) -> str:
    return repr(float(x))


def matrix(a: np.ndarray) -> str:
    """A GWFL matrix or column-vector literal."""
    if a.ndim == 1:
        return "[" + "; ".join(num(x) for x in a) + "]"
    return "[" + "; ".join(", ".join(num(x) for x in row) for row in a) + "]"


def voigt_strain(g: str, dimension: int) -> str:
    """The engineering Voigt strain of the displacement whose gradient is `g`."""
    if dimension == 2:
        return f"[{g}(1,1); {g}(2,2); {g}(1,2)+{g}(2,1)]"
    return (f"[{g}(1,1); {g}(2,2); {g}(3,3); {g}(2,3)+{g}(3,2); {g}(1,3)+{g}(3,1); {g}(1,2)+{g}(2,1)]")


def voigt_to_tensor(s: str, dimension: int) -> str:
    if dimension == 2:
        return f"[{s}(1), {s}(3); {s}(3), {s}(2)]"
    return f"[{s}(1), {s}(6), {s}(5); {s}(6), {s}(2), {s}(4); {s}(5), {s}(4), {s}(3)]"


@dataclass(frozen=True)
class Body:
    """A part of the body with one material (reduced): the whole body ("bulk"), or the
    cells of one material region, GetFEM region `region`, whose law macros carry `suffix`."""

    role: str
    region: int
    suffix: str
    material: dict[str, np.ndarray]


@dataclass(frozen=True)
class Problem:
    """What the residual needs: dimension, effects, the bodies' materials, data, scales."""

    dimension: int
    effects: frozenset[str]
    bodies: tuple[Body, ...]
    data: dict[str, dict[str, float]]
    scales: Scales
    floating: tuple[str, ...] = ()  # the floating electrodes' roles the mesh has

    def has(self, effect: str) -> bool:
        return effect in self.effects


def law_macros(p: Problem, body: Body) -> dict[str, str]:
    """The physical stress (Voigt), electric displacement and heat flux of one material, in SI
    units, from the scaled unknowns."""
    s, d, mat, x = p.scales, p.dimension, body.material, body.suffix
    sigma = f"({num(s.U)}*({matrix(mat['C'])}*{voigt_strain('Grad_u', d)}))"
    dfield = f"(-{num(s.Phi)}*({matrix(mat['beta'])}*Grad_phi))" if p.has("piezoelectric") else ""
    if p.has("piezoelectric"):
        # Converse piezoelectric effect: + e^T grad(phi) in sigma; direct: + e eps(u) in D.
        sigma += f" + {num(s.Phi)}*(({matrix(mat['e'])})'*Grad_phi)"
        dfield += f" + {num(s.U)}*({matrix(mat['e'])}*{voigt_strain('Grad_u', d)})"
    if p.has("thermal"):
        sigma += f" - {num(s.Theta)}*theta*{matrix(mat['m'])}"
    if p.has("pyroelectric"):
        dfield += f" - {num(s.Theta)}*theta*{matrix(mat['p'])}"
    out = {f"SigV{x}": f"({sigma})"}
    if p.has("piezoelectric"):
        out[f"Dv{x}"] = f"({dfield})"
    if p.has("thermal"):
        out[f"Qv{x}"] = f"(-{num(s.Theta)}*({matrix(mat['k'])}*Grad_theta))"
    return out


def macros(p: Problem) -> dict[str, str]:
    """GWFL macros: each body's law (law_macros) and the contact quantities."""
    s = p.scales
    out = {name: expr for body in p.bodies for name, expr in law_macros(p, body).items()}
    if p.has("contact"):
        c = p.data["contact"]
        out["Pen"] = f"({num(s.U)}*(u.Normal) - {num(c['gap'])})"  # s = u_nu - g [m]
        out["UTau"] = f"({num(s.U)}*(u - (u.Normal)*Normal))"  # u_tau [m]
    if p.has("friction"):
        out.update(friction(c))
    return out


def define_functions(gf) -> None:  # noqa: ANN001 (the getfem module)
    """GWFL functions the macros call. AtRest(t) = H(-t), 1 at t = 0 and 0 for t > 0, as an
    indicator whose derivative is 0 (GetFEM will not differentiate Heaviside): it selects a
    tangent, it is not a term of the residual."""
    gf.asm_define_function("AtRest", 1, "Heaviside(-t)", "0")


def friction(c: dict[str, float]) -> dict[str, str]:
    """The friction law, once (docs/laws.md): the tangential traction P_B(0,R)(w), w = c_nu u_tau,
    the projection onto the ball of radius R in the tangent space (an interval in 2D, a disc in
    3D), whose derivative GetFEM takes itself, in w and in R; and the ball's radius, which also
    tells stick (|w| < R) from slip (|w| >= R) in the contact state.

    R is the slip bound: Tresca's S, or Coulomb's mu times the normal pressure c_nu (s)_+
    (contact.friction_law). Coulomb's ball is a point where the contact is open; a point at
    rest there (w = 0 exactly, the zero and pressed starts) counts as sticking, as in the
    model's tangent (H(0) = 1 for the normal law likewise): its radius is lifted to 1 N/m^2
    while w = 0. That changes no value, P_B(0) = 0 for any radius, only the tangent (c_nu I
    instead of GetFEM's 0 for a ball of radius 0) and the stick/slip state, so that Newton's
    path is the model's. Tresca keeps S as it is (S = 0 slips)."""
    law = c.get("friction_law", "tresca")
    if law == "tresca":
        bound = num(c["S"])
    elif law == "coulomb":
        at_rest = "AtRest(Norm_sqr(UTau))"  # 1 where u_tau = 0 (|u_tau| < 1e-154 m), else 0
        bound = f"({num(c.get('mu', 0.0))}*{num(c['c_nu'])}*pos_part(Pen) + {at_rest})"
    else:
        raise ValueError(f"contact.friction_law {law!r} (tresca | coulomb)")
    return {"SlipBound": bound, "Wt": f"({num(c['c_nu'])}*UTau)", "Ptau": "Ball_projection(Wt, SlipBound)"}


def truncated(t: str, bound: float) -> str:
    """phi_L(t) = max(-L, min(L, t)), written with pos_part so that L = 1e300 is exact."""
    return f"(({t}) - pos_part(({t}) - {num(bound)}) + pos_part(-({t}) - {num(bound)}))"


def conductance(k: float, eps: float) -> str:
    """p_r(s) = k min(max(s/eps, 0), 1), derivative k/eps on [0, eps), 0 elsewhere."""
    return f"({num(k)}*(pos_part(Pen/{num(eps)}) - pos_part(Pen/{num(eps)} - 1)))"


def terms(p: Problem) -> list[tuple[str, str]]:
    """(region role or "bulk", GWFL residual term) pairs, each already divided by its
    equation's scale. The residual is docs/model.md's R_u, R_phi, R_theta."""
    s, d, loads = p.scales, p.dimension, p.data["loads"]
    axes = "xyz"[:d]
    out = [(b.role, f"({voigt_to_tensor('SigV' + b.suffix, d)}):Grad_Test_u/{num(s.Su)}") for b in p.bodies]
    traction = [loads.get(f"traction_{a}", 0.0) for a in axes]
    body = [loads.get(f"body_force_{a}", 0.0) for a in axes]
    if any(traction):
        out.extend((role, f"-({matrix(np.array(traction))}.Test_u)/{num(s.Su)}") for role in (LOADED, *p.floating))
    if any(body):
        out.append(("bulk", f"-({matrix(np.array(body))}.Test_u)/{num(s.Su)}"))
    if p.has("piezoelectric"):
        out.extend((b.role, f"-(Dv{b.suffix}.Grad_Test_phi)/{num(s.Sphi)}") for b in p.bodies)
        if loads.get("surface_charge", 0.0):
            for role in (LOADED, FREE):  # Gamma_b: D.nu = phi2, entering R_phi with +
                out.append((role, f"{num(loads['surface_charge'])}*Test_phi/{num(s.Sphi)}"))
        if loads.get("charge_density", 0.0):
            out.append(("bulk", f"-{num(loads['charge_density'])}*Test_phi/{num(s.Sphi)}"))
    if p.has("thermal"):
        out.extend((b.role, f"-(Qv{b.suffix}.Grad_Test_theta)/{num(s.Stheta)}") for b in p.bodies)
        if loads.get("heat_source", 0.0):
            out.append(("bulk", f"-{num(loads['heat_source'])}*Test_theta/{num(s.Stheta)}"))
    if p.has("contact"):
        c = p.data["contact"]
        # Normal compliance: sigma_nu = -c_nu (u_nu - g)_+, tested with v_nu.
        out.append((CONTACT, f"{num(c['c_nu'])}*pos_part(Pen)*(Test_u.Normal)/{num(s.Su)}"))
        if p.has("friction"):  # sigma_tau = -P_B(0,R)(c_nu u_tau), tested with v_tau
            out.append((CONTACT, f"(Ptau.Test_u)/{num(s.Su)}"))
    if p.has("electric_contact"):
        e = p.data["electric_contact"]
        flux = conductance(e["k_e"], e["eps_e"]) + "*" + truncated(num(s.Phi) + "*phi - " + num(e["phi_f"]), e["L"])
        out.append((CONTACT, f"{flux}*Test_phi/{num(s.Sphi)}"))
    if p.has("thermal_contact"):
        t, bound = p.data["thermal_contact"], p.data["electric_contact"]["L"]
        flux = conductance(t["k_c"], t["eps_c"]) + "*" + truncated(num(s.Theta) + "*theta - " + num(t["theta_f"]), bound)
        out.append((CONTACT, f"{flux}*Test_theta/{num(s.Stheta)}"))
    return out


def resultants(p: Problem) -> dict[str, str]:
    """The contact integrals over Gamma_3 the harness compares (SI units): the normal force
    int c_nu (u_nu - g)_+, the friction force vector int P_B(c_nu u_tau), and the heat and
    charge entering the body, minus the outward fluxes (2.13), (2.15)."""
    out: dict[str, str] = {}
    if not p.has("contact"):
        return out
    c = p.data["contact"]
    out["contact_force"] = f"{num(c['c_nu'])}*pos_part(Pen)"
    if p.has("friction"):
        out["friction_force_vector"] = "Ptau"
    if p.has("electric_contact"):
        e = p.data["electric_contact"]
        out["charge_in_contact"] = "-" + conductance(e["k_e"], e["eps_e"]) + "*" + truncated(
            num(p.scales.Phi) + "*phi - " + num(e["phi_f"]), e["L"])
    if p.has("thermal_contact"):
        t, bound = p.data["thermal_contact"], p.data["electric_contact"]["L"]
        out["heat_in_contact"] = "-" + conductance(t["k_c"], t["eps_c"]) + "*" + truncated(
            num(p.scales.Theta) + "*theta - " + num(t["theta_f"]), bound)
    return out
