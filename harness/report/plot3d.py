"""A picture of a 3D solution (`python -m harness plot results/paper3d/n16 --view section
[--case case.toml]`): phi and theta on the mid-plane y = (ymin + ymax)/2 and on the contact face,
with the displacement of the mid-plane exaggerated, from solution.vtu. A Kuhn mesh has nodes
on every grid plane; any other tetrahedral mesh (a gmsh scene) is cut by sampling its P1
fields on a grid of the plane (point location). The contact face is Gamma_3 of the case when
one is given, drawn in its own plane, and the face z = zmin otherwise."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.tri import Triangulation  # noqa: E402

from harness.measure.checks import contact_normal  # noqa: E402
from harness.measure.fields import Fields, read_fields  # noqa: E402
from harness.scene.scene import load_scene  # noqa: E402
from harness.measure.slices import Section, plane  # noqa: E402


def contact_face(fields: Fields, case: Path | None) -> tuple[Section, str]:
    """Gamma_3 of the case (drawn in its plane: two tangents of its outward normal), or the
    face z = zmin."""
    if case is None:
        bottom = fields.points[:, 2].min()
        return plane(fields, 2, bottom), f"the contact face z = {bottom:g}"
    scene = load_scene(case)
    mask = scene.geometry.contact_mask(fields.points)
    on = np.flatnonzero(mask)
    normal = contact_normal(scene, fields, mask)
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

