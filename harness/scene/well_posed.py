"""What fixes each field of a scene, one rule for the rectangle, the box and gmsh scenes.

Without a Dirichlet part (or a term that acts like one), u can move as a rigid body and φ or
θ is defined only up to a constant: Newton's matrix is singular, and the run ends late and
obscurely (a rectangle with both ends free hit Newton's maximum; the box, a Krylov residual
of 1.96e10). Such a scene is refused when it loads, naming the field and what would fix it.
"""

from __future__ import annotations

from typing import Any, Collection, Protocol

import numpy as np

from harness.core.errors import SceneError
from harness.scene.schema import FRICTION_LAWS

# The roles with a Dirichlet condition on each field: freefem/dimension.idp onU (u),
# freefem/forms.idp vDirP (φ) and vDirT (θ).
PHI_FIXED = ("clamped", "ground", "electrode")
THETA_FIXED = ("clamped", "loaded", "free", "ground", "electrode")
# Rollers along each axis (harness/core/contract.py ROLE_LABELS), each holding u along its axis.
ROLLERS = ("roller_x", "roller_y", "roller_z")


class Geometry(Protocol):
    dimension: int

    def used_roles(self) -> frozenset[str]: ...

    def contact_normals(self) -> np.ndarray: ...


def friction_holds(effects: Collection[str], contact: dict[str, Any]) -> bool:
    """Whether a pressed contact part holds the body tangentially: the friction effect with
    a slip bound that is not identically zero (Tresca S > 0, or Coulomb mu > 0: the law's
    key of schema.FRICTION_LAWS)."""
    if "friction" not in effects:
        return False  # (and the friction keys are not in the resolved table)
    return contact[FRICTION_LAWS[contact["friction_law"]]] > 0


def u_fixed(geometry: Geometry, effects: Collection[str], contact: dict[str, Any]) -> bool:
    """A clamp holds u; so does a pressed contact part with friction. Otherwise the directions
    held must span space: each roller's axis, and (with the contact effect) the contact
    part's normals, which the normal penalty holds once pressed (tests/data/block3d.toml:
    rollers on the x and y faces, the foundation under z0). As for the rollers' axes (on
    flat sides normal to them, docs/geometry.md), the rotations are taken as held with them."""
    used = geometry.used_roles()
    if "clamped" in used:
        return True
    pressed = "contact" in used and "contact" in effects
    if pressed and friction_holds(effects, contact):
        return True
    d = geometry.dimension
    axes = np.eye(d)[[i for i, roller in enumerate(ROLLERS[:d]) if roller in used]]
    held = np.vstack([axes, geometry.contact_normals()]) if pressed else axes
    return held.size > 0 and np.linalg.matrix_rank(held, tol=1e-9 * np.abs(held).max()) == d


def check_fixed(geometry: Geometry, effects: Collection[str], table: dict[str, dict[str, Any]]) -> None:
    """Refuse a scene whose data cannot fix u, phi (with the piezoelectric effect) or theta
    (with the thermal effect); `table` is the resolved case."""
    used = geometry.used_roles()
    contact = "contact" in used and "contact" in effects
    if not u_fixed(geometry, effects, table.get("contact", {})):
        raise SceneError("geometry: no part is clamped (nor rollers or a pressed contact part holding every axis, "
                         "nor a contact part with friction): u is not fixed, the body could move as a rigid body")
    if "piezoelectric" in effects and not (used & set(PHI_FIXED) or (
            contact and "electric_contact" in effects and table["electric_contact"]["k_e"] > 0)):
        raise SceneError(f"geometry: no part fixes phi (none is {', '.join(PHI_FIXED)}) and there is no electric "
                         "contact conductance (effect electric_contact with k_e > 0): phi is defined only up "
                         "to a constant")
    if "thermal" in effects and not (used & set(THETA_FIXED) or (
            contact and "thermal_contact" in effects and table["thermal_contact"]["k_c"] > 0)):
        raise SceneError(f"geometry: no part fixes theta (none is {', '.join(THETA_FIXED)}) and there is no "
                         "thermal contact conductance (effect thermal_contact with k_c > 0): theta is defined "
                         "only up to a constant")
