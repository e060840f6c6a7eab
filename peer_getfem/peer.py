"""The GetFEM peer: one level of a scene solved by GetFEM, an independent second code.

    /usr/bin/python3 peer_getfem/peer.py PROBLEM.json OUTPUT.json

PROBLEM.json (written by harness/run/peer.py) names the level's mesh (the MSH 2.2 file the
harness made for FreeFEM), the role labels, the scene's effects and data, the material's
full 3D tensors and the start ("zero" or "pressed"). OUTPUT.json holds the nodal fields in
SI units, the Newton history, the contact integrals, the time of each phase and the peak
memory. Written from docs/model.md, not from the FreeFEM scripts.

Exit codes: 0 converged; 2 bad input (one `error:` line); 3 Newton did not converge (the
output is still written) or GetFEM failed; 4 GetFEM missing.
"""

from __future__ import annotations

import json
import math
import resource
import sys
import time
from dataclasses import replace
from pathlib import Path

EXIT_INPUT, EXIT_NOT_CONVERGED, EXIT_NO_GETFEM = 2, 3, 4

try:
    import getfem as gf
    gf.util("trace level", 0)
except ImportError:
    gf = None

import numpy as np

from gmsh22 import CELL_REGION, MeshFileError, getfem_mesh, read_msh
from newton import NewtonResult, Unknowns, newton
from rotation import length, turned, unit
from terms import (CHARGE_OF, CONTACT, CONTACT_MACROS, FLOATING, Body, Problem, define_functions, macros, reduced,
                   resultants, scales, terms)

# Integration: the bulk integrands are at most of degree 2 on P1 (exact with any rule of
# degree >= 2). The contact integrals use the rules FreeFEM uses: on segments (2D) the
# 2-point Gauss rule, which is the face rule of IM_TRIANGLE(3); on triangles (3D) the
# 7-point degree-5 rule, the face rule of IM_TETRAHEDRON(5) (checked in docs/crosscheck.md).
INTEGRATION = {2: "IM_TRIANGLE(3)", 3: "IM_TETRAHEDRON(5)"}


class InputError(ValueError):
    pass


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        return fail("usage: peer.py PROBLEM.json OUTPUT.json", EXIT_INPUT)
    if gf is None:
        return fail("GetFEM is missing: install the Debian package python3-getfem", EXIT_NO_GETFEM)
    try:
        spec = json.loads(Path(argv[0]).read_text())
        result = solve(spec)
    except KeyError as exc:
        return fail(f"{argv[0]}: no {exc} in the problem", EXIT_INPUT)
    except (OSError, ValueError, TypeError, MeshFileError) as exc:
        return fail(f"{argv[0]}: {exc}", EXIT_INPUT)
    except RuntimeError as exc:  # GetFEM's own errors (its message's last line says what)
        return fail(f"GetFEM failed on {argv[0]}: {str(exc).strip().splitlines()[-1]}", EXIT_NOT_CONVERGED)
    Path(argv[1]).write_text(json.dumps(result) + "\n")
    return 0 if result["converged"] else EXIT_NOT_CONVERGED


def fail(message: str, code: int) -> int:
    sys.stderr.write(f"error: {message}\n")
    return code


def problem_of(spec: dict) -> Problem:
    dimension = int(spec["dimension"])
    if dimension not in (2, 3):
        raise InputError(f"dimension {dimension} (2 or 3)")
    # A section of an effect that is off may be absent; its values then enter no term.
    data = {k: dict(spec.get(k) or {}) for k in ("loads", "contact", "electric_contact", "thermal_contact")}
    bound = data["electric_contact"].get("L", math.inf)
    data["electric_contact"]["L"] = 1e300 if bound is None or math.isinf(float(bound)) else float(bound)
    bodies = bodies_of(spec, dimension)
    return Problem(dimension, frozenset(spec["effects"]), tuple(b for b, _ in bodies), data,
                   scales(bodies[0][1], data["electric_contact"].get("phi_f", 0.0),
                          data["thermal_contact"].get("theta_f", 0.0), data["loads"].get("electrode_potential", 0.0)))


