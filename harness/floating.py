"""The floating electrode (role `floating`): whether a scene has one, the FreeFEM switch of
freefem/floating.idp, and the scenes it cannot run in (docs/model.md, "Floating electrodes")."""

from __future__ import annotations

from typing import Any

from harness.errors import SceneError

ROLE = "floating"


def roles_of(geometry: Any) -> set[str]:
    """The boundary roles a geometry of any kind (rectangle, box, gmsh) gives its parts."""
    if hasattr(geometry, "role_of_name"):
        return set(geometry.role_of_name.values())
    if hasattr(geometry, "role_areas"):
        return set(geometry.role_areas())
    return set(geometry.role_lengths())


def check_floating(table: dict[str, dict[str, Any]], geometry: Any) -> None:
    """A floating electrode needs the potential and the sequential direct solve (its exact
    elimination is written for one rank's matrices); a charge needs an electrode to sit on."""
    floating = ROLE in roles_of(geometry)
    charge = table["loads"].get("floating_charge", 0.0)  # absent: the potential is off
    if not floating:
        if charge != 0:
            raise SceneError(f"loads.floating_charge = {charge!r}: no boundary part has the role 'floating'")
        return
    if "piezoelectric" not in table["scene"]["effects"]:
        raise SceneError("geometry: the role 'floating' needs the effect 'piezoelectric' (the electric potential)")
    if any(str(v).strip() for v in table.get("manufactured", {}).values()):
        raise SceneError("geometry: the role 'floating' has no manufactured solution (its charge is a load of its own)")
    run = table["run"]
    if run["linear_solver"] == "petsc" or run["ranks"] > 1:
        raise SceneError(f"run.linear_solver = {run['linear_solver']!r}, run.ranks = {run['ranks']}: a floating "
                         "electrode is solved on one rank with a direct solver (mumps, umfpack, umfpack64)")


def floating_macros(geometry: Any) -> dict[str, str]:
    """FLOATING switches on freefem/floating.idp when a part has the role `floating`."""
    return {"FLOATING": "1"} if ROLE in roles_of(geometry) else {}
