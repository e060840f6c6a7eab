"""Named sub-blocks of the rectangle and the box (`[geometry.blocks]`): axis-aligned blocks that
tile the body, each a region `[scene.materials]` can map to a material, as a gmsh scene's named
physical groups are (harness/scene/regions.py).

A block is `name = [x0, x1, y0, y1]` in 2D, `[x0, x1, y0, y1, z0, z1]` in 3D. The structured
meshes put a grid line on every multiple of h, so a block whose faces lie on multiples of h is
a union of whole grid squares (cubes): each cell lies in one block, found from its centroid
(harness/mesh/mesh.py, box_mesh.py), and the interfaces are lines (faces) of the mesh at every
level, as the regions' bonding needs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from harness.core.errors import MeshError, SceneError
from harness.scene.cell_size import Body


@dataclass(frozen=True)
class Block:
    name: str
    lo: tuple[float, ...]  # its lowest corner, one entry per axis
    hi: tuple[float, ...]

    @property
    def measure(self) -> float:
        return math.prod(b - a for a, b in zip(self.lo, self.hi))

    def body(self) -> Body:
        return Body(f"block {self.name!r}", self.lo, self.hi)


def parse_blocks(value: Any, lengths: tuple[float, ...]) -> tuple[Block, ...]:
    """The blocks of `[geometry.blocks]` in the case file's order, checked to tile the body
    (0, L_1) x ... (a SceneError naming the culprit otherwise); none when the table is empty."""
    if value in ({}, None):
        return ()
    dimension = len(lengths)
    shape = "[x0, x1, y0, y1]" if dimension == 2 else "[x0, x1, y0, y1, z0, z1]"
    body = " x ".join(f"[0, {length:g}]" for length in lengths)
    if not isinstance(value, dict):
        raise SceneError(f"geometry.blocks must be a table of name = {shape}")
    blocks = []
    for name, bounds in value.items():
        ok = (isinstance(bounds, list) and len(bounds) == 2 * dimension
              and all(type(b) in (int, float) for b in bounds)
              and all(0 <= bounds[2 * i] < bounds[2 * i + 1] <= lengths[i] for i in range(dimension)))
        if not ok:
            raise SceneError(f"geometry.blocks.{name} = {bounds!r} must be {shape} with each low < high, inside {body}")
        blocks.append(Block(name, tuple(float(b) for b in bounds[0::2]), tuple(float(b) for b in bounds[1::2])))
    for i, block in enumerate(blocks):
        for other in blocks[:i]:
            if all(min(a1, b1) > max(a0, b0) for a0, a1, b0, b1 in zip(block.lo, block.hi, other.lo, other.hi)):
                raise SceneError(f"geometry.blocks: {other.name!r} and {block.name!r} overlap: a region has one material")
    # Blocks inside the body, none overlapping, whose measures add up to the body's tile it.
    if not math.isclose(sum(b.measure for b in blocks), math.prod(lengths), rel_tol=1e-12):
        raise SceneError(f"geometry.blocks do not cover the body {body}: every cell needs a block, and its block a material")
    return tuple(blocks)


def check_on_grid(blocks: tuple[Block, ...], n: int) -> None:
    """Every face of every block on a grid line of level n (a multiple of h = 1/n), or the cells
    that straddle it would belong to two regions."""
    for block in blocks:
        for x in block.lo + block.hi:
            if abs(round(x * n) - x * n) > 1e-9 * max(1.0, x * n):  # round-off of x*n only
                raise MeshError(f"n={n}: block {block.name!r} has a side at {x:g}, not a multiple of h = 1/{n}: "
                                "place its sides on the coarsest level's grid")


def block_labels(blocks: tuple[Block, ...], regions: tuple[str, ...], centroids: np.ndarray) -> np.ndarray:
    """Each cell's region label, 1 + the index in `regions` of the block holding its centroid
    (a centroid lies strictly inside one block when the blocks are on the grid)."""
    labels = np.zeros(len(centroids), dtype=np.int64)
    index = {name: i + 1 for i, name in enumerate(regions)}
    for block in blocks:
        inside = np.all((centroids > np.array(block.lo)) & (centroids < np.array(block.hi)), axis=1)
        labels[inside] = index[block.name]
    if (labels == 0).any():
        where = tuple(np.round(centroids[np.flatnonzero(labels == 0)[0]], 6))
        raise MeshError(f"the cell at {where} lies in no block: are the blocks' sides on the mesh's grid lines?")
    return labels
