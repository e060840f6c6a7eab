"""The one table of the quantities an engineer reads from a run (`BUILT_IN`): each quantity's
name, the run.json key it is read from (computed once, there: freefem/checks.idp,
freefem/output.idp, freefem/quantities.idp), its unit in 2D and 3D, and the effect a scene needs
for it. Every run writes those of its scene into run.json's `quantities`
(harness/run/quantities.py), and a convergence study studies each (harness/measure/quantity_study.py).

A case adds its own in a `[quantities]` section: probes (a field's value at a point) and
averages (a field's mean over a boundary part), checked when the scene loads. A probe outside
the body is refused before anything runs: against the rectangle's or the box's extent, which
is the body; a gmsh body against its bounding box here, then against its meshes
(harness/run/quantities.py: the study's coarsest level before anything runs, each level before
it runs).

The same section names the goals (`goals = [...]`, `GOAL_KINDS`): the quantities whose
discretisation error a run estimates by dual-weighted residuals (freefem/goals.idp,
docs/goals.md), each checked to be one of the scene's that the estimate supports, on a run it
supports (one rank, P1, FreeFEM's own linear solver, theta in the Newton system, no floating
electrode)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from harness.core.contract import FLOATING_ROLES, ROLE_LABELS
from harness.core.errors import SceneError


@dataclass(frozen=True)
class Quantity:
    name: str
    source: str              # its run.json key: dotted into an object, [i] into a list
    units: tuple[str, str]   # in 2D (per unit depth) and in 3D
    effect: str | None       # the effect a scene must have for it (None: every scene)
    meaning: str

    def unit(self, dimension: int) -> str:
        return self.units[0 if dimension == 2 else 1]


BUILT_IN: tuple[Quantity, ...] = (
    Quantity("contact_force_normal", "contact_force", ("N/m", "N"), "contact",
             "the normal contact force on Gamma_3, int p(s)"),
    Quantity("contact_force_tangential", "friction_force", ("N/m", "N"), "friction",
             "the magnitude of the friction force on Gamma_3"),
    Quantity("peak_contact_pressure", "peak_contact_pressure", ("N/m^2", "N/m^2"), "contact",
             "the largest contact pressure p(s) at a node of Gamma_3"),
    Quantity("contact_extent", "active_measure", ("m", "m^2"), "contact",
             "where Gamma_3 is closed (s > 0): a length in 2D, an area in 3D"),
    Quantity("charge_through_contact", "charge_in_contact", ("C/m", "C"), "electric_contact",
             "the charge entering the body through Gamma_3"),
    Quantity("heat_through_contact", "heat_in_contact", ("W/m", "W"), "thermal_contact",
             "the heat entering the body through Gamma_3"),
    Quantity("max_theta", "max_theta", ("K", "K"), "thermal", "the largest temperature"),
    Quantity("max_abs_u", "max_abs_u", ("m", "m"), None, "the largest displacement magnitude |u| at a node"),
)
# An electrode's free charge, -int D . nu over its parts [C/m; C in 3D]: the driven electrode's
# (role `electrode`) and each floating electrode's, in harness/core/contract.py FLOATING_ROLES order.
ELECTRODE_SOURCE = "checks.electrode_charge"
FLOATING_SOURCE = "checks.floating_charge"


def electrode_quantities(effects: tuple[str, ...], roles: frozenset[str]) -> tuple[Quantity, ...]:
    if "piezoelectric" not in effects:
        return ()
    out = []
    if "electrode" in roles:
        out.append(Quantity("electrode_charge.electrode", ELECTRODE_SOURCE, ("C/m", "C"), "piezoelectric",
                            "the free charge on the electrode parts"))
    present = [role for role in FLOATING_ROLES if role in roles]
    for j, role in enumerate(present):
        out.append(Quantity(f"electrode_charge.{role}", f"{FLOATING_SOURCE}[{j}]", ("C/m", "C"), "piezoelectric",
                            f"the free charge on the floating electrode {role} (the given one, as solved)"))
    return tuple(out)


def quantity_table(effects: tuple[str, ...], roles: frozenset[str], probes: tuple["Probe", ...] = (),
                   averages: tuple["Average", ...] = ()) -> tuple[Quantity, ...]:
    """Every quantity a scene with these effects, boundary roles and case quantities has."""
    built_in = tuple(q for q in BUILT_IN if q.effect is None or q.effect in effects)
    own = tuple(Quantity(p.name, f"probes[{j}]", (FIELDS[p.field][1],) * 2, None, f"{p.field} at {p.at}")
                for j, p in enumerate(probes))
    own += tuple(Quantity(a.name, f"averages[{j}]", (FIELDS[a.field][1],) * 2, None, f"the mean of {a.field} on {a.on}")
                 for j, a in enumerate(averages))
    return built_in + electrode_quantities(effects, roles) + own


def read_source(source: str, data: dict[str, Any]) -> float | None:
    """The value under `source` in run.json's data; None when the run has none."""
    value: Any = data
    for part in source.split("."):
        key, _, index = part.partition("[")
        value = value.get(key) if isinstance(value, dict) else None
        if index and isinstance(value, list):
            j = int(index.rstrip("]"))
            value = value[j] if j < len(value) else None
        elif index:
            value = None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value)


