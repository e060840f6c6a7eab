"""The paper's figures (Ouafik 2019, Figs. 2-3) from both codes side by side: the deformed
mesh with the initial boundary, the von Mises stress in the deformed configuration, the
electric potential and the temperature; FreeFEM, GetFEM and their difference. In 3D the same
on the mid-plane y = const (harness/measure/slices.py: a Kuhn mesh's grid plane, or samples of any
other tetrahedral mesh).

The stress is computed here, per cell, from each code's nodal fields with the same law,
sigma = C eps(u) + e^T grad(phi) - theta m (docs/model.md section 2; in 2D the plane-strain
state of the 3D law, which gives the out-of-plane sigma_22 too), so its difference is the
difference of the solutions, not of two post-processings."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.tri import Triangulation  # noqa: E402

from harness.measure.crosscheck import matched  # noqa: E402
from harness.measure.fields import Fields  # noqa: E402
from harness.measure.slices import Section, plane, whole  # noqa: E402

# 2D axes x, y are the material's 1 and 3 (docs/model.md section 2).
AXES_2D = (0, 2)


def peer_fields(fields: Fields, peer: dict[str, Any], names: tuple[str, ...]) -> dict[str, np.ndarray]:
    """The peer's nodal fields in FreeFEM's node order."""
    d = fields.cells.shape[1] - 1
    out = {}
    for name in names:
        key = "u_points" if name == "u" else "points"
        out[name] = np.array(peer[name], float)[matched(fields.points[:, :d], np.array(peer[key], float))]
    return out


def cell_gradients(points: np.ndarray, cells: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Per cell, grad[m, k, i] = d v_i / d x_k of a P1 field (scalars as one component)."""
    d = cells.shape[1] - 1
    p = points[cells][:, :, :d]
    v = values[cells] if values.ndim == 2 else values[cells][:, :, None]
    return np.linalg.solve(p[:, 1:] - p[:, :1], v[:, 1:] - v[:, :1])


def von_mises(points: np.ndarray, cells: np.ndarray, fields: dict[str, np.ndarray], material: dict[str, Any]) -> np.ndarray:
    d = cells.shape[1] - 1
    axes = AXES_2D if d == 2 else (0, 1, 2)
    grad = np.zeros((len(cells), 3, 3))  # d u_i / d x_k in the material's axes
    gu = cell_gradients(points, cells, fields["u"][:, :d])
    for a, k in enumerate(axes):
        for b, i in enumerate(axes):
            grad[:, k, i] = gu[:, a, b]
    g = lambda k, i: grad[:, k, i]  # noqa: E731
    strain = np.stack([g(0, 0), g(1, 1), g(2, 2), g(1, 2) + g(2, 1), g(0, 2) + g(2, 0), g(0, 1) + g(1, 0)], axis=1)
    sigma = strain @ np.array(material["C"], float).T
    if "phi" in fields:
        e_field = np.zeros((len(cells), 3))
        e_field[:, list(axes)] = cell_gradients(points, cells, fields["phi"])[:, :, 0]
        sigma += e_field @ np.array(material["e"], float)
    if "theta" in fields:
        sigma -= fields["theta"][cells].mean(axis=1)[:, None] * np.array(material["m"], float)[None, :]
    s11, s22, s33, s23, s13, s12 = sigma.T
    return np.sqrt(0.5 * ((s11 - s22) ** 2 + (s22 - s33) ** 2 + (s33 - s11) ** 2) + 3 * (s23**2 + s13**2 + s12**2))


def section(fields: Fields) -> tuple[Section, tuple[int, int]]:
    """What is drawn: the whole 2D mesh, or the mid-plane y = const of a 3D body
    (harness/measure/slices.py); and the two drawn axes."""
    if fields.tetrahedra is None:
        return whole(fields), (0, 1)
    pts = fields.points
    return plane(fields, 1, (pts[:, 1].min() + pts[:, 1].max()) / 2), (0, 2)


