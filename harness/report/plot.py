"""Every plot the studies draw, with one label per error: the log-log convergence plot (E^h
per field and in total, fitted slopes, a slope-1 guide), the manufactured solutions' errors,
and the cost study's errors against cost, time split and scaling."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Protocol

import numpy as np
import pandas as pd
from matplotlib.axes import Axes
from matplotlib.ticker import NullFormatter
from matplotlib.figure import Figure  # no pyplot: no global figure state, no GUI backend

from harness.measure.norm_table import FIELD_NAMES, TOTAL, error_column, error_label, error_names, mms_norm
from harness.measure.rates import scaling_exponents
from harness.study.study import Study



class CostTables(Protocol):
    """What the cost plots read of a cost study (harness/report/frontier.py's CostStudy)."""
    scene: str
    reference: tuple[str, int]
    table: pd.DataFrame
    scaling: pd.DataFrame
    fits: Mapping[str, Any]


def plot_convergence(study: Study, target: Path) -> None:
    graded = study.table.iloc[:-1]
    h = graded["h"].to_numpy(dtype=float)
    fig = Figure(figsize=(6.4, 4.8))
    ax = fig.subplots()
    for name in error_names(study.fields):
        errors = graded[error_column(name)].to_numpy(dtype=float)
        style = "k-o" if name == TOTAL else "--s"
        label = f"{error_label(name)}, slope {study.slopes[name]['all']:.2f}"
        ax.loglog(h, errors, style, label=label, markersize=4)
    add_slope_guide(ax, h, graded[error_column(TOTAL)].to_numpy(dtype=float))
    # Each level's tick names n and its real largest cell (model units): n is only a label.
    ax.set_xticks(h, [f"1/{n}\n{size:.2g}" for n, size in zip(graded["n"], graded["h_max"])])
    ax.minorticks_off()
    ax.set_xlabel("h = 1/n (below it: the largest cell h_max, in the model's units)")
    ax.set_ylabel(f"error against h = 1/{study.reference}")
    ax.set_title(f"{study.scene.name}: convergence (initial guess {study.scene.initial_guess})")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(target, format="png", dpi=120)


def plot_quantities(scene: str, values: pd.DataFrame, studied: Mapping[str, Any], target: Path) -> None:
    """Each quantity's relative error against its extrapolated value (harness/measure/quantity_study.py),
    against the unknowns and against each level's wall time: the price of each digit. A
    quantity that is not extrapolable has no error to draw; the title counts them."""
    fig = Figure(figsize=(11, 4.8))
    axes = fig.subplots(1, 2)
    drawn = [name for name, q in studied.items() if q.relative_errors and q.status == "extrapolated"]
    for name in drawn:
        q = studied[name]
        levels = sorted(q.relative_errors)
        rows = values.set_index("n").loc[levels]
        errors = np.array([q.relative_errors[n] for n in levels], dtype=float)
        shown = errors > 0  # the finest level's error can be 0 to round-off: nothing to draw in log scale
        for ax, column in zip(axes, ("dofs", "wall_s")):
            ax.loglog(rows[column].to_numpy(dtype=float)[shown], errors[shown], "-o", markersize=4,
                      label=f"{name}, order {q.order:.2f}")
    for ax, label in zip(axes, ("unknowns (dofs)", "wall time of the level [s]")):
        ax.set_xlabel(label)
        ax.xaxis.set_minor_formatter(NullFormatter())  # a narrow range of times: minor labels overlap
        ax.set_ylabel("|Q_n - Q_ext| / |Q_ext|  (Q_ext: Richardson, three finest levels)", fontsize=8)
        ax.grid(True, which="both", alpha=0.3)
        if drawn:
            ax.legend(fontsize=7)
    for ax, column in zip(axes, ("dofs", "wall_s")):  # each level's own value as a tick: few decades are spanned
        ticks = values[column].to_numpy(dtype=float)
        ticks = np.unique(ticks[np.isfinite(ticks) & (ticks > 0)])
        if drawn and len(ticks) < 10:
            ax.set_xticks(ticks, [f"{s:.3g}" for s in ticks], fontsize=7, rotation=60)
    title = f"{scene}: each quantity's error against its extrapolated value"
    for status in sorted({q.status for name, q in studied.items() if name not in drawn}):
        title += f"\n{status} (not drawn): {', '.join(name for name, q in studied.items() if q.status == status)}"
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(target, format="png", dpi=120)


def add_slope_guide(ax: Axes, h: np.ndarray, total: np.ndarray) -> None:
    """A slope-1 line from the coarsest total error, halved so it never hides the data."""
    if len(h) and np.isfinite(total[0]) and total[0] > 0:
        ends = np.array([h.min(), h.max()])
        ax.loglog(ends, 0.5 * total[0] * ends / h.max(), ":", color="gray", label="slope 1")


def plot_mms(errors: pd.DataFrame, rates: pd.DataFrame, target: Path) -> None:
    """One panel per case: relative errors against h, a colour per field, a line style per
    norm (norm_table.MMS_NORMS), the fitted slope and its standard error in the legend."""
    cases = list(dict.fromkeys(errors["case"]))
    colours = {name: f"C{i}" for i, name in enumerate(FIELD_NAMES)}
    fig = Figure(figsize=(5.2 * len(cases), 4.6))
    axes = fig.subplots(1, len(cases), squeeze=False)[0]
    for ax, case in zip(axes, cases):
        for (field, norm), group in errors[errors["case"] == case].groupby(["field", "norm"], sort=False):
            rate = rates[(rates["case"] == case) & (rates["field"] == field) & (rates["norm"] == norm)].iloc[0]
            ax.loglog(group["h"], group["relative_error"], mms_norm(norm).style, markersize=4,
                      color=colours.get(field), label=f"{field} {norm}: {rate['slope']:.2f} ± {rate['slope_stderr']:.2f}")
        h = sorted(set(errors["h"]))
        ax.set_xticks(h, [f"1/{round(1 / v)}" for v in h])
        ax.minorticks_off()
        ax.set_title(f"manufactured solution: {case}")
        ax.set_xlabel("h")
        ax.set_ylabel("error / norm of the exact field")
        ax.grid(True, which="major", alpha=0.3)
        ax.legend(fontsize=7, title="slope ± standard error", title_fontsize=7)
    fig.tight_layout()
    fig.savefig(target, format="png", dpi=120)


def plot_errors(study: CostTables, x: str, xlabel: str, target: Path) -> None:
    fig = Figure(figsize=(10, 7.5))
    axes = fig.subplots(2, 2).ravel()
    table = study.table[~study.table["discretisation"].str.contains("reference")]
    styles = ("-o", "--s", ":^", "-.D", "-v")  # P1 and P1-rtol have the same errors: both show
    for ax, name in zip(axes, error_names()):  # u, phi, theta, total
        for i, (disc, rows) in enumerate(table.groupby("discretisation", sort=False)):
            rows = rows[np.isfinite(rows[error_column(name)].astype(float))]
            fit = study.fits.get(disc)
            label = disc + (f" (p = {fit.errors[name].exponent:.2f})" if fit and name in fit.errors else "")
            ax.loglog(rows[x], rows[error_column(name)], styles[i % len(styles)], markersize=5 - i % 3,
                      fillstyle="none" if i % 2 else "full", label=label)
        ax.set_title(error_label(name))
        ax.set_xlabel(xlabel)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f"{study.scene}: error against {study.reference[0]} at h = 1/{study.reference[1]}")
    fig.tight_layout()
    fig.savefig(target, format="png", dpi=110)


