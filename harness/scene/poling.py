"""The poling axis of a scene (the material's axis 3), as the case file gives it.

`scene.poling_axis` is blank (the default: y in 2D, z in 3D), a named axis with an optional
sign ("x", "-z", "+y"), or a vector of the scene's dimension of any nonzero length (a 2D
poling lies in the plane). The material tensors are rotated once, in FreeFEM
(freefem/material.idp, "Poling"); this module only reads and checks the value and hands
FreeFEM the unit vector.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from harness.core.errors import SceneError

AXES = ("x", "y", "z")


@dataclass(frozen=True)
class Poling:
    """The unit poling vector in the scene's coordinates."""

    axis: tuple[float, ...]

    @property
    def dimension(self) -> int:
        return len(self.axis)

    @property
    def is_default(self) -> bool:
        """Along +y (2D) or +z (3D): the material files' own axes, nothing to rotate."""
        return self.axis == default_axis(self.dimension)

    def macros(self, always: bool = False) -> dict[str, str]:
        """FreeFEM's compile-time macros polingX, polingY(, polingZ); none for the default
        axis, so that a default run compiles the very law it compiled before, unless
        `always` (material regions of which another is rotated: every region's set then
        has the rotated entries, zero for this one)."""
        if self.is_default and not always:
            return {}
        return {f"poling{name.upper()}": repr(value) for name, value in zip(AXES, self.axis)}


def default_axis(dimension: int) -> tuple[float, ...]:
    return tuple(1.0 if i == dimension - 1 else 0.0 for i in range(dimension))


def parse_poling(value: Any, dimension: int) -> Poling:
    """A SceneError naming the value when it is not an axis of this dimension."""
    named = AXES[:dimension]
    if value == "":
        return Poling(default_axis(dimension))
    if isinstance(value, str):
        sign, name = (-1.0, value[1:]) if value.startswith("-") else (1.0, value.removeprefix("+"))
        if name not in named:
            choices = ", ".join(f"{s}{a}" for a in named for s in ("", "-"))
            raise SceneError(f"scene.poling_axis = {value!r} names no axis of a {dimension}D scene "
                             f"(one of {choices}, or a vector of {dimension} numbers)")
        return Poling(tuple(sign if a == name else 0.0 for a in named))
    if not (isinstance(value, list) and len(value) == dimension
            and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in value)):
        raise SceneError(f"scene.poling_axis = {value!r} is not a vector of {dimension} numbers "
                         f"(in 2D the poling lies in the plane of the drawing)")
    if not all(math.isfinite(x) for x in value):
        raise SceneError(f"scene.poling_axis = {value!r} has an entry that is not a finite number")
    if not any(value):
        raise SceneError(f"scene.poling_axis = {value!r} has zero length (give the direction the material is poled in)")
    return Poling(unit(tuple(float(x) for x in value)))


def unit(vector: tuple[float, ...]) -> tuple[float, ...]:
    """`vector` / |vector| for any finite nonzero vector. The vector is first scaled by the power
    of two that brings its largest entry into [0.5, 1), as hypot scales: exact, so every vector
    whose squares are normal numbers gives the very doubles it gave unscaled, and none overflows
    ([1e200, 1e200] squared is inf) or loses its digits in the subnormals ([3e-162, 0] squared
    keeps one bit: it gave the axis (0.95, 0))."""
    exponent = math.frexp(max(abs(x) for x in vector))[1]
    scaled = tuple(math.ldexp(x, -exponent) for x in vector)
    length = math.hypot(*scaled)
    return tuple(x / length for x in scaled)
