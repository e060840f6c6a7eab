"""P1 transfer between meshes and the seminorms of docs/model.md section 7, on the fine mesh.

    ||v||_V^2 = int eps(v):eps(v),   ||xi||_W^2 = ||eta||_Q^2 = int |grad xi|^2

P1 gradients are constant per triangle, so the integrals are exact sums of area x integrand.
Which norm each field is measured in is harness/measure/norm_table.py's: the integrands here are
looked up by its stems (P1_INTEGRANDS, EXACT_INTEGRANDS), as freefem/norms.idp's are.
"""

from __future__ import annotations

import itertools
import math
from typing import TYPE_CHECKING, Callable, Mapping, Sequence

import numpy as np
from matplotlib.tri import Triangulation

from harness.core.errors import FieldsError, MeshError
from harness.mesh.box_mesh import grid_index, kuhn_weights
from harness.measure.fields import Fields
from harness.measure.norm_table import MMS_NORMS, measure_of

if TYPE_CHECKING:
    import sympy


def kuhn_located(coarse: Fields, at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The Kuhn point location of box_mesh.kuhn_weights, for a coarse mesh that is a Kuhn
    mesh: its nodes on a grid and every located tetrahedron one of its own (a gmsh mesh whose
    nodes happen to lie on a grid, cut another way, is not; MeshError then)."""
    grid, spacing = grid_index(coarse.points)
    nodes, weights = kuhn_weights(coarse.points, grid, spacing, at)
    own = {tuple(t) for t in np.sort(coarse.tetrahedra, axis=1).tolist()}
    if any(tuple(t) not in own for t in np.unique(np.sort(nodes, axis=1), axis=0).tolist()):
        raise MeshError(f"{coarse.source}: not a Kuhn mesh")
    return nodes, weights


def gradients(points: np.ndarray, triangles: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-triangle (d/dx, d/dy) of the P1 function with nodal `values`, and |area|."""
    x, y = points[triangles, 0], points[triangles, 1]  # (M, 3)
    v = values[triangles]
    twice = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0])
    # Gradient of the barycentric coordinate of vertex i: the opposite edge turned by 90 degrees.
    bx = np.roll(y, -1, axis=1) - np.roll(y, -2, axis=1)
    by = np.roll(x, -2, axis=1) - np.roll(x, -1, axis=1)
    dx = (v * bx).sum(axis=1) / twice
    dy = (v * by).sum(axis=1) / twice
    return dx, dy, 0.5 * np.abs(twice)


def gradient_seminorm_sq(points: np.ndarray, triangles: np.ndarray, values: np.ndarray) -> float:
    dx, dy, area = gradients(points, triangles, values)
    return float(np.sum(area * (dx**2 + dy**2)))


def strain_seminorm_sq(points: np.ndarray, triangles: np.ndarray, u: np.ndarray) -> float:
    u1x, u1y, area = gradients(points, triangles, u[:, 0])
    u2x, u2y, _ = gradients(points, triangles, u[:, 1])
    e12 = 0.5 * (u1y + u2x)
    return float(np.sum(area * (u1x**2 + u2y**2 + 2.0 * e12**2)))


# norm_table's integrand stems, squared and integrated over triangles (P1 fields).
P1_INTEGRANDS: dict[str, Callable[[np.ndarray, np.ndarray, np.ndarray], float]] = {
    "strain": strain_seminorm_sq, "grad": gradient_seminorm_sq}


def seminorm(points: np.ndarray, triangles: np.ndarray, values: np.ndarray) -> float:
    """||.||_V for a vector field (N, 2), ||.||_W = ||.||_Q for a scalar field (N,)."""
    return float(np.sqrt(P1_INTEGRANDS["strain" if values.ndim == 2 else "grad"](points, triangles, values)))