def bodies_of(spec: dict, dimension: int) -> list[tuple[Body, dict]]:
    """Each body and its material in the scene's axes (3D tensors): the whole body with
    spec's material, or each material region (spec's "regions": the cells' label, the
    material, its poling) on its cells. A poling is the unit vector of the scene's
    dimension along which the material's axis 3 points (None: the file's own axes)."""
    regions = spec.get("regions") or [{"label": None, "material": spec["material"], "poling": spec.get("poling")}]
    plane = spec.get("plane", "strain")  # a 2D scene's geometry.plane
    if plane not in ("strain", "stress"):
        raise InputError(f"plane {plane!r} (strain or stress)")
    out = []
    for r in regions:
        material = oriented(r["material"], r.get("poling"), dimension)
        if r["label"] is None:
            body = Body("bulk", -1, "", reduced(material, dimension, plane))
        else:
            label = int(r["label"])
            body = Body(f"body{label}", CELL_REGION + label, f"R{label}", reduced(material, dimension, plane))
        out.append((body, material))
    return out


def oriented(material: dict, poling: list[float] | None, dimension: int) -> dict:
    """The material poled along `poling`; in 2D the drawing's (x, y) are the 3D axes (1, 3),
    so an in-plane axis (a, b) is the 3D axis (a, 0, b) (docs/model.md section 9)."""
    if poling is None:
        return material
    axis = np.array(poling, float) if dimension == 3 else np.array([poling[0], 0.0, poling[1]], float)
    if not (np.isfinite(axis).all() and length(axis) > 0):
        raise InputError(f"poling axis {poling} (a nonzero vector of {dimension} numbers)")
    return material if np.array_equal(unit(axis), [0.0, 0.0, 1.0]) else turned(material, axis)


def solve(spec: dict) -> dict:
    clock = time.perf_counter()
    p = problem_of(spec)
    labels = {role: int(label) for role, label in spec["labels"].items()}
    msh = read_msh(Path(spec["mesh"]), p.dimension)
    present = set(msh.labels.tolist())
    p = replace(p, floating=tuple(role for role in FLOATING if role in labels and labels[role] in present))
    if p.floating and not p.has("piezoelectric"):
        raise InputError(f"a floating electrode ({p.floating[0]}) needs the effect piezoelectric")
    mesh = getfem_mesh(gf, msh, p.dimension)
    define_functions(gf)
    mim = gf.MeshIm(mesh, gf.Integ(INTEGRATION[p.dimension]))
    mfu = gf.MeshFem(mesh, p.dimension)
    mfu.set_classical_fem(1)
    mfs = gf.MeshFem(mesh, 1)
    mfs.set_classical_fem(1)
    md = gf.Model("real")
    md.add_fem_variable("u", mfu)
    fields = ["u"] + ["phi"] * p.has("piezoelectric") + ["theta"] * p.has("thermal")
    for name in fields[1:]:
        md.add_fem_variable(name, mfs)
    for name, expr in macros(p).items():
        md.add_macro(name, expr)
    region_of = {b.role: b.region for b in p.bodies}  # the whole body (-1) or a material region's cells
    for role, expr in terms(p):
        md.add_nonlinear_term(mim, expr, region_of[role] if role in region_of else -1 if role == "bulk" else labels[role])
    unknowns = Unknowns(md, fields, dirichlet_dofs(mfu, mfs, fields, labels, p.dimension),
                        electrode(mfs, fields, labels, p), floating(mfs, labels, p))
    setup = time.perf_counter() - clock
    start = spec["start"]
    if start not in ("zero", "pressed", "given"):
        raise InputError(f"start {start!r} (zero | pressed | given)")
    pressed = lambda: pressed_state(md, mim, mfu, mfs, fields, labels, p, spec["pressed_depth"])  # noqa: E731
    first = {"zero": lambda: None, "pressed": pressed,
             "given": lambda: given_state(spec["given"], mfu, mfs, fields, p)}[start]()
    result: NewtonResult = newton(md, unknowns, first, spec["newton"], contact_state(md, mim, mfu, mfs, p, labels),
                                  pressed)
    return output(md, mim, mfu, mfs, fields, p, labels, result, setup, time.perf_counter() - clock)


