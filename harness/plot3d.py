"""A picture of a 3D solution (`python -m harness.plot3d results/paper3d/n16 [out.png]
[case.toml]`): phi and theta on the mid-plane y = (ymin + ymax)/2 and on the contact face,
with the displacement of the mid-plane exaggerated, from solution.vtu. A Kuhn mesh has nodes
on every grid plane; any other tetrahedral mesh (a gmsh scene) is cut by sampling its P1
fields on a grid of the plane (point location). The contact face is Gamma_3 of the case when
one is given, drawn in its own plane, and the face z = zmin otherwise."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.tri import Triangulation  # noqa: E402

from harness.checks import contact_normal  # noqa: E402
from harness.fields import Fields, read_fields  # noqa: E402
from harness.norms import tetrahedron_weights  # noqa: E402
from harness.scene import load_scene  # noqa: E402


@dataclass(frozen=True)
class Section:
    """Values on a plane of the body: P1 weights of sample points and their 2D coordinates."""

    coords: np.ndarray    # (P, 2) in the plane
    nodes: np.ndarray     # (P, k) mesh nodes each sample interpolates
    weights: np.ndarray   # (P, k)
    triangles: np.ndarray

    def of(self, values: np.ndarray) -> np.ndarray:
        return np.einsum("pk,pk...->p...", self.weights, values[self.nodes])

    def triangulation(self, shift: np.ndarray | None = None) -> Triangulation:
        xy = self.coords if shift is None else self.coords + shift
        return Triangulation(xy[:, 0], xy[:, 1], self.triangles)


def plane(fields: Fields, axis: int, value: float, across: int = 160) -> Section:
    """The section x_axis = value: the mesh's own nodes when a grid plane of them lies there
    (a Kuhn mesh), else a grid of `across` samples along its longer side, inside the body."""
    others = [i for i in range(3) if i != axis]
    on = np.flatnonzero(np.abs(fields.points[:, axis] - value) < 1e-6)
    if len(on) >= 3 and len(on) >= 0.5 * len(fields.points) ** (2 / 3):
        xy = fields.points[on][:, others]
        return Section(xy, on[:, None], np.ones((len(on), 1)), Triangulation(xy[:, 0], xy[:, 1]).triangles)
    low, high = fields.points.min(axis=0)[others], fields.points.max(axis=0)[others]
    step = max(high - low) / across
    a, b = (np.arange(lo, hi + step / 2, step) for lo, hi in zip(low, high))
    ga, gb = (g.ravel() for g in np.meshgrid(a, b, indexing="ij"))
    at = np.zeros((len(ga), 3))
    at[:, axis], at[:, others[0]], at[:, others[1]] = value, ga, gb
    nodes, weights = tetrahedron_weights(fields, at, outside=None)
    inside = nodes[:, 0] >= 0
    if inside.sum() < 3:
        raise SystemExit(f"error: the plane {'xyz'[axis]} = {value} does not cut the body")
    xy = np.column_stack([ga, gb])[inside]
    tri = Triangulation(xy[:, 0], xy[:, 1])
    # Delaunay fills the concave parts of the section: keep the grid's own triangles.
    edges = xy[tri.triangles] - xy[np.roll(tri.triangles, 1, axis=1)]
    keep = np.linalg.norm(edges, axis=2).max(axis=1) < 1.5 * step
    return Section(xy, nodes[inside], weights[inside], tri.triangles[keep])


def contact_face(fields: Fields, case: Path | None) -> tuple[Section, str]:
    """Gamma_3 of the case (drawn in its plane: two tangents of its outward normal), or the
    face z = zmin."""
    if case is None:
        bottom = fields.points[:, 2].min()
        return plane(fields, 2, bottom), f"the contact face z = {bottom:g}"
    scene = load_scene(case)
    on = np.flatnonzero(scene.geometry.contact_mask(fields.points))
    normal = contact_normal(scene, fields)
    first = np.cross(normal, [0.0, 1.0, 0.0] if abs(normal[1]) < 0.9 else [1.0, 0.0, 0.0])
    first /= np.linalg.norm(first)
    xy = fields.points[on] @ np.column_stack([first, np.cross(first, normal)])
    tri = Triangulation(xy[:, 0], xy[:, 1]).triangles
    return Section(xy, on[:, None], np.ones((len(on), 1)), tri), f"Gamma_3 (normal {np.round(normal, 3).tolist()})"


def render(run: Path, target: Path, case: Path | None = None) -> None:
    f = read_fields(run / "solution.vtu")
    pts, u = f.points, f.field("u")
    middle = (pts[:, 1].min() + pts[:, 1].max()) / 2
    fig, axes = plt.subplots(2, 2, figsize=(11, 6.5), constrained_layout=True)
    mid = plane(f, 1, middle)
    size = np.ptp(pts, axis=0).max()
    scale = 0.02 * size / max(np.abs(u).max(), 1e-300)  # the largest displacement drawn as 2% of the body
    xz = mid.triangulation(scale * mid.of(u)[:, [0, 2]])
    face, face_name = contact_face(f, case)
    face_axes = ("x [m]", "y [m]") if case is None else ("along t1 [m]", "along t2 = t1 x nu [m]")
    for row, name, unit in ((0, "phi", "V"), (1, "theta", "K")):
        values = f.field(name)
        ax = axes[row, 0]
        c = ax.tricontourf(xz, mid.of(values), levels=np.linspace(values.min(), values.max(), 25), cmap="viridis", extend="both")
        fig.colorbar(c, ax=ax, label=f"{name} [{unit}]")
        ax.set(title=f"{name} on y = {middle:g}, displacement x {scale:.2g}", xlabel="x [m]", ylabel="z [m]", aspect="equal")
        ax = axes[row, 1]
        c = ax.tricontourf(face.triangulation(), face.of(values), levels=np.linspace(values.min(), values.max(), 25),
                           cmap="viridis", extend="both")
        fig.colorbar(c, ax=ax, label=f"{name} [{unit}]")
        ax.set(title=f"{name} on {face_name}", xlabel=face_axes[0], ylabel=face_axes[1], aspect="equal")
    fig.suptitle(f"{run.parent.name}, {run.name}: {len(pts):,} nodes")
    fig.savefig(target, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    run = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("results/paper3d/n16")
    out = Path(sys.argv[2]) if len(sys.argv) > 2 else run.parent / "fields.png"
    render(run, out, Path(sys.argv[3]) if len(sys.argv) > 3 else None)
    print(f"wrote {out}")