# Dunavant's 6-point rule, exact for degree 4 (barycentric points, weights summing to 1).
_A, _B = 0.816847572980458513, 0.091576213509770743
_C, _D = 0.108103018168070227, 0.445948490915964886
QUAD_POINTS = np.array([[_A, _B, _B], [_B, _A, _B], [_B, _B, _A], [_C, _D, _D], [_D, _C, _D], [_D, _D, _C]])
QUAD_WEIGHTS = np.array([0.109951743655321869] * 3 + [0.223381589678011466] * 3)

Exact = Callable[[np.ndarray, np.ndarray], np.ndarray]


# norm_table's scalar stems of the manufactured norms, at the quadrature points: (P1 value,
# its d/dx, d/dy; the exact value, d/dx, d/dy) -> the squared difference. A vector field's
# norm is the sum over its components (norms.idp's vecL2, fullGrad).
EXACT_INTEGRANDS: dict[str, Callable[..., np.ndarray]] = {
    "l2": lambda uh, dx, dy, f, fx, fy: (uh - f) ** 2,
    "grad": lambda uh, dx, dy, f, fx, fy: (dx - fx) ** 2 + (dy - fy) ** 2,
}


def exact_errors(points: np.ndarray, triangles: np.ndarray, nodal: np.ndarray,
                 exact: Sequence[tuple[Exact, Exact, Exact]]) -> dict[str, float]:
    """The error of a P1 field (N,) or (N, k) in every manufactured norm of norm_table.py
    (L2, full-gradient H1 seminorm) against exact functions (value, d/dx, d/dy of each
    component), by quadrature on each triangle, keyed by the norm."""
    corners = points[triangles]  # (M, 3, 2)
    qp = np.einsum("qk,mkd->mqd", QUAD_POINTS, corners)  # (M, Q, 2)
    qx, qy = qp[..., 0], qp[..., 1]
    columns = [nodal[:, i] for i in range(nodal.shape[1])] if nodal.ndim == 2 else [nodal]
    sums = dict.fromkeys((n.key for n in MMS_NORMS), 0.0)
    for column, (f, fx, fy) in zip(columns, exact, strict=True):
        dx, dy, area = gradients(points, triangles, column)
        at = (np.einsum("qk,mk->mq", QUAD_POINTS, column[triangles]), dx[:, None], dy[:, None],
              f(qx, qy), fx(qx, qy), fy(qx, qy))
        for norm in MMS_NORMS:
            sums[norm.key] += np.sum(area * (EXACT_INTEGRANDS[norm.scalar](*at) @ QUAD_WEIGHTS))
    return {key: math.sqrt(value) for key, value in sums.items()}


