"""Two potentials at one point: an electrode part (φ = loads.electrode_potential) that touches
a clamped or ground part (φ = 0), found from the parts' extents when the scene loads, before
anything is meshed. Each geometry lists its boundary parts as closed axis-aligned extents
(`Part`): a rectangle's segments and sides, a box's patches, a gmsh part's corner points."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

from harness.core.errors import SceneError

# The roles whose parts hold φ = 0 (freefem/dirichlet.idp's vOnEarthed).
EARTHED = ("clamped", "ground")


@dataclass(frozen=True)
class Part:
    name: str                 # as the case file names it, e.g. geometry.bottom [1.0, 3.0]
    role: str
    lo: tuple[float, ...]     # the closed extent's lowest corner
    hi: tuple[float, ...]     # and highest (lo = hi: a point)


def shared_point(a: Part, b: Part, tol: float) -> tuple[float, ...] | None:
    """A point the two closed extents share (within `tol`), or None."""
    lo = [max(p, q) for p, q in zip(a.lo, b.lo)]
    hi = [min(p, q) for p, q in zip(a.hi, b.hi)]
    return tuple(lo) if all(l <= h + tol for l, h in zip(lo, hi)) else None


def check_electrodes(parts: Iterable[Part], size: float) -> None:
    """One SceneError line naming the first electrode part that touches an earthed one, both
    parts and the point's coordinates (`size`: the body's, for the tolerance)."""
    parts = list(parts)
    tol = 1e-9 * size
    for electrode in (p for p in parts if p.role == "electrode"):
        for earthed in (p for p in parts if p.role in EARTHED):
            point = shared_point(electrode, earthed, tol)
            if point is not None:
                where = ", ".join(f"{x:.6g}" for x in point)
                raise SceneError(f"the electrode part {electrode.name} touches the {earthed.role} part "
                                 f"{earthed.name} at ({where}): two potentials at one point (a clamped or ground "
                                 "part holds phi = 0); leave a free or loaded part between them")