def dirichlet_dofs(mfu, mfs, fields: list[str], labels: dict[str, int], dimension: int) -> dict[str, np.ndarray]:  # noqa: ANN001
    """The constrained dofs of each field, at every node of the closed Dirichlet parts:
    u on Gamma_1 (and one component on a roller side), phi on Gamma_a = Gamma_1, theta on
    Gamma_1 and Gamma_2 (docs/model.md section 1)."""
    def on(mf, roles: list[str]) -> np.ndarray:
        dofs = [np.asarray(mf.basic_dof_on_region(labels[r]), dtype=int) for r in roles if r in labels]
        return np.unique(np.concatenate(dofs)) if dofs else np.zeros(0, dtype=int)

    u = [on(mfu, ["clamped"])]
    for axis, role in enumerate(("roller_x", "roller_y", "roller_z")[:dimension]):
        dofs = on(mfu, [role])
        u.append(dofs[dofs % dimension == axis])  # u's dofs are interleaved by component
    out = {"u": np.unique(np.concatenate(u))}
    if "phi" in fields:
        out["phi"] = on(mfs, ["clamped", "ground", "electrode"])
    if "theta" in fields:
        out["theta"] = on(mfs, ["clamped", "loaded", "free", "ground", "electrode", *FLOATING])
    return out


def electrode(mfs, fields: list[str], labels: dict[str, int], p: Problem) -> dict[str, tuple[np.ndarray, float]]:  # noqa: ANN001
    """phi's dofs on the electrode part and their scaled value V/Phi (docs/model.md section 1)."""
    if "phi" not in fields or "electrode" not in labels:
        return {}
    dofs = np.asarray(mfs.basic_dof_on_region(labels["electrode"]), dtype=int)
    return {"phi": (dofs, p.data["loads"].get("electrode_potential", 0.0) / p.scales.Phi)}


def floating(mfs, labels: dict[str, int], p: Problem) -> list[tuple[np.ndarray, float]]:  # noqa: ANN001
    """phi's dofs on each floating electrode and its net free charge Q over phi's equation
    scale (docs/model.md, "Floating electrodes": phi uniform and unknown there)."""
    out = []
    for role in p.floating:
        dofs = np.asarray(mfs.basic_dof_on_region(labels[role]), dtype=int)
        out.append((dofs, float(p.data["loads"].get(CHARGE_OF[role], 0.0)) / p.scales.Sphi))
    return out


def pressed_state(md, mim, mfu, mfs, fields: list[str], labels: dict[str, int], p: Problem,  # noqa: ANN001
                  depth_m: float) -> dict[str, np.ndarray]:
    """docs/model.md section 6: Gamma_3 pushed depth_m = 2 max(eps_e, eps_c) into the foundation along
    its mean outward normal, phi = phi_f and theta = 5 K on Gamma_3, each extended into the
    body as the harmonic function that is 1 on Gamma_3 and 0 on the field's Dirichlet part."""
    contact = labels["contact"]
    w_mech = harmonic(mim, mfs, contact, [labels["clamped"]])
    normal = np.asarray(gf.asm("generic", mim, 0, "Normal", contact, md), dtype=float)
    normal /= gf.asm("generic", mim, 0, "1", contact, md)
    depth = float(depth_m)
    state = {"u": (depth / p.scales.U * np.outer(w_mech, normal)).ravel()}
    if "phi" in fields:
        state["phi"] = p.data["electric_contact"].get("phi_f", 0.0) / p.scales.Phi * w_mech
    if "theta" in fields:
        zero = [labels[r] for r in ("clamped", "loaded", "free", "ground", "electrode") if r in labels]
        state["theta"] = 5.0 / p.scales.Theta * harmonic(mim, mfs, contact, zero)
    return state


def given_state(given: dict, mfu, mfs, fields: list[str], p: Problem) -> dict[str, np.ndarray]:  # noqa: ANN001
    """A start from nodal fields in SI units (another code's solution, `given`: its "points"
    and one array per field), matched to this mesh's nodes by their coordinates."""
    points = np.array(given["points"], float)[:, :p.dimension]
    extent = float(np.ptp(points, axis=0).max())
    index = {tuple(np.round(x / extent * 1e6).astype(int)): i for i, x in enumerate(points)}

    def order(nodes: np.ndarray) -> np.ndarray:
        try:
            return np.array([index[tuple(np.round(x / extent * 1e6).astype(int))] for x in nodes])
        except KeyError:
            raise InputError("the given start's points are not this mesh's nodes") from None

    s = p.scales
    scalar = order(np.asarray(mfs.basic_dof_nodes()).T)
    vector = order(np.asarray(mfu.basic_dof_nodes()).T[::p.dimension])
    state = {"u": (np.array(given["u"], float)[:, :p.dimension][vector] / s.U).ravel()}
    for name, scale in (("phi", s.Phi), ("theta", s.Theta)):
        if name in fields:
            state[name] = np.array(given[name], float)[scalar] / scale
    return state


