"""A picture of a 3D solution (`python -m harness.plot3d results/paper3d/n16`): phi and theta
on the mid-plane y = Ly/2 and on the contact face z = 0, with the displacement of the mid-plane
exaggerated, from solution.vtu (nodes of a Kuhn mesh lie on every grid plane)."""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.tri import Triangulation  # noqa: E402

from harness.fields import Fields, read_fields  # noqa: E402


def plane(fields: Fields, axis: int, value: float) -> np.ndarray:
    on = np.flatnonzero(np.abs(fields.points[:, axis] - value) < 1e-6)
    if len(on) < 3:
        raise SystemExit(f"error: no grid plane at {'xyz'[axis]} = {value}")
    return on


def render(run: Path, target: Path) -> None:
    f = read_fields(run / "solution.vtu")
    pts, u = f.points, f.field("u")
    ly = pts[:, 1].max()
    fig, axes = plt.subplots(2, 2, figsize=(11, 6.5), constrained_layout=True)
    mid = plane(f, 1, ly / 2)
    scale = 0.08 / max(np.abs(u).max(), 1e-300)  # the largest displacement drawn as 0.08 m
    xz = Triangulation(pts[mid, 0] + scale * u[mid, 0], pts[mid, 2] + scale * u[mid, 2])
    bottom = plane(f, 2, 0.0)
    xy = Triangulation(pts[bottom, 0], pts[bottom, 1])
    for row, name, unit in ((0, "phi", "V"), (1, "theta", "K")):
        values = f.field(name)
        ax = axes[row, 0]
        c = ax.tricontourf(xz, values[mid], levels=np.linspace(values.min(), values.max(), 25), cmap="viridis", extend="both")
        fig.colorbar(c, ax=ax, label=f"{name} [{unit}]")
        ax.set(title=f"{name} on y = {ly / 2:g}, displacement x {scale:.2g}", xlabel="x [m]", ylabel="z [m]", aspect="equal")
        ax = axes[row, 1]
        c = ax.tricontourf(xy, values[bottom], levels=np.linspace(values.min(), values.max(), 25), cmap="viridis", extend="both")
        fig.colorbar(c, ax=ax, label=f"{name} [{unit}]")
        ax.set(title=f"{name} on the contact face z = 0", xlabel="x [m]", ylabel="y [m]", aspect="equal")
    fig.suptitle(f"{run.parent.name}, {run.name}: {len(pts):,} nodes")
    fig.savefig(target, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    run = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("results/paper3d/n16")
    out = Path(sys.argv[2]) if len(sys.argv) > 2 else run.parent / "fields.png"
    render(run, out)
    print(f"wrote {out}")
