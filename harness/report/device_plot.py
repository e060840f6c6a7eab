"""A picture of a device scene's solution (`python -m harness plot results/strip_actuator/n16`):
for a 2D body, phi, theta (when the scene has it) and the displacement on the deformed mesh (displacement and
thickness exaggerated: a device is thin); for a 3D body, phi and theta on its bottom face
(where a device meets its pad; see face_panel) and on the section y = 0 (harness/measure/slices.py), from solution.vtu."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.tri import Triangulation  # noqa: E402

from harness.measure.fields import Fields, read_fields  # noqa: E402
from harness.measure.slices import plane  # noqa: E402

PANELS = (("phi", "V"), ("theta", "K"))


def panels(f: Fields) -> tuple[tuple[str, str], ...]:
    """The scalar fields of PANELS the solution has (a scene without heat has no theta)."""
    return tuple(p for p in PANELS if p[0] in f.values)


def contour(ax: plt.Axes, tri: Triangulation, values: np.ndarray, label: str) -> None:
    low, high = float(values.min()), float(values.max())
    levels = np.linspace(low, high if high > low else low + 1.0, 25)
    c = ax.tricontourf(tri, values, levels=levels, cmap="viridis", extend="both")
    plt.colorbar(c, ax=ax, label=label)


def render_2d(f: Fields, fig: plt.Figure) -> None:
    pts, u = f.points, f.field("u")
    length, thickness = np.ptp(pts[:, 0]), np.ptp(pts[:, 1])
    # The largest displacement drawn as a tenth of the thickness, then the thickness shown at
    # a fifth of the length: the shape of the strain, not its size.
    scale = 0.1 * thickness / max(np.abs(u).max(), 1e-300)
    stretch = 0.2 * length / max(thickness, 1e-300)
    moved = pts + scale * u
    tri = Triangulation(1e3 * moved[:, 0], 1e3 * stretch * moved[:, 1], f.triangles)
    shown = (*panels(f), ("|u|", "m"))
    axes = fig.subplots(len(shown), 1, squeeze=False)[:, 0]
    for ax, (name, unit) in zip(axes, shown):
        values = np.linalg.norm(u, axis=1) if name == "|u|" else f.field(name)
        contour(ax, tri, values, f"{name} [{unit}]")
        ax.set(title=f"{name}; displacement x {scale:.2g}, thickness x {stretch:.2g}", xlabel="x [mm]",
               ylabel=f"y [mm] x {stretch:.2g}")
        ax.set_aspect("equal")


def face_nodes(pts: np.ndarray, top: bool) -> np.ndarray:
    """The nodes of the body's bottom (or top) face z = min (max)."""
    z = pts[:, 2].max() if top else pts[:, 2].min()
    return np.flatnonzero(np.abs(pts[:, 2] - z) < 1e-6 * np.ptp(pts[:, 2]))


def face_panel(f: Fields, name: str, unit: str) -> tuple[str, str, np.ndarray, np.ndarray]:
    """What a field's face panel shows: the field on the bottom face (where a device meets its
    pad), or on the top face where only that one varies; where both faces hold one value (an
    earthed base under a floating electrode), the vertical displacement on the top face, which
    the field's uniform value says nothing about. Returns the title, the colour bar's label,
    the face's nodes and the values shown (at every node)."""
    values = f.field(name)
    for top in (False, True):
        nodes = face_nodes(f.points, top)
        if np.ptp(values[nodes]) > 1e-9 * max(np.ptp(values), 1e-300):
            return f"{name} on the {'top' if top else 'bottom'} face", f"{name} [{unit}]", nodes, values
    return "u_z on the top face", "u_z [m]", face_nodes(f.points, True), f.field("u")[:, 2]


def render_3d(f: Fields, fig: plt.Figure) -> None:
    pts = f.points
    cut = plane(f, 1, 0.0)
    axes = fig.subplots(len(panels(f)), 2, squeeze=False)
    for row, (name, unit) in enumerate(panels(f)):
        values = f.field(name)
        title, label, nodes, shown = face_panel(f, name, unit)
        face = Triangulation(1e3 * pts[nodes, 0], 1e3 * pts[nodes, 1])
        contour(axes[row, 0], face, shown[nodes], label)
        axes[row, 0].set(title=title, xlabel="x [mm]", ylabel="y [mm]", aspect="equal")
        contour(axes[row, 1], Triangulation(1e3 * cut.coords[:, 0], 1e3 * cut.coords[:, 1], cut.triangles),
                cut.of(values), f"{name} [{unit}]")
        axes[row, 1].set(title=f"{name} on the section y = 0", xlabel="x [mm]", ylabel="z [mm]")


def render(run: Path, target: Path) -> None:
    f = read_fields(run / "solution.vtu")
    fig = plt.figure(figsize=(11, 7.5), constrained_layout=True)
    (render_3d if f.tetrahedra is not None else render_2d)(f, fig)
    fig.suptitle(f"{run.parent.name}, {run.name}: {len(f.points):,} nodes")
    fig.savefig(target, dpi=100)
    plt.close(fig)

