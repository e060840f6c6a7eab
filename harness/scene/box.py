"""The box scene geometry (0, Lx) x (0, Ly) x (0, Lz): each face split into rectangular
patches with a boundary role, the way the rectangle's sides are split into segments
(harness/scene/segments.py). Axis z is the poling axis (the paper's axis 3).

A face is named by its normal axis and side: x0 (x = 0), x1 (x = Lx), y0, y1, z0, z1. Its
value is a role, or a list of patches [a0, a1, b0, b1, role] over the face's two in-plane
coordinates in axis order (x0/x1: y, z; y0/y1: x, z; z0/z1: x, y) that tile the face.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from harness.scene.blocks import Block, parse_blocks
from harness.scene.cell_size import Body
from harness.scene.electrodes import Part
from harness.core.errors import MeshError, SceneError
from harness.core.contract import ROLE_LABELS

FACES = ("x0", "x1", "y0", "y1", "z0", "z1")


@dataclass(frozen=True)
class Patch:
    a0: float
    a1: float
    b0: float
    b1: float
    role: str

    def contains(self, a: float, b: float) -> bool:
        return self.a0 <= a <= self.a1 and self.b0 <= b <= self.b1

    @property
    def area(self) -> float:
        return (self.a1 - self.a0) * (self.b1 - self.b0)


@dataclass(frozen=True)
class Box:
    lx: float
    ly: float
    lz: float
    faces: dict[str, tuple[Patch, ...]]
    dimension: int = 3
    diagonals: str = "kuhn"  # the Kuhn/Freudenthal split of harness/mesh/box_mesh.py, or "unstructured" (gmsh)
    # Named sub-blocks (harness/scene/blocks.py) and, when [scene.materials] maps them, the
    # regions in label order (harness/scene/regions.py): the cells of regions[i] carry label i + 1.
    blocks: tuple[Block, ...] = ()
    regions: tuple[str, ...] = ()

    @property
    def lengths(self) -> tuple[float, float, float]:
        return self.lx, self.ly, self.lz

    # The memory and disk guards (harness/core/guards.py) size a level by width x height x ly.
    @property
    def width(self) -> float:
        return self.lx

    @property
    def height(self) -> float:
        return self.lz

    def role_of(self, centroid: np.ndarray, axis: int, side: int) -> str:
        """Role of a boundary triangle from its centroid (strictly inside one patch)."""
        name = f"{'xyz'[axis]}{0 if side < 0 else 1}"
        a, b = (centroid[i] for i in range(3) if i != axis)
        for patch in self.faces[name]:
            if patch.contains(a, b):
                return patch.role
        raise MeshError(f"face {name}: no patch contains the triangle at {tuple(np.round(centroid, 6))}: "
                        "are the patch edges on the mesh's grid lines?")

    def body_parts(self) -> tuple[Body, ...]:
        if self.blocks:
            return tuple(block.body() for block in self.blocks)
        return (Body("the box", (0.0, 0.0, 0.0), self.lengths),)

    def parts(self) -> tuple[Part, ...]:
        """Each face's patches as closed extents, named as the case file gives them."""
        out = []
        for name, patches in self.faces.items():
            axis = "xyz".index(name[0])
            at = 0.0 if name[1] == "0" else self.lengths[axis]
            others = [i for i in range(3) if i != axis]
            for p in patches:
                lo, hi = [at] * 3, [at] * 3
                lo[others[0]], hi[others[0]], lo[others[1]], hi[others[1]] = p.a0, p.a1, p.b0, p.b1
                out.append(Part(f"geometry.{name} [{p.a0:g}, {p.a1:g}] x [{p.b0:g}, {p.b1:g}]", p.role,
                                tuple(lo), tuple(hi)))
        return tuple(out)

    def cuts(self, axis: int) -> list[float]:
        """The coordinates along `axis` where a patch or a block starts or ends, with the box's
        own ends: an unstructured mesh must have faces along them for its roles and regions to
        be exact."""
        length = self.lengths[axis]
        found = {0.0, length}
        for name, patches in self.faces.items():
            normal = "xyz".index(name[0])
            in_plane = [i for i in range(3) if i != normal]
            if axis in in_plane:
                first = in_plane.index(axis) == 0
                for patch in patches:
                    found |= {patch.a0, patch.a1} if first else {patch.b0, patch.b1}
        for block in self.blocks:  # the interfaces between regions, too
            found |= {block.lo[axis], block.hi[axis]}
        return sorted(found)

    def contact_measure(self) -> float:
        """|Gamma_3|: the area of the contact patches."""
        return self.role_areas().get("contact", 0.0)

    def contact_mask(self, points: np.ndarray) -> np.ndarray:
        """Which points lie on a contact patch."""
        tol = 1e-6 * max(self.lengths)  # solution.vtu's coordinates are single precision
        on = np.zeros(len(points), dtype=bool)
        for name, patches in self.faces.items():
            axis = "xyz".index(name[0])
            a, b = (i for i in range(3) if i != axis)
            plane = np.abs(points[:, axis] - (0.0 if name[1] == "0" else self.lengths[axis])) < tol
            for patch in (p for p in patches if p.role == "contact"):
                on |= plane & (points[:, a] > patch.a0 - tol) & (points[:, a] < patch.a1 + tol) \
                    & (points[:, b] > patch.b0 - tol) & (points[:, b] < patch.b1 + tol)
        return on

    def used_roles(self) -> frozenset[str]:
        return frozenset(self.role_areas())

    def contact_normals(self) -> np.ndarray:
        """The normal axis of each face with a contact patch (rows)."""
        axes = ["xyz".index(name[0]) for name, patches in self.faces.items() if any(p.role == "contact" for p in patches)]
        return np.eye(3)[axes]

    def role_areas(self) -> dict[str, float]:
        areas = dict.fromkeys(ROLE_LABELS, 0.0)
        for patches in self.faces.values():
            for patch in patches:
                areas[patch.role] += patch.area
        return {role: area for role, area in areas.items() if area > 0}


