"""The case-file schema in one table: section -> key -> type, default and physical range.

Every check returns a complaint (a phrase) or None, so the loader can name the key
generically; nothing here knows about files or overrides.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

# Boundary roles and the integer labels FreeFEM sees (gmsh physical curve tags).
ROLE_LABELS = {"clamped": 1, "loaded": 2, "free": 3, "contact": 4}

# Sections passed verbatim to FreeFEM as `-<section>.<key> <value>`.
SOLVER_SECTIONS = ("loads", "contact", "electric_contact", "thermal_contact", "newton")

REQUIRED = object()

Check = Callable[[Any], "str | None"]


@dataclass(frozen=True)
class Key:
    kind: type
    default: Any = REQUIRED
    check: Check | None = None

    @property
    def required(self) -> bool:
        return self.default is REQUIRED


def positive(v: float) -> str | None:
    return None if v > 0 else "must be > 0"


def nonnegative(v: float) -> str | None:
    return None if v >= 0 else "must be >= 0"


def one_of(*choices: str) -> Check:
    def check(v: str) -> str | None:
        return None if v in choices else f"must be one of {', '.join(choices)}"

    return check


def positive_ints(v: list) -> str | None:
    ok = v and all(type(x) is int and x > 0 for x in v)
    return None if ok else "must be a non-empty list of positive integers"


def increasing_pair(v: list) -> str | None:
    ok = (
        len(v) == 2
        and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)
        and all(math.isfinite(x) for x in v)
        and v[0] < v[1]
    )
    return None if ok else "must be [low, high] with low < high"


def safe_name(v: str) -> str | None:
    ok = v and v not in (".", "..") and all(c.isalnum() or c in "-_." for c in v)
    return None if ok else "must be a plain file name (letters, digits, - _ .)"


_ROLE = one_of(*ROLE_LABELS)

SCHEMA: dict[str, dict[str, Key]] = {
    "scene": {
        "name": Key(str, check=safe_name),
        "description": Key(str, ""),
        "material": Key(str, check=safe_name),
        "initial_guess": Key(str, "zero", one_of("zero", "pressed")),
    },
    "geometry": {
        "kind": Key(str, check=one_of("rectangle")),
        "width": Key(float, check=positive),
        "height": Key(float, check=positive),
        "bottom": Key(list),
        "top": Key(list),
        "left": Key(str, check=_ROLE),
        "right": Key(str, check=_ROLE),
        "diagonals": Key(str, "SW-NE", one_of("SW-NE", "NW-SE")),
    },
    "loads": {
        name: Key(float)
        for name in (
            "traction_x", "traction_y", "surface_charge", "body_force_x",
            "body_force_y", "charge_density", "heat_source",
        )
    },
    "contact": {
        "c_nu": Key(float, check=positive),
        "gap": Key(float),
        "S": Key(float, check=nonnegative),
    },
    "electric_contact": {
        "k_e": Key(float, check=nonnegative),
        "eps_e": Key(float, check=positive),
        "phi_f": Key(float),
        "L": Key(float, check=positive),
    },
    "thermal_contact": {
        "k_c": Key(float, check=nonnegative),
        "eps_c": Key(float, check=positive),
        "theta_f": Key(float),
    },
    "newton": {
        "max_iterations": Key(int, check=positive),
        "rtol": Key(float, check=positive),
    },
    "run": {"timeout_s": Key(float, 600.0, positive)},
    "study": {
        "levels": Key(list, check=positive_ints),
        "slope_band": Key(list, check=increasing_pair),
    },
}