# A probe's or an average's field -> (the unknown it belongs to, its unit, its component of u:
# 0 for a scalar field). The FreeFEM name of each is harness/run/quantities.py's.
FIELDS: dict[str, tuple[str, str, int]] = {
    "u_x": ("u", "m", 1), "u_y": ("u", "m", 2), "u_z": ("u", "m", 3),
    "phi": ("phi", "V", 0), "theta": ("theta", "K", 0),
}


@dataclass(frozen=True)
class Probe:
    name: str
    field: str
    at: tuple[float, ...]


@dataclass(frozen=True)
class Average:
    name: str
    field: str
    on: str  # a boundary role


def is_name(v: Any) -> bool:
    return isinstance(v, str) and v[:1].isalpha() and all(c.isalnum() or c == "_" for c in v)


def entries(kind: str, value: Any, keys: tuple[str, ...]) -> list[dict[str, Any]]:
    if not isinstance(value, list) or not all(isinstance(e, dict) for e in value):
        raise SceneError(f"quantities.{kind} must be a list of tables like {{ {', '.join(k + ' = ...' for k in keys)} }}")
    for entry in value:
        odd = sorted(set(entry) ^ set(keys))
        if odd:
            label = entry.get("name", "?")
            raise SceneError(f"quantities.{kind} {label!r}: needs exactly the keys {', '.join(keys)} (not {odd[0]!r})")
    return value


def field_of(kind: str, name: str, field: Any, fields: tuple[str, ...], dimension: int) -> str:
    if field not in FIELDS:
        raise SceneError(f"quantities.{kind} {name!r}: field {field!r} must be one of {', '.join(FIELDS)}")
    unknown, _, component = FIELDS[field]
    if unknown not in fields or component > dimension:
        have = [f for f, (u, _, c) in FIELDS.items() if u in fields and c <= dimension]
        raise SceneError(f"quantities.{kind} {name!r}: the scene has no field {field!r} (it has {', '.join(have)})")
    return field