def nodal_from_cells(n_nodes: int, cells: np.ndarray, values: np.ndarray) -> np.ndarray:
    total, count = np.zeros(n_nodes), np.zeros(n_nodes)
    for k in range(cells.shape[1]):
        np.add.at(total, cells[:, k], values)
        np.add.at(count, cells[:, k], 1.0)
    return total / np.maximum(count, 1.0)


def render(fields: Fields, peer: dict[str, Any], material: dict[str, Any], names: tuple[str, ...], title: str,
           target: Path) -> None:
    ours = {name: fields.field(name)[:, : fields.cells.shape[1] - 1] if name == "u" else fields.field(name)
            for name in names}
    theirs = peer_fields(fields, peer, names)
    pts = fields.points[:, : fields.cells.shape[1] - 1]
    cut, (a, b) = section(fields)
    xy, tris = cut.coords, cut.triangles
    codes = {"FreeFEM": ours, "GetFEM": theirs}
    stress = {code: cut.of(nodal_from_cells(len(pts), fields.cells, von_mises(pts, fields.cells, f, material)))
              for code, f in codes.items()}
    umax = max(float(np.abs(ours["u"]).max()), 1e-300)
    scale = 0.1 * float(np.ptp(xy[:, 1])) / umax  # the largest displacement drawn as 1/10 of the height
    rows = [("von Mises stress [Pa]", stress)]
    rows += [(f"{name} [{'V' if name == 'phi' else 'K'}]", {c: cut.of(f[name]) for c, f in codes.items()})
             for name in ("phi", "theta") if name in names]
    fig, axes = plt.subplots(1 + len(rows), 3, figsize=(15, 2.3 * (1 + len(rows)) + 0.6), constrained_layout=True)
    boundary = outline(xy, tris)
    for col, (code, f) in enumerate(codes.items()):
        u = cut.of(f["u"])
        moved = Triangulation(xy[:, 0] + scale * u[:, a], xy[:, 1] + scale * u[:, b], tris)
        ax = axes[0, col]
        ax.triplot(moved, lw=0.2, color="tab:blue")
        for seg in boundary:
            ax.plot(xy[seg, 0], xy[seg, 1], color="k", lw=0.8)
        ax.set(title=f"{code}: deformed mesh, u x {scale:.3g}", aspect="equal")
    du = cut.of(ours["u"]) - cut.of(theirs["u"])
    c = axes[0, 2].tripcolor(Triangulation(xy[:, 0], xy[:, 1], tris), np.linalg.norm(du, axis=1), shading="gouraud", cmap="magma")
    fig.colorbar(c, ax=axes[0, 2], label="|u_FreeFEM - u_GetFEM| [m]")
    axes[0, 2].set(title=f"difference (max |u| {umax:.3g} m)", aspect="equal")
    flat = Triangulation(xy[:, 0], xy[:, 1], tris)
    for row, (label, values) in enumerate(rows, start=1):
        lo = min(v.min() for v in values.values())
        hi = max(v.max() for v in values.values())
        for col, code in enumerate(codes):
            c = axes[row, col].tripcolor(flat, values[code], shading="gouraud", vmin=lo, vmax=hi, cmap="viridis")
            fig.colorbar(c, ax=axes[row, col], label=label)
            axes[row, col].set(title=f"{code}: {label.split(' [')[0]}", aspect="equal")
        diff = values["FreeFEM"] - values["GetFEM"]
        c = axes[row, 2].tripcolor(flat, diff, shading="gouraud", cmap="coolwarm")
        fig.colorbar(c, ax=axes[row, 2], label=f"difference [{label.split('[')[1]}")
        axes[row, 2].set(title=f"FreeFEM - GetFEM (max {np.abs(diff).max():.2g}, of {np.abs(values['FreeFEM']).max():.3g})",
                         aspect="equal")
    fig.suptitle(title + "; black: the initial boundary")
    target.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(target, dpi=100)
    plt.close(fig)


def outline(xy: np.ndarray, tris: np.ndarray) -> list[np.ndarray]:
    """The boundary edges of a triangulation (each edge of one triangle only)."""
    edges = np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    return list(unique[counts == 1])
