"""The contact state along Gamma_3 (`python -m harness plot results/paper/n16 --view contact`),
from the level's contact.csv (freefem/quantities.idp): in 2D the contact pressure, the
tangential traction and the gap against the position along Gamma_3 (the coordinate that varies
most over it); in 3D the contact pressure over Gamma_3, seen along the axis it varies least in."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure  # no pyplot: no global figure state, no GUI backend

from harness.core.errors import HarnessError

CONTACT_TABLE = "contact.csv"


def read_contact(level: Path) -> pd.DataFrame:
    path = level / CONTACT_TABLE
    if not path.is_file():
        raise HarnessError(f"{level}: no {CONTACT_TABLE} (a run whose scene has contact writes one)")
    table = pd.read_csv(path)
    if table.empty:
        raise HarnessError(f"{path}: no node of Gamma_3")
    return table


def render(level: Path, out: Path) -> None:
    table = read_contact(level)
    coords = [c for c in ("x", "y", "z") if c in table.columns]
    spans = {c: float(np.ptp(table[c].to_numpy(dtype=float))) for c in coords}
    if len(coords) == 2:
        along = max(spans, key=spans.__getitem__)
        order = table.sort_values(along)
        s = order[along].to_numpy(dtype=float)
        fig = Figure(figsize=(7, 6.4))
        axes = fig.subplots(3, 1, sharex=True)
        for ax, column, label in zip(axes, ("contact_pressure", "tangential_traction", "gap"),
                                     ("contact pressure p [N/m^2]", "tangential traction [N/m^2]", "gap g - u_nu [m]")):
            ax.plot(s, order[column].to_numpy(dtype=float), "-o", markersize=3)
            ax.set_ylabel(label, fontsize=8)
            ax.grid(True, alpha=0.3)
        axes[-1].set_xlabel(f"{along} along Gamma_3 [m]")
        fig.suptitle(f"{level.parent.name} {level.name}: contact along Gamma_3", fontsize=10)
    else:
        flat = min(spans, key=spans.__getitem__)
        a, b = (c for c in coords if c != flat)
        fig = Figure(figsize=(6.4, 5.2))
        ax = fig.subplots()
        drawn = ax.tricontourf(table[a].to_numpy(dtype=float), table[b].to_numpy(dtype=float),
                               table["contact_pressure"].to_numpy(dtype=float), levels=20)
        fig.colorbar(drawn, ax=ax, label="contact pressure p [N/m^2]")
        ax.set_xlabel(f"{a} [m]")
        ax.set_ylabel(f"{b} [m]")
        ax.set_aspect("equal")
        ax.set_title(f"{level.parent.name} {level.name}: contact pressure on Gamma_3", fontsize=10)
    fig.tight_layout()
    fig.savefig(out, format="png", dpi=120)
