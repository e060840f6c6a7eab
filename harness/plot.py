"""The log-log convergence plot: E^h per field and in total, fitted slopes, a slope-1 guide."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure  # no pyplot: no global figure state, no GUI backend

from harness.study import Study

LABELS = {
    "u": r"$\|u-u^h\|_V$",
    "phi": r"$\|\varphi-\varphi^h\|_W$",
    "theta": r"$\|\theta-\theta^h\|_Q$",
    "total": r"$E^h$ (total)",
}


def plot_convergence(study: Study, target: Path) -> None:
    graded = study.table.iloc[:-1]
    h = graded["h"].to_numpy(dtype=float)
    fig = Figure(figsize=(6.4, 4.8))
    ax = fig.subplots()
    for name in (*study.fields, "total"):
        errors = graded[f"err_{name}"].to_numpy(dtype=float)
        style = "k-o" if name == "total" else "--s"
        label = f"{LABELS[name]}, slope {study.slopes[name]['all']:.2f}"
        ax.loglog(h, errors, style, label=label, markersize=4)
    add_slope_guide(ax, h, graded["err_total"].to_numpy(dtype=float))
    ax.set_xlabel("h")
    ax.set_ylabel(f"error against h = 1/{study.reference}")
    ax.set_title(f"{study.scene.name}: convergence (initial guess {study.scene.initial_guess})")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(target, format="png", dpi=120)


def add_slope_guide(ax: Axes, h: np.ndarray, total: np.ndarray) -> None:
    """A slope-1 line from the coarsest total error, halved so it never hides the data."""
    if len(h) and np.isfinite(total[0]) and total[0] > 0:
        ends = np.array([h.min(), h.max()])
        ax.loglog(ends, 0.5 * total[0] * ends / h.max(), ":", color="gray", label="slope 1")