def transfer_weights(coarse: Fields, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The coarse triangle of each point (point location, once for every field) and the
    point's barycentric coordinates in it: the P1 interpolation from coarse to `points`.

    Exact (to round-off) when every coarse triangle is a union of fine ones (nested meshes);
    on non-nested meshes it is the nodal interpolant of the coarse field, an approximation of
    the true difference of the two P1 functions.
    """
    tri = Triangulation(coarse.points[:, 0], coarse.points[:, 1], coarse.triangles)
    found = tri.get_trifinder()(points[:, 0], points[:, 1])
    missing = np.flatnonzero(found < 0)
    if len(missing):
        found[missing] = nearest_simplices(coarse.points[:, :2], coarse.triangles, points[missing, :2], coarse.source)
    corners = coarse.triangles[found]  # (N, 3)
    a, b, c = (coarse.points[corners[:, i], :2] for i in range(3))
    twice = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
    p = points[:, :2]
    wb = ((p[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (p[:, 1] - a[:, 1])) / twice
    wc = ((b[:, 0] - a[:, 0]) * (p[:, 1] - a[:, 1]) - (p[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])) / twice
    return corners, np.column_stack([1.0 - wb - wc, wb, wc])


# How far outside every coarse simplex a fine node may lie, in barycentric units (a fraction
# of the simplex), and still take the P1 extension of the nearest one: a boundary node of a
# tilted straight side is outside by round-off (solution.vtu holds single-precision
# coordinates: ~1e-6), one of a curved side meshed anew or split onto the curve by ~h / R.
OUTSIDE = 0.5


def nearest_simplices(corners_of: np.ndarray, cells: np.ndarray, at: np.ndarray, source: object) -> np.ndarray:
    """For each point of `at`, the simplex whose smallest barycentric coordinate of the point
    is largest: the one holding it, or the nearest when it lies just outside them all."""
    corners = corners_of[cells]                                        # (M, d + 1, d)
    to_weights = np.linalg.inv(np.swapaxes(corners[:, 1:] - corners[:, :1], 1, 2))
    best = np.empty(len(at), dtype=np.int64)
    for start in range(0, len(at), 256):  # 256 points x M simplices at a time
        chunk = at[start:start + 256]
        w = np.einsum("mij,pmj->pmi", to_weights, chunk[:, None, :] - corners[None, :, 0])
        smallest = np.minimum(1.0 - w.sum(axis=-1), w.min(axis=-1))    # (P, M)
        pick = smallest.argmax(axis=1)
        if (smallest[np.arange(len(chunk)), pick] < -OUTSIDE).any():
            raise FieldsError(f"{source}: some fine nodes lie outside the coarse mesh")
        best[start:start + 256] = pick
    return best


def transfer(coarse: Fields, name: str, points: np.ndarray,
             weights: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """The coarse P1 field `name` at `points` (transfer_weights, or the given ones)."""
    corners, w = weights if weights is not None else transfer_weights(coarse, points)
    values = coarse.field(name)
    at_corners = values[corners]  # (N, 3) or (N, 3, 2)
    return np.einsum("nk,nk...->n...", w, at_corners)


def simplex_seminorm(points: np.ndarray, cells: np.ndarray, values: np.ndarray, stem: str | None = None) -> float:
    """seminorm on simplices of any dimension (tetrahedra of a box scene): the gradient of
    a P1 function solves edges @ grad = jumps on each simplex; ||.||_V with
    eps : eps = sum eps_ii^2 + 2 sum_{i<j} eps_ij^2 (norm_table's stem "strain", the default
    for a vector field), else the full gradient ("grad")."""
    d = cells.shape[1] - 1
    p = points[cells][:, :, :d]
    edges = p[:, 1:] - p[:, :1]
    volume = np.abs(np.linalg.det(edges)) / math.factorial(d)
    v = values[cells]
    jumps = v[:, 1:] - v[:, :1]
    grad = np.linalg.solve(edges, jumps if values.ndim == 2 else jumps[:, :, None])  # [m, k, i] = d v_i / d x_k
    if (stem or ("strain" if values.ndim == 2 else "grad")) == "strain":
        eps = 0.5 * (grad + np.swapaxes(grad, 1, 2))
        density = np.sum(eps**2, axis=(1, 2))
    else:
        density = np.sum(grad**2, axis=(1, 2))
    return float(np.sqrt(np.sum(volume * density)))


def tetrahedron_weights(coarse: Fields, at: np.ndarray, tol: float = 1e-5,
                        outside: float | None = OUTSIDE) -> tuple[np.ndarray, np.ndarray]:
    """Point location in an unstructured tetrahedral mesh: for each point of `at`, the four
    nodes of the coarse tetrahedron holding it and its barycentric weights. The tetrahedra
    are binned on a uniform grid by their bounding boxes; each point is tested against its
    bin's tetrahedra only (bins padded by `tol` of the mesh's size) and takes the one where
    its smallest weight is largest (on a shared face either neighbour gives the same P1
    value); a node outside every tetrahedron by up to OUTSIDE takes the nearest one's P1
    extension (single-precision coordinates, or a curved boundary). `outside=None`: a point
    in no tetrahedron (beyond `tol`) gets node -1 and zero weights instead of an error (a
    picture's samples of a plane through the body)."""
    points, tets = coarse.points, coarse.tetrahedra
    corners = points[tets]                                            # (M, 4, 3)
    to_weights = np.linalg.inv(np.swapaxes(corners[:, 1:] - corners[:, :1], 1, 2))  # x - a -> (w1, w2, w3)
    low, span = points.min(axis=0), np.ptp(points, axis=0)
    bins = max(1, round(len(tets) ** (1 / 3) / 2))

    def cell(x: np.ndarray) -> np.ndarray:
        return np.clip(((x - low) / span * bins).astype(np.int64), 0, bins - 1)

    first, last = cell(corners.min(axis=1) - tol * span), cell(corners.max(axis=1) + tol * span)
    members: dict[tuple[int, int, int], list[int]] = {}
    for m, (a, b) in enumerate(zip(first, last)):
        for key in itertools.product(*(range(a[i], b[i] + 1) for i in range(3))):
            members.setdefault(key, []).append(m)
    found, weights = np.full(len(at), -1), np.zeros((len(at), 4))
    keys = cell(at)
    for key in {tuple(k) for k in keys}:
        rows = np.flatnonzero((keys == key).all(axis=1))
        candidates = np.array(members.get(key, []), dtype=np.int64)
        if not len(candidates):
            continue
        w = np.einsum("cij,pcj->pci", to_weights[candidates], at[rows][:, None, :] - corners[candidates, 0][None])
        full = np.concatenate([1.0 - w.sum(axis=-1, keepdims=True), w], axis=-1)   # (P, C, 4)
        best = full.min(axis=-1).argmax(axis=1)
        inside = full[np.arange(len(rows)), best].min(axis=-1) >= -(tol if outside is None else outside)
        found[rows[inside]] = candidates[best[inside]]
        weights[rows[inside]] = full[np.arange(len(rows)), best][inside]
    if outside is None:
        return np.where(found[:, None] >= 0, tets[found], -1), weights
    if np.any(found < 0):
        raise FieldsError(f"{coarse.source}: some fine nodes lie outside the coarse mesh")
    return tets[found], weights


def error_norms(coarse: Fields, fine: Fields, names: list[str]) -> dict[str, float]:
    """||fine - coarse|| per field in its norm of E^h (norm_table.MEASURE), on the fine mesh."""
    if coarse.tetrahedra is not None:
        try:  # a Kuhn mesh of a box (harness/mesh/box_mesh.py): its grid locates every point at once
            nodes, w = kuhn_located(coarse, fine.points)
        except MeshError:  # any other (gmsh's): point location, exact on nested meshes as on 2D
            nodes, w = tetrahedron_weights(coarse, fine.points)
        return {name: simplex_seminorm(fine.points, fine.cells,
                                       fine.field(name) - np.einsum("nk,nk...->n...", w, coarse.field(name)[nodes]),
                                       measure_of(name).stem)
                for name in names}
    weights = transfer_weights(coarse, fine.points)
    return {
        name: float(np.sqrt(P1_INTEGRANDS[measure_of(name).stem](
            fine.points, fine.triangles, fine.field(name) - transfer(coarse, name, fine.points, weights))))
        for name in names
    }


def fe_errors(points: np.ndarray, triangles: np.ndarray, values: Mapping[str, np.ndarray],
              exact: Mapping[str, "sympy.Expr"]) -> dict[str, dict[str, float]]:
    """Absolute L2 error and full-gradient H1-seminorm error of P1 nodal fields against a
    manufactured solution's exact ones (exact_errors): an independent check of what FreeFEM
    reports. `values` maps "u" to (N, 2) and "phi"/"theta" to (N,); `exact` holds u1, u2,
    phi, theta."""
    import sympy  # only the manufactured cases pay for sympy's import

    from harness.scene.mms import X, Y, numeric

    out = {}
    for field, nodal in values.items():
        keys = ["u1", "u2"] if nodal.ndim == 2 else [field]
        f = [numeric({"v": exact[k], "dx": sympy.diff(exact[k], X), "dy": sympy.diff(exact[k], Y)}) for k in keys]
        out[field] = exact_errors(points, triangles, nodal, [(g["v"], g["dx"], g["dy"]) for g in f])
    return out
