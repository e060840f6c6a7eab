"""The physical checks of a converged run: every quantity is FreeFEM's
(freefem/checks.idp, written to run.json); this module only compares them with their
tolerances, each relative to a named scale, and says why each tolerance is what it is."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from harness.core.errors import HarnessError
from harness.measure.fields import Fields
from harness.mesh.simplex import boundary_facets, outward_normals, signed_measures, turned_over
from harness.run.record import RunRecord
from harness.scene.scene import Scene

# Tolerances of the physical checks, each relative to the named scale, and why.
TOLERANCES: dict[str, tuple[float, str]] = {
    "force": (2.0, "applied load + clamp reaction + contact force = 0 holds exactly up to Newton's "
                   "final residual (the sum of all test functions is a rigid translation), so the "
                   "imbalance must stay below its Cauchy-Schwarz bound sqrt(N_u) ||R_u|| S_u "
                   "(force_residual_bound; N_u displacement dofs, S_u the mechanical equation "
                   "scale) times this factor, plus 1e-12 of the force scale or ROUNDINGS machine "
                   "epsilons of the terms summed (force_reading), the larger, for the sums' round-off. "
                   "Measured: <= 0.85 of the bound; the bound is <= 4e-8 of the forces (pressed "
                   "branch, n = 64, where internal stresses ~8e6 Pa carry 1e2 N/m resultants) and "
                   "the imbalance <= 6e-12 on the barely-touching branch"),
    "sigma_nu": (1e-6, "sigma_nu = -c_nu (s)_+ <= 0 at every node up to the nodal residual; relative "
                       "to the larger of max |sigma_nu|, the mean applied traction on Gamma_3 and "
                       "the round-off floor (floor, traction_reading); measured <= 6.3e-14"),
    "sigma_tau": (1e-6, "|sigma_tau| = |P_B(c_nu u_tau)| <= S up to the nodal residual: the excess "
                        "over S relative to S + 1e-4 sigma_nu's scale, i.e. |sigma_tau| <= S (1 + 1e-6) "
                        "+ 1e-10 of the traction scale, or the round-off floor where that is larger "
                        "(Coulomb's bound is 0 where the contact is open); measured <= 3.4e-9"),
    "open_flux": (1e-6, "no flux where p_r = 0: the flux read from the bulk at an open node (s <= 0) "
                        "equals what the contact term of the residual puts there (checks.idp: 2-point "
                        "Gauss, a Gauss point of a segment to a closed neighbour can be closed; 0 when "
                        "its support is open; theta-Dirichlet nodes skipped in both); relative to the "
                        "largest nodal flux on Gamma_3 (floors: FLOOR, and floor of the flux reading); "
                        "measured <= 2.3e-12"),
    "heat": (1e-8, "heat in through Gamma_3 + sources = heat out through the Dirichlet boundary is "
                   "exact up to Newton's final residual (the constant is a test function); relative to "
                   "the largest of the three (floors: FLOOR, and floor of the heat reading), "
                   "at most this or the force check's factor times the Cauchy-Schwarz bound of the "
                   "residual's sum, sqrt(N_theta) ||R_theta|| S_theta (heat_residual_bound), the "
                   "larger; measured <= 5.6e-14"),
    "charge": (1e-8, "charge balance, as the heat balance (charge_residual_bound); measured <= 1.4e-11, "
                     "and 2.9e-7 within a bound of 6.6e-6 where nothing carries charge out (the paper's "
                     "scene with both ends free, n = 16: 2.9e-12 C/m in through Gamma_3, Newton's "
                     "residual, against a floor of 1e-5 C/m)"),
    "floating": (1e-8, "a floating electrode's free charge read from the residual (the sum of its nodes' "
                       "reactions, as electrode_charge) equals the given loads.floating_charge: the "
                       "eliminated unknown's equation is that sum, so it holds up to Newton's final "
                       "residual, as the charge balance; relative to the larger of |Q| and the round-off "
                       "floor of the terms summed (floating_charge_reading); measured <= 1.1e-15 of Q, "
                       "2e-16 of the reading for Q = 0 (tests/test_floating.py, n = 2, 4, 8)"),
}


def contact_nodes(scene: Scene, fields: Fields) -> list[np.ndarray]:
    """Indices of the nodes on Gamma_3, whatever its place and normal (the scene's geometry
    says which points lie on it: harness/scene/segments.py, box.py, gmsh_geometry.py); in 2D sorted
    along the tangent, so consecutive nodes of one straight part bound a Gamma_3 edge."""
    mask = scene.geometry.contact_mask(fields.points)
    on = np.flatnonzero(mask)
    if scene.dimension == 2 and len(on):
        normal = contact_normal(scene, fields, mask)
        along = fields.points[on, :2] @ np.array([-normal[1], normal[0]])
        on = on[np.argsort(along, kind="stable")]
    return [on]


def contact_normal(scene: Scene, fields: Fields, mask: np.ndarray | None = None) -> np.ndarray:
    """Gamma_3's outward unit normal, from the mesh's boundary facets on it (their mean: the
    contact part is flat, harness/mesh/gmsh_mesh.py check_flat_contact); `mask`: the nodes on
    Gamma_3 when the caller has them (geometry.contact_mask)."""
    cells = turned_over(fields.cells, signed_measures(fields.points, fields.cells) < 0)
    facets = boundary_facets(cells)
    mask = scene.geometry.contact_mask(fields.points) if mask is None else mask
    facets = facets[mask[facets].all(axis=1)]
    if not len(facets):
        raise HarnessError(f"{fields.source}: no boundary facet lies on Gamma_3")
    mean = outward_normals(fields.points, facets).mean(axis=0)
    return mean / np.linalg.norm(mean)


def contact_node_count(scene: Scene, fields: Fields) -> int:
    """How many nodes lie on Gamma_3."""
    return int(scene.geometry.contact_mask(fields.points).sum())


def contact_length(scene: Scene) -> float:
    """|Gamma_3|: a length in 2D, an area in 3D."""
    return scene.geometry.contact_measure()


# Of the largest flux per unit length each conductance could carry (checks.idp's
# natural_*_flux, k_r times the foundation's drive, W/m^2 and C/m^2; times |Gamma_3| for a
# total): the floor of the flux checks' scales, where no flux passes at all (an open
# contact) and a relative test would compare round-off with round-off. FLOOR of it is 1e8
# times round-off (~1e-20 C/m and W/m here) and over 500 times below the smallest flow
# that does pass in the suite (charge 4.7e-7 C/m against a floor of 8.8e-10 on the
# paper's scene).
FLOOR = 1e-10
# W/m or C/m: a floor of the balance scale, 23 decades below the smallest flow that passes
# in the suite (4.7e-7 C/m), so a 0/0 is not a failure.
NOTHING_FLOWS = 1e-30

# The round-off floor: a check's imbalance also passes when it is below ROUNDINGS machine
# epsilons of `reading`, the size of the terms it is summed from (checks.idp: |K_ii x_i| +
# |b_i|, the loads and the bulk of the mesh at the state; per unit of a node's share of
# Gamma_3 for a nodal traction or flux, over the body for a balance). An open contact carries
# no traction and no flux: its readings are round-off, measured <= 6 eps of `reading` (the
# open cantilever, cases/cantilever.toml with a 1 um gap, n = 8: charge flux 1.3e-17 C/m^2 of
# 9.8e-3, sigma_nu 6.3e-8 N/m^2 of 3.8e8), so 1000 roundings leave a margin over 150 and
# still fail any imbalance above 2.2e-13 of the terms.
ROUNDINGS = 1e3
EPS = float(np.finfo(float).eps)
# The quantum of a contact flow: each nodal phi (theta) is one double, half an ulp <= eps |phi| / 2
# from the discrete solution, and forming the law's flux p_r(s) (Phi ph - phi_f) rounds by
# eps |phi| / 2 and eps |phi - phi_f| / 2 more: the flow through Gamma_3 is known to within
# QUANTA = 1 eps of int p_r(s) (|phi| + |phi_f|) (checks.idp's *_contact_reading), whatever
# Newton does. Against the flow int p_r(s) (phi - phi_f), that floor exceeds the check's
# tolerance only where the contact pins phi to phi_f within eps / 1e-8 = 2.2e-8 of
# |phi| + |phi_f|, i.e. where the foundation's conductance dwarfs the body's: alumina (beta 140
# times below BaTiO3's) pressed on the paper's foundation leaves phi - phi_f ~ 3e-10 of that,
# and its charge imbalance is 2.2e-8 to 7.1e-8 of the flow, 0.03 to 0.09 eps of the reading
# (n = 4, 8, 16; tests/test_materials.py). Everywhere else the check is as strict as before:
# on the paper's scene the imbalance it allows, eps times the reading, is 9.4e-16 of the charge
# flow and 2.2e-16 of the heat flow (n = 4; the check allows 1e-8), and no flow of
# results/stress/ has phi - phi_f (theta - theta_f) below 2.6e-5 of the sum.
QUANTA = 1.0


def floors(c: dict[str, Any], length: float) -> dict[str, float]:
    """The floor of each check's scale, in the flow's units: every floor rule is here, once
    (docs/hard-cases.md, "Round-off floors"). A check compares its imbalance with its
    tolerance times the larger of its flow and this floor:

        floor = max(ROUNDINGS eps reading / tolerance, QUANTA eps contact reading / tolerance,
                    what the loads could drive)

    the second being FLOOR of the foundation's natural flux for the heat and charge checks (a
    contact that never closes: the state never sees theta_f, phi_f) and NOTHING_FLOWS.
    `force` is absolute [N/m; N in 3D]: its check adds it to Newton's residual bound."""

    def roundoff(key: str, check: str) -> float:
        return ROUNDINGS * EPS * c.get(key, 0.0) / TOLERANCES[check][0]

    natural = {name: c.get(f"natural_{name}_flux", 0.0) for name in ("heat", "charge")}
    out = {
        "force": ROUNDINGS * EPS * c.get("force_reading", 0.0),
        "sigma_nu": roundoff("traction_reading", "sigma_nu"),
        "sigma_tau": roundoff("traction_reading", "sigma_tau"),
    }
    for name in ("heat", "charge"):
        quantum = QUANTA * EPS * c.get(f"{name}_contact_reading", 0.0) / TOLERANCES[name][0]
        out[name] = max(roundoff(f"{name}_reading", name), quantum, FLOOR * natural[name] * length, NOTHING_FLOWS)
        out[f"{name}_open_flux"] = max(roundoff(f"{name}_flux_reading", "open_flux"), FLOOR * natural[name], 1e-300)
    # One per floating electrode (run.json's lists, in harness/core/contract.py FLOATING_ROLES order).
    out["floating"] = [max(ROUNDINGS * EPS * reading / TOLERANCES["floating"][0], NOTHING_FLOWS)
                       for reading in c.get("floating_charge_reading", [])]
    return out