def parse_quantities(table: dict[str, Any], fields: tuple[str, ...], dimension: int, roles: frozenset[str],
                     bounds: tuple[tuple[float, ...], tuple[float, ...]]) -> tuple[
                         tuple[Probe, ...], tuple[Average, ...]]:
    """The section's probes and averages, each checked: a unique name that no built-in
    quantity has, a field of the scene, a point of the scene's dimension inside
    `bounds` (lowest and highest corners), a boundary role the geometry has."""
    seen: set[str] = set()

    def named(kind: str, entry: dict[str, Any]) -> str:
        name = entry["name"]
        if not is_name(name):
            raise SceneError(f"quantities.{kind} name {name!r} must be a plain name (a letter, then letters, digits, _)")
        if name in {q.name for q in BUILT_IN} or name in seen:
            raise SceneError(f"quantities.{kind} {name!r}: the name is taken (by another quantity)")
        seen.add(name)
        return name

    probes = []
    for entry in entries("probes", table.get("probes", []), ("name", "field", "at")):
        name = named("probes", entry)
        field = field_of("probes", name, entry["field"], fields, dimension)
        at = entry["at"]
        if not (isinstance(at, list) and len(at) == dimension
                and all(isinstance(c, (int, float)) and not isinstance(c, bool) and math.isfinite(c) for c in at)):
            raise SceneError(f"quantities.probes {name!r}: at = {at!r} must be a point of {dimension} coordinates")
        point = tuple(float(c) for c in at)
        lo, hi = bounds
        tol = 1e-9 * max(max(h - l for l, h in zip(lo, hi)), 1e-300)
        if any(c < l - tol or c > h + tol for c, l, h in zip(point, lo, hi)):
            raise SceneError(f"quantities.probes {name!r}: the point {point} is outside the body "
                             f"(which spans {lo} to {hi})")
        probes.append(Probe(name, field, point))
    averages = []
    for entry in entries("averages", table.get("averages", []), ("name", "field", "on")):
        name = named("averages", entry)
        field = field_of("averages", name, entry["field"], fields, dimension)
        on = entry["on"]
        if on not in ROLE_LABELS or on not in roles:
            raise SceneError(f"quantities.averages {name!r}: on = {on!r} must be a boundary role the geometry has "
                             f"({', '.join(sorted(roles))})")
        averages.append(Average(name, field, on))
    return tuple(probes), tuple(averages)


def parse_tolerances(value: Any, quantities: tuple[Quantity, ...]) -> dict[str, float]:
    """[quantities] tolerances = { <quantity> = <relative error> }: each key a quantity the scene
    has, each value a positive, finite number (a relative error, 0.01 for 1 %)."""
    if not isinstance(value, dict):
        raise SceneError(f"quantities.tolerances must be a table like {{ charge_through_contact = 0.01 }}, "
                         f"not {value!r}")
    names = [q.name for q in quantities]
    out = {}
    for name, tolerance in value.items():
        if name not in names:
            raise SceneError(f"quantities.tolerances.{name}: the scene has no quantity {name!r} "
                             f"(it has {', '.join(names)})")
        if isinstance(tolerance, bool) or not isinstance(tolerance, (int, float)) \
                or not (math.isfinite(tolerance) and tolerance > 0):
            raise SceneError(f"quantities.tolerances.{name} = {tolerance!r} must be a relative error > 0 "
                             f"(0.01 for 1 %)")
        out[name] = float(tolerance)
    return out


# The quantities whose discretisation error a run can estimate by dual-weighted residuals
# (freefem/goals.idp, docs/goals.md) -> the kind of goal functional goals.idp forms for it.
GOAL_KINDS = {"heat_through_contact": "Heat", "charge_through_contact": "Charge",
              "electrode_charge.electrode": "Electrode"}


def parse_goals(value: Any, quantities: tuple[str, ...], why_not: str) -> tuple[str, ...]:
    """The section's goals: each a quantity of the scene that goals.idp can estimate, once;
    `why_not` says why this scene's run cannot estimate any (empty: it can)."""
    if not isinstance(value, list) or not all(isinstance(g, str) for g in value):
        raise SceneError(f"quantities.goals must be a list of quantity names, e.g. [\"heat_through_contact\"] (not {value!r})")
    can = [g for g in GOAL_KINDS if g in quantities]
    for goal in value:
        if goal not in can:
            raise SceneError(f"quantities.goals {goal!r}: not a goal this scene can estimate "
                             f"(it can: {', '.join(can) or 'none'})")
        if value.count(goal) > 1:
            raise SceneError(f"quantities.goals {goal!r}: named twice")
    if value and why_not:
        raise SceneError(f"quantities.goals {value[0]!r}: goal estimates need {why_not}")
    return tuple(value)