SPLIT = (
    ("mesh_s", "mesh (gmsh)"),
    ("startup_s", "FreeFEM start-up"),
    ("setup_s", "setup (mesh read, warm start, checks)"),
    ("bulk_assembly_s", "bulk assembly"),
    ("first_factorisation_s", "first factorisation"),
    ("refactor_s", "further factorisations"),
    ("solve_s", "GMRES / triangular solves"),
    ("newton_other_s", "rest of Newton (tangent, residuals, block matrix)"),
    ("output_s", "output"),
)


def finished(table: pd.DataFrame) -> pd.DataFrame:
    """The rows of runs that finished (a failed scaling level has no times)."""
    return table[np.isfinite(table["wall_s"].astype(float))] if "wall_s" in table else table


def split_columns(table: pd.DataFrame) -> pd.DataFrame:
    t = table.copy()
    t["refactor_s"] = t["factorisation_s"] - t["first_factorisation_s"]
    t["newton_other_s"] = t["newton_s"] - t["assembly_s"] - t["factorisation_s"] - t["solve_s"]
    t["newton_other_s"] += t["assembly_s"] - t["bulk_assembly_s"]
    t["setup_s"] = t["wall_s"] - t["startup_s"] - t["newton_s"] - t["output_s"]
    return t


def plot_time_split(study: CostTables, target: Path) -> None:
    """Per level, each part's share of the level's wall time (mesh included), the total on top."""
    table = split_columns(finished(study.table[~study.table["discretisation"].str.contains("reference")]))
    groups = list(table.groupby("discretisation", sort=False))
    fig = Figure(figsize=(4.2 * len(groups) + 3.2, 4.5))
    axes = np.atleast_1d(fig.subplots(1, len(groups), sharey=True))
    for ax, (disc, rows) in zip(axes, groups):
        labels = [f"1/{n}" for n in rows["n"]]
        parts = np.clip(np.array([rows[c].to_numpy(dtype=float) for c, _ in SPLIT]), 0, None)
        totals = parts.sum(axis=0)
        bottom = np.zeros(len(rows))
        for (column, label), values, i in zip(SPLIT, parts, range(len(SPLIT))):
            share = 100 * values / totals
            ax.bar(labels, share, bottom=bottom, color=f"C{i}", label=label)
            bottom += share
        for x, total in zip(labels, totals):
            ax.annotate(f"{total:.2g} s", (x, 100), ha="center", va="bottom", fontsize=7)
        ax.set_ylim(0, 108)
        ax.set_title(f"{disc}: where the time goes", fontsize=10)
        ax.set_xlabel("h")
    axes[0].set_ylabel("% of the level's wall time (mesh + FreeFEM)")
    axes[-1].legend(fontsize=7, loc="center left", bbox_to_anchor=(1.02, 0.5))
    fig.tight_layout()
    fig.savefig(target, format="png", dpi=110)