def balance_allowance(name: str, out: dict[str, Any]) -> float:
    """What the heat or charge balance may miss by: its tolerance, or Newton's final residual's
    bound times the force check's factor where that is larger (both relative to the flow)."""
    return max(TOLERANCES[name][0], TOLERANCES["force"][0] * out[f"{name}_residual_bound"])


def physical_checks(record: RunRecord, scene: Scene) -> dict[str, Any]:
    """The checks of issue 4 on a converged run: values, the scale each is relative to, and
    a pass flag per check (TOLERANCES). Every quantity is FreeFEM's (freefem/checks.idp);
    this only compares (`checks` holds the keys record.CHECK_KEYS declares)."""
    c = record.checks or {}
    tol = {name: value for name, (value, _) in TOLERANCES.items()}
    length = contact_length(scene)
    applied = float(np.linalg.norm(c.get("applied_load", [0.0, 0.0])))
    floor = floors(c, length)
    sigma_scale = max(abs(c.get("max_sigma_nu", 0.0)), abs(c.get("min_sigma_nu", 0.0)), applied / max(length, 1e-300),
                      floor["sigma_nu"])
    # checks.idp's force scale, the largest of the three forces it balances [N/m; N in 3D]
    forces = max(float(np.linalg.norm(c.get(key, [0.0])))
                 for key in ("applied_load", "clamp_reaction", "contact_force_on_body"))
    S = c.get("S", math.inf)
    tau = c.get("max_abs_sigma_tau", 0.0)
    out: dict[str, Any] = {
        "force_imbalance": c.get("force_imbalance", math.nan),
        # checks.idp's Cauchy-Schwarz bound of the final residual's sum; absent: the strict check
        "force_residual_bound": c.get("force_residual_bound", 0.0),
        "max_sigma_nu": c.get("max_sigma_nu", math.nan),
        "sigma_nu_scale": sigma_scale,
        "max_abs_sigma_tau": tau,
        "S": S,
        "sigma_tau_over_S": tau / S if S > 0 else math.nan,
        # > 0 when |sigma_tau| exceeds S; relative to S plus 1e-4 of the traction scale (the
        # nodal reading's error follows the load, not S: S = 0, or S = 8.5 under 1e8 N/m^2),
        # or to the readings' round-off floor (Coulomb's S = 0 where the contact is open)
        "sigma_tau_excess": (tau - S) / max(S + 1e-4 * sigma_scale, floor["sigma_tau"]) if math.isfinite(S) else -1.0,
    }
    # The force imbalance's round-off allowance, relative to the force scale as the imbalance.
    force_floor = max(1e-12, floor["force"] / max(forces, 1e-300))
    natural = {name: c.get(f"natural_{name}_flux", 0.0) for name in ("heat", "charge")}
    flows = {"heat": (record.heat_in_contact or 0.0, c.get("heat_source", 0.0), c.get("heat_out_dirichlet", 0.0)),
             "charge": (record.charge_in_contact or 0.0, c.get("charge_source", 0.0), c.get("charge_out_dirichlet", 0.0))}
    # A driven electrode's charge leaves through the ground and the clamps: the net charge out
    # of the Dirichlet parts is then ~0 and the electrode's own charge is the flow's size.
    electrode = {"heat": 0.0, "charge": abs(c.get("electrode_charge", 0.0))}
    driven_electrode = {"heat": False, "charge": scene.sections.loads.electrode_potential != 0}
    for name, (into, source, leaving) in flows.items():
        # FreeFEM's {name}_imbalance, with a floor for a contact that carries nothing.
        scale = max(abs(into), abs(source), abs(leaving), electrode[name], floor[name])
        out[f"{name}_imbalance"] = abs(into + source - leaving) / scale
        # Newton's final residual's bound on the same scale (checks.idp: sqrt(N) ||R|| S; absent: 0).
        out[f"{name}_residual_bound"] = c.get(f"{name}_residual_bound", 0.0) / scale
        # Nothing drives this flow (no conductance drive, no source: `block`'s phi_f = theta_f = 0,
        # `heated`'s charge, `heat` without a contact part): the exact flow is zero and every term
        # round-off of the bulk flux, whose size run.json does not give; the balance then has
        # nothing to compare with.
        out[f"{name}_driven"] = natural[name] * length > 0 or abs(source) > 0 or driven_electrode[name]
    open_ok = True
    for name in ("heat", "charge"):
        found = c.get(f"max_{name}_flux_open", math.nan)
        # What the contact law puts at open nodes (checks.idp); absent: no open node may carry any.
        expected = c.get(f"max_{name}_flux_open_expected", 0.0)
        scale = max(c.get(f"max_{name}_flux_contact", 0.0), floor[f"{name}_open_flux"])
        out[f"max_{name}_flux_open"] = found
        out[f"{name}_flux_open_expected"] = expected
        out[f"{name}_flux_open_error"] = abs(found - expected) / scale
        open_ok &= out[f"{name}_flux_open_error"] <= tol["open_flux"]
    out.update({
        "force_ok": out["force_imbalance"] <= tol["force"] * out["force_residual_bound"] + force_floor,
        "sigma_nu_ok": out["max_sigma_nu"] <= tol["sigma_nu"] * sigma_scale,
        "sigma_tau_ok": out["sigma_tau_excess"] <= tol["sigma_tau"],
        "open_flux_ok": bool(open_ok),
        "heat_ok": out["heat_imbalance"] <= balance_allowance("heat", out) or not out["heat_driven"],
        "charge_ok": out["charge_imbalance"] <= balance_allowance("charge", out) or not out["charge_driven"],
    })
    if "floating_charge" in c:
        # The worst electrode's: |charge read - given| relative to the larger of |given| and its floor.
        out["floating_charge_error"] = max(abs(read - given) / max(abs(given), low) for read, given, low
                                           in zip(c["floating_charge"], c["floating_charge_given"], floor["floating"]))
        out["floating_ok"] = out["floating_charge_error"] <= tol["floating"]
    out["checks_ok"] = all(out[k] for k in CHECK_FLAGS + SCENE_FLAGS if k in out)
    return out


CHECK_FLAGS = ("force_ok", "sigma_nu_ok", "sigma_tau_ok", "open_flux_ok", "heat_ok", "charge_ok")
# Checks of a part only some scenes have (a floating electrode): judged when the run reports
# it, never said to be missing otherwise.
SCENE_FLAGS = ("floating_ok",)
