"""The rectangle's boundary as role-tagged segments; validated so they tile each side."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from harness.scene.blocks import Block, parse_blocks
from harness.scene.cell_size import Body
from harness.scene.electrodes import Part
from harness.core.errors import SceneError
from harness.core.contract import ROLE_LABELS


@dataclass(frozen=True)
class Segment:
    x0: float
    x1: float
    role: str

    @property
    def length(self) -> float:
        return self.x1 - self.x0


@dataclass(frozen=True)
class Geometry:
    width: float
    height: float
    bottom: tuple[Segment, ...]
    top: tuple[Segment, ...]
    left: str
    right: str
    diagonals: str
    # Named sub-blocks (harness/scene/blocks.py) and, when [scene.materials] maps them, the
    # regions in label order (harness/scene/regions.py): the cells of regions[i] carry label i + 1.
    blocks: tuple[Block, ...] = ()
    regions: tuple[str, ...] = ()

    def breakpoints(self) -> tuple[float, ...]:
        """Every x where a bottom or top segment starts or ends, sorted, 0 and width included."""
        xs = {s.x0 for s in self.bottom + self.top} | {s.x1 for s in self.bottom + self.top}
        return tuple(sorted(xs))

    dimension = 2

    def contact_measure(self) -> float:
        """|Gamma_3|: the length of the contact segments."""
        return sum(seg.length for seg in self.bottom + self.top if seg.role == "contact")

    def contact_mask(self, points: np.ndarray) -> np.ndarray:
        """Which points lie on a contact segment of the bottom (y = 0) or the top (y = height)."""
        on = np.zeros(len(points), dtype=bool)
        for side, y in ((self.bottom, 0.0), (self.top, self.height)):
            for seg in (s for s in side if s.role == "contact"):
                on |= (np.abs(points[:, 1] - y) < 1e-12 * max(1.0, self.height)) & (points[:, 0] >= seg.x0 - 1e-12) \
                    & (points[:, 0] <= seg.x1 + 1e-12)
        return on

    def used_roles(self) -> frozenset[str]:
        return frozenset(self.role_lengths())

    def contact_normals(self) -> np.ndarray:
        """The normal axis of each side holding contact (rows)."""
        normals = [[0.0, 1.0] for side in (self.bottom, self.top) if any(s.role == "contact" for s in side)]
        normals += [[1.0, 0.0] for role in (self.left, self.right) if role == "contact"]
        return np.array(normals, dtype=float).reshape(-1, 2)

    def body_parts(self) -> tuple[Body, ...]:
        if self.blocks:
            return tuple(block.body() for block in self.blocks)
        return (Body("the rectangle", (0.0, 0.0), (self.width, self.height)),)

    def parts(self) -> tuple[Part, ...]:
        """Each segment and side as a closed extent, named as the case file gives it."""
        w, h = self.width, self.height
        out = [Part(f"geometry.{name} [{s.x0:g}, {s.x1:g}]", s.role, (s.x0, y), (s.x1, y))
               for name, side, y in (("bottom", self.bottom, 0.0), ("top", self.top, h)) for s in side]
        out += [Part("geometry.left", self.left, (0.0, 0.0), (0.0, h)),
                Part("geometry.right", self.right, (w, 0.0), (w, h))]
        return tuple(out)

    def role_lengths(self) -> dict[str, float]:
        lengths = dict.fromkeys(ROLE_LABELS, 0.0)
        for seg in self.bottom + self.top:
            lengths[seg.role] += seg.length
        lengths[self.left] += self.height
        lengths[self.right] += self.height
        return {role: length for role, length in lengths.items() if length > 0}


def parse_geometry(table: dict[str, Any]) -> Geometry:
    width = table["width"]
    blocks = parse_blocks(table.get("blocks", {}), (width, table["height"]))
    if blocks and table["diagonals"] == "unstructured":
        raise SceneError("geometry.blocks need the structured lattice (diagonals = \"SW-NE\" or \"NW-SE\"): "
                         "unstructured triangles would straddle the blocks' interfaces")
    return Geometry(
        width=width,
        height=table["height"],
        bottom=parse_side("geometry.bottom", table["bottom"], width),
        top=parse_side("geometry.top", table["top"], width),
        left=table["left"],
        right=table["right"],
        diagonals=table["diagonals"],
        blocks=blocks,
    )


def parse_side(name: str, items: list, width: float) -> tuple[Segment, ...]:
    segments = tuple(parse_segment(name, item) for item in items)
    # Breakpoints come from the same decimal literals, so exact comparison is the right test;
    # a tolerance would let a mistyped breakpoint through and leave a gap in the mesh.
    ends = [0.0] + [s.x1 for s in segments]
    starts = [s.x0 for s in segments] + [width]
    if not segments or ends != starts:
        raise SceneError(f"{name} must tile [0, {width}] with consecutive [x0, x1, role] segments")
    return segments


def parse_segment(name: str, item: Any) -> Segment:
    ok = (
        isinstance(item, list)
        and len(item) == 3
        and all(type(x) in (int, float) for x in item[:2])
        and item[0] < item[1]
        and item[2] in ROLE_LABELS
    )
    if not ok:
        roles = ", ".join(ROLE_LABELS)
        raise SceneError(f"{name}: segment {item!r} must be [x0, x1, role] with x0 < x1, role in {roles}")
    return Segment(float(item[0]), float(item[1]), item[2])