def plot_scaling(study: CostTables, target: Path) -> None:
    s = finished(study.scaling)
    if s.empty:
        return
    exps = scaling_exponents(s)
    fig = Figure(figsize=(6.4, 4.8))
    ax = fig.subplots()
    ax.loglog(s["dofs"], s["wall_s"], "-o", label=f"wall s (slope {exps['time_vs_dofs']:.2f} for n >= 32)")
    ax.loglog(s["dofs"], s["peak_rss_mb"] / 1000, "-s", label=f"peak RSS GB (slope {exps['memory_vs_dofs']:.2f})")
    for _, r in s.iterrows():
        ax.annotate(f"1/{r['n']}", (r["dofs"], r["wall_s"]), fontsize=7, textcoords="offset points", xytext=(3, -9))
    ax.set_xlabel("dofs")
    ax.set_title(f"{study.scene}: P1 chain, time and memory per level")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(target, format="png", dpi=110)


def plot_rank_iterations(ranks: pd.DataFrame, target: Path) -> None:
    """The rank table (python -m harness solvers --ranks): the most Krylov iterations of a
    Newton step against the MPI ranks, one line per coarse space, one rank's factorisation
    as the reference."""
    fig = Figure(figsize=(5.6, 4.0))
    ax = fig.subplots()
    done = ranks[ranks["status"] == "ok"]
    one = done[done["ranks"] == 1]
    names = {"none": "one-level Schwarz", "nested": "two-level (nested coarse mesh)"}
    for space, group in done[done["ranks"] > 1].groupby("coarse_space", sort=False):
        group = pd.concat([one, group]).sort_values("ranks")
        ax.plot(group["ranks"], group["max_krylov_per_step"], "-o", label=names.get(str(space), str(space)))
    ax.set_xscale("log", base=2)
    ax.set_xticks(sorted(done["ranks"].unique()), [str(r) for r in sorted(done["ranks"].unique())])
    ax.minorticks_off()
    scene, n = done["scene"].iloc[0], int(done["n"].iloc[0])
    ax.set_title(f"{scene}, h = 1/{n}, from zero")
    ax.set_xlabel("MPI ranks")
    ax.set_ylabel("most GMRES iterations in a Newton step")
    ax.set_ylim(bottom=0)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(target, format="png", dpi=120)
