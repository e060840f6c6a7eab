"""A level's interior nodes moved by a tiny pseudo-random amount (the branch-stability study,
harness/study/stability.py): each interior node by at most `relative` times the shortest edge
that meets it, in a direction and by a length drawn from a seeded generator, so that the same
seed moves the same nodes the same way on every machine. Nodes on the boundary, on a labelled
facet (an electrode inside the body) and on an interface between material regions stay where
they are: the body, its parts and its regions keep their exact shape, only the cells inside
change by round-off's order.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from harness.mesh.simplex import EDGES, SimplexMesh, boundary_facets, cell_facets


@dataclass(frozen=True)
class Jitter:
    """How far interior nodes move (a fraction of their shortest edge) and the generator's seed."""

    relative: float
    seed: int


def fixed_nodes(level: SimplexMesh) -> np.ndarray:
    """Whether each node must stay: on the boundary, on a labelled facet, or on a facet
    between cells of two material regions."""
    fixed = np.zeros(len(level.points), dtype=bool)
    fixed[boundary_facets(level.cells).ravel()] = True
    if len(level.facets):
        fixed[level.facets.ravel()] = True
    if level.regions is not None and len(np.unique(level.regions)) > 1:
        faces = cell_facets(level.cells)                                  # (M, d + 1, d)
        keys = np.sort(faces.reshape(-1, faces.shape[-1]), axis=1)
        owners = np.repeat(level.regions, faces.shape[1])
        _, inverse = np.unique(keys, axis=0, return_inverse=True)
        inverse = inverse.ravel()
        low = np.full(inverse.max() + 1, np.iinfo(np.int64).max)
        high = np.full(inverse.max() + 1, np.iinfo(np.int64).min)
        np.minimum.at(low, inverse, owners)
        np.maximum.at(high, inverse, owners)
        fixed[keys[(low != high)[inverse]].ravel()] = True
    return fixed


def shortest_edges(level: SimplexMesh) -> np.ndarray:
    """Each node's shortest edge: the local h the jitter is a fraction of."""
    shortest = np.full(len(level.points), np.inf)
    d = level.dimension
    for i, j in EDGES[d]:
        a, b = level.cells[:, i], level.cells[:, j]
        length = np.linalg.norm(level.points[a] - level.points[b], axis=1)
        np.minimum.at(shortest, a, length)
        np.minimum.at(shortest, b, length)
    return shortest


def jittered(level: SimplexMesh, jitter: Jitter) -> SimplexMesh:
    """`level` with each interior node moved by at most `jitter.relative` of its shortest
    edge; topology, labels and regions unchanged (a move far below any cell's size turns no
    cell over)."""
    rng = np.random.default_rng(jitter.seed)
    d = level.dimension
    direction = rng.normal(size=(len(level.points), d))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    length = rng.uniform(0.0, 1.0, size=len(level.points)) * jitter.relative * shortest_edges(level)
    move = direction * length[:, None]
    move[fixed_nodes(level)] = 0.0
    return replace(level, points=level.points + move)
