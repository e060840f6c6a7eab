"""Floating electrodes (roles `floating`, `floating_2`, `floating_3`): which a scene has, the
FreeFEM switch of freefem/floating.idp, and the scenes it cannot run in (docs/model.md,
"Floating electrodes")."""

from __future__ import annotations

from typing import Any

from harness.core.contract import FLOATING_CHARGES, FLOATING_ROLES
from harness.core.errors import SceneError
from harness.scene.linear_solvers import accepting, solver


def roles_of(geometry: Any) -> set[str]:
    """The boundary roles a geometry of any kind (rectangle, box, gmsh) gives its parts."""
    if hasattr(geometry, "role_of_name"):
        return set(geometry.role_of_name.values())
    if hasattr(geometry, "role_areas"):
        return set(geometry.role_areas())
    return set(geometry.role_lengths())


def conductor_roles(materials: Any) -> set[str]:
    """The roles the conductor regions of [scene.materials] are tied to (harness/scene/regions.py)."""
    entries = materials.values() if isinstance(materials, dict) else ()
    return {entry.get("conductor", "") for entry in entries if isinstance(entry, dict)}


def floating_roles(geometry: Any, materials: Any = None) -> tuple[str, ...]:
    """The scene's floating electrodes, on its boundary or tied to a conductor region of
    `materials` ([scene.materials]), in the order run.json reports them."""
    present = roles_of(geometry) | conductor_roles(materials)
    return tuple(role for role in FLOATING_ROLES if role in present)


def check_floating(table: dict[str, dict[str, Any]], geometry: Any) -> None:
    """A floating electrode needs the potential and the sequential direct solve (its exact
    elimination is written for one rank's matrices); a charge needs its electrode."""
    roles = floating_roles(geometry, table["scene"]["materials"])
    for role, key in FLOATING_CHARGES.items():
        charge = table["loads"].get(key, 0.0)  # absent: the potential is off
        if role not in roles and charge != 0:
            raise SceneError(f"loads.{key} = {charge!r}: no boundary part nor conductor region has the role {role!r}")
    if not roles:
        return
    check_own_potential(table, f"geometry: the role {roles[0]!r}", "its charge is a load of its own",
                        "a floating electrode")


def check_own_potential(table: dict[str, dict[str, Any]], where: str, why_not_manufactured: str, what: str) -> None:
    """What a part whose potential the scheme itself sets (a floating electrode's elimination, a
    conductor region's Dirichlet dofs) needs: the potential, no manufactured phi, and one rank's
    direct solve (both are written for one rank's matrices)."""
    if "piezoelectric" not in table["scene"]["effects"]:
        raise SceneError(f"{where} needs the effect 'piezoelectric' (the electric potential)")
    if any(str(v).strip() for v in table.get("manufactured", {}).values()):
        raise SceneError(f"{where} has no manufactured solution ({why_not_manufactured})")
    run = table["run"]
    if not solver(run["linear_solver"]).floating or run["ranks"] > 1:
        raise SceneError(f"run.linear_solver = {run['linear_solver']!r}, run.ranks = {run['ranks']}: {what} "
                         f"is solved on one rank with a direct solver ({accepting('floating')})")


def floating_macros(geometry: Any, materials: Any = None) -> dict[str, str]:
    """FLOATING switches on freefem/floating.idp when a part or a conductor region has a floating role."""
    return {"FLOATING": "1"} if floating_roles(geometry, materials) else {}