def harmonic(mim, mfs, one: int, zero: list[int]) -> np.ndarray:  # noqa: ANN001
    """The P1 harmonic function equal to 1 on region `one` and 0 on the regions `zero`
    (a node on both is 0)."""
    from scipy.sparse.linalg import spsolve

    stiffness = to_scipy(gf.asm_laplacian(mim, mfs, mfs, np.ones(mfs.nbdof())))
    values = np.full(mfs.nbdof(), np.nan)
    values[np.asarray(mfs.basic_dof_on_region(one), dtype=int)] = 1.0
    for region in zero:
        values[np.asarray(mfs.basic_dof_on_region(region), dtype=int)] = 0.0
    fixed = ~np.isnan(values)
    free = np.flatnonzero(~fixed)
    out = np.where(fixed, values, 0.0)
    rhs = -stiffness[free][:, np.flatnonzero(fixed)] @ out[fixed]
    out[free] = spsolve(stiffness[free][:, free].tocsc(), rhs)
    return out


def to_scipy(matrix):  # noqa: ANN001, ANN201
    from scipy.sparse import csc_matrix

    indptr, indices = matrix.csc_ind()
    return csc_matrix((matrix.csc_val(), indices, indptr), shape=matrix.size()).tocsr()


def contact_state(md, mim, mfu, mfs, p: Problem, labels: dict[str, int]):  # noqa: ANN001, ANN201
    """A function giving the contact state of Gamma_3's nodes: closed (some quadrature point
    of a face around the node penetrates, s > 0) and, with friction, slipping (c_nu |u_tau|
    >= R there, the slip bound of terms.friction). Newton stops only when the last step changed
    neither."""
    if not p.has("contact"):
        return lambda: np.zeros(0, dtype=bool)
    region = labels[CONTACT]
    probe = gf.Model("real")  # a test function per node, and u as data
    probe.add_fem_variable("z", mfs)
    probe.add_fem_data("u", mfu)
    for name, expr in macros(p).items():
        if name in CONTACT_MACROS:
            probe.add_macro(name, expr)
    kinds = ["Heaviside(Pen - 1e-300)"]
    if p.has("friction"):
        kinds.append("Heaviside(Norm(Wt) - SlipBound)")  # on the ball's rim or outside: slip

    def state() -> np.ndarray:
        probe.set_variable("u", md.variable("u"))
        return np.concatenate([np.asarray(gf.asm("generic", mim, 1, f"{k}*Test_z", region, probe)) > 0 for k in kinds])

    return state


def output(md, mim, mfu, mfs, fields: list[str], p: Problem, labels: dict[str, int], result: NewtonResult,  # noqa: ANN001
           setup_s: float, total_s: float) -> dict:
    s = p.scales
    nodes = np.asarray(mfs.basic_dof_nodes()).T
    out = {
        "converged": result.converged, "reason": result.reason, "newton_iterations": result.iterations,
        "restarted_at": result.restarted_at, "increments": result.increments, "damping": result.damping,
        "contact_changes": result.changes, "dofs": int(md.nbdof()), "points": nodes.tolist(),
        "u_points": np.asarray(mfu.basic_dof_nodes()).T[::p.dimension].tolist(),
        "u": (s.U * np.asarray(md.variable("u")).reshape(-1, p.dimension)).tolist(),
        "setup_s": setup_s, "assembly_s": result.assembly_s, "factorisation_s": result.factorisation_s,
        "solve_s": result.solve_s, "newton_s": result.newton_s, "total_s": total_s,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "getfem_version": getattr(gf, "__version__", "5.4"),
    }
    if "phi" in fields:
        out["phi"] = (s.Phi * np.asarray(md.variable("phi"))).tolist()
    if "theta" in fields:
        out["theta"] = (s.Theta * np.asarray(md.variable("theta"))).tolist()
    for name, expr in resultants(p).items():
        value = np.asarray(gf.asm("generic", mim, 0, expr, labels[CONTACT], md), dtype=float)
        out[name] = value.tolist() if value.ndim else float(value)
    return out


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