def face_extent(name: str, lengths: tuple[float, float, float]) -> tuple[float, float]:
    axis = "xyz".index(name[0])
    a, b = (lengths[i] for i in range(3) if i != axis)
    return a, b


def parse_box(table: dict[str, Any]) -> Box:
    lengths = (table["lx"], table["ly"], table["lz"])
    faces = {name: parse_face(f"geometry.{name}", table[name], face_extent(name, lengths)) for name in FACES}
    return Box(*lengths, faces=faces, diagonals=table.get("diagonals", "kuhn"),
               blocks=parse_blocks(table.get("blocks", {}), lengths))


def parse_face(name: str, value: Any, extent: tuple[float, float]) -> tuple[Patch, ...]:
    roles = ", ".join(ROLE_LABELS)
    if isinstance(value, str):
        if value not in ROLE_LABELS:
            raise SceneError(f"{name} = {value!r}: role must be one of {roles}")
        return (Patch(0.0, extent[0], 0.0, extent[1], value),)
    if not isinstance(value, list) or not value:
        raise SceneError(f"{name} must be a role or a list of [a0, a1, b0, b1, role] patches")
    patches = []
    for item in value:
        ok = (isinstance(item, list) and len(item) == 5 and all(type(x) in (int, float) for x in item[:4])
              and 0 <= item[0] < item[1] <= extent[0] and 0 <= item[2] < item[3] <= extent[1]
              and item[4] in ROLE_LABELS)
        if not ok:
            raise SceneError(f"{name}: patch {item!r} must be [a0, a1, b0, b1, role] inside "
                             f"[0, {extent[0]}] x [0, {extent[1]}], role in {roles}")
        patches.append(Patch(float(item[0]), float(item[1]), float(item[2]), float(item[3]), item[4]))
    # Patches inside the face whose areas add up to the face's tile it unless two overlap.
    for i, p in enumerate(patches):
        for q in patches[:i]:
            if min(p.a1, q.a1) > max(p.a0, q.a0) and min(p.b1, q.b1) > max(p.b0, q.b0):
                raise SceneError(f"{name}: patches {p} and {q} overlap")
    if not math.isclose(sum(p.area for p in patches), extent[0] * extent[1], rel_tol=1e-12):
        raise SceneError(f"{name}: the patches do not cover the face [0, {extent[0]}] x [0, {extent[1]}]")
    return tuple(patches)
