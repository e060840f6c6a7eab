"""What accuracy costs, the library of `make cost` (harness/studies/cost.py): every
discretisation's chain measured against one reference, the fitted laws E ~ C h^p, T ~ D h^-q,
M ~ G h^-r (harness/measure/rates.py's PowerLaw), the frontier (to reach E <= tau: h, seconds, MB),
and the files written (tables, Markdown, plots from harness/report/plot.py)."""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pandas as pd

from harness.core import freefem
from harness.core.errors import SceneError
from harness.study.engine import InlineMeshes, Progress, freefem_startup_s, quiet, run_levels, runs_of, stderr_line, timed_meshes
from harness.core.layout import Layout
from harness.measure.norm_table import FIELD_NAMES, TOTAL, error_column, error_names
from harness.report.plot import plot_errors, plot_scaling, plot_time_split
from harness.measure.rates import PowerLaw, power_fit, scaling_exponents
from harness.run.record import RunRecord
from harness.run.run import RunResult, check_solver_files
from harness.scene.scene import Scene, load_scene
from harness.study.adapt import DEFAULT_BULK, adapt
from harness.core.writers import markdown_table, write_csv, write_json, write_text, write_with

ERROR_NAMES = error_names()
# Relative accuracies of the frontier table: E <= tau_rel * ||reference||, per field.
TAUS_REL = (1e-1, 3e-2, 1e-2, 3e-3, 1e-3)
# The table gives no prediction for an h more than this factor outside the fitted levels.
MAX_EXTRAPOLATION = 4.0


@dataclass(frozen=True)
class Discretisation:
    name: str
    overrides: tuple[str, ...]
    description: str
    grading: float = 1.0  # > 1: the mesh graded towards the ends of Gamma_3 (graded_level)
    adaptive: bool = False  # the adaptive loop's steps (harness/study/adapt.py) in place of levels


DISCRETISATIONS = {
    "P1": Discretisation("P1", ("scene.element=P1",), "P1 for all fields (the paper's)"),
    "P2": Discretisation("P2", ("scene.element=P2",), "P2 for all fields"),
    "P1-rtol": Discretisation(
        "P1-rtol", ("scene.element=P1", "newton.rtol=1e-4"), "P1, Newton stopped at a relative increment of 1e-4"
    ),
    # Non-nested with the reference: its error is integrated on the reference mesh with
    # every triangle split in 4 (reference_error.idp); against 16 the error norms moved by
    # < 0.01 % (and by < 0.2 % against no split) at h = 1/4, 1/8.
    "P1-graded": Discretisation(
        "P1-graded", ("scene.element=P1", "reference.split=2"),
        "P1 on a mesh graded towards the ends of Gamma_3 (x -> 1, 3 and y -> 0, power 1.5)", grading=1.5,
    ),
    # Bisected from the coarsest mesh where the estimate is large: not nested in the reference
    # either (newest-vertex bisection cuts a square along both diagonals), hence the split.
    "P1-adaptive": Discretisation(
        "P1-adaptive", ("scene.element=P1", "reference.split=2"),
        "P1 on meshes adapted by the error estimate (Dörfler 0.5, bisection from the coarsest level)", adaptive=True,
    ),
}
# The adaptive loop of the cost study: steps enough to reach the budget (the unknowns of the P1
# level n_ref/2, where the error fits end) from n = 2.
ADAPT_STEPS = 60



# ---------------------------------------------------------------- fits and the frontier


@dataclass(frozen=True)
class Fits:
    """E(h) = C h^p per error name, T(h) = D h^-q (chain seconds), M(h) = G h^-r (MB)."""

    errors: dict[str, PowerLaw]
    time: PowerLaw  # exponent is -q
    memory: PowerLaw  # exponent is -r
    h_range: tuple[float, float]  # the h of the error fits (extrapolation outside)

    def h_for(self, name: str, tau: float) -> float:
        law = self.errors[name]
        return law.solve(tau) if law.valid and law.exponent > 0 else math.nan


def fit_discretisation(rows: pd.DataFrame, error_levels: Sequence[int], cost_min_n: int) -> Fits:
    """Error fits over `error_levels`, time and memory fits over those of them with
    n >= cost_min_n (below that the fixed costs, start-up and the harness, dominate)."""
    err = rows[rows["n"].isin(error_levels)]
    cost = err[err["n"] >= cost_min_n]
    if len(cost) < 2:
        cost = rows.tail(2)
    errors = {name: power_fit(err["h"], err[error_column(name)]) for name in ERROR_NAMES if error_column(name) in err}
    h = err["h"].to_numpy(dtype=float)
    return Fits(
        errors=errors,
        time=power_fit(cost["h"], cost["chain_s"]),
        memory=power_fit(cost["h"], cost["peak_rss_mb"]),
        h_range=(float(h.min()), float(h.max())) if len(h) else (math.nan, math.nan),
    )


def frontier_rows(
    fits: dict[str, Fits], norms: dict[str, float], taus_rel: Sequence[float] = TAUS_REL
) -> list[dict[str, Any]]:
    """To reach E <= tau: h, level (the next power of two), predicted seconds and MB."""
    out = []
    for name in ERROR_NAMES:
        if name not in norms:
            continue
        for tau_rel in taus_rel:
            tau = tau_rel * norms[name]
            for disc, fit in fits.items():
                if name not in fit.errors:
                    continue
                h = fit.h_for(name, tau)
                ok = math.isfinite(h) and h > 0
                out.append({
                    "field": name,
                    "tau_rel": tau_rel,
                    "tau": tau,
                    "discretisation": disc,
                    "h": h if ok else math.nan,
                    "n_needed": 1.0 / h if ok else math.nan,
                    "level": next_level(h) if ok else math.nan,
                    "time_s": fit.time(h) if ok else math.nan,
                    "memory_mb": fit.memory(h) if ok else math.nan,
                    "extrapolated": bool(ok and not (fit.h_range[0] <= h <= fit.h_range[1])),
                    # How far outside the fitted h range (1 inside it).
                    "extrapolation": max(fit.h_range[0] / h, h / fit.h_range[1], 1.0) if ok else math.nan,
                    "p": fit.errors[name].exponent,
                    "q": -fit.time.exponent,
                })
    return out


def next_level(h: float) -> int:
    """The first power of two n with 1/n <= h (the level a nested study would run)."""
    return 2 ** max(0, math.ceil(math.log2(1.0 / h) - 1e-9))


def cheapest(frontier: pd.DataFrame) -> dict[str, dict[str, str]]:
    """Per field and tau_rel, the discretisation with the smallest predicted time (among
    predictions at most MAX_EXTRAPOLATION outside their fitted levels)."""
    out: dict[str, dict[str, str]] = {}
    ok = frontier[np.isfinite(frontier["time_s"]) & (frontier["extrapolation"] <= MAX_EXTRAPOLATION)]
    for (name, tau_rel), group in ok.groupby(["field", "tau_rel"], sort=False):
        best = group.loc[group["time_s"].idxmin()]
        out.setdefault(name, {})[f"{tau_rel:g}"] = str(best["discretisation"])
    return out


@dataclass
class CostStudy:
    scene: str
    reference: tuple[str, int]
    table: pd.DataFrame
    scaling: pd.DataFrame
    startup_s: float
    load_1min: float
    norms: dict[str, float] = field(default_factory=dict)
    fits: dict[str, Fits] = field(default_factory=dict)
    frontier: pd.DataFrame = field(default_factory=pd.DataFrame)


def row_of(
    scene_name: str, disc: str, element: str, run: RunResult, mesh_s: float, startup_s: float,
    finer_than_reference: bool = False,
) -> dict[str, Any]:
    r = run.record
    reference_s = float(r.reference_s or 0.0)
    errors = {} if finer_than_reference else (r.reference_errors or {})
    wall = float(r.value("wall_s")) - reference_s
    total = float(r.value("total_s")) - reference_s
    row = {
        "scene": scene_name,
        "discretisation": disc,
        "element": element,
        "n": run.n,
        "h": 1.0 / run.n,
        "dofs": r.dofs,
        "newton_iterations": r.newton_iterations,
        "factorisations": r.factorisations,
        "gmres_iterations": r.gmres_iterations,
        "mesh_s": mesh_s,
        "startup_s": startup_s,
        "bulk_assembly_s": r.bulk_assembly_s,
        "assembly_s": r.assembly_s,
        "factorisation_s": r.factorisation_s,
        "first_factorisation_s": r.first_factorisation_s,
        "solve_s": r.solve_s,
        "newton_s": r.newton_s,
        "output_s": r.output_s,
        "total_s": total,
        "wall_s": wall,
        "reference_s": reference_s,
        "peak_rss_mb": r.peak_rss_mb,
        "rss_source": r.peak_rss_source,
        "newton_over_linear": r.newton_over_linear,
        "reused": run.reused,
    }
    for name in FIELD_NAMES:
        row[error_column(name)] = errors.get(name, math.nan)
    row[error_column(TOTAL)] = sum(errors.get(f, 0.0) for f in FIELD_NAMES) if errors else math.nan
    return row


def add_chain_costs(table: pd.DataFrame) -> pd.DataFrame:
    """chain_s: mesh + run wall time summed over the chain up to each level."""
    # Stable: two adaptive steps may share their rounded n; they stay in step order.
    table = table.sort_values(["discretisation", "n"], kind="stable").reset_index(drop=True)
    table["chain_s"] = (table["mesh_s"] + table["wall_s"]).groupby(table["discretisation"]).cumsum()
    return table


def scene_names(base: str, discretisations: Sequence[str]) -> list[str]:
    """The scene directories of a cost study's runs (under its results' runs/)."""
    return [f"{base}-reference", *(f"{base}-{name}" for name in discretisations)]


def planned_scenes(case: Path, levels: Sequence[int], discretisations: Sequence[str], reference: tuple[str, int],
                   scaling_levels: Sequence[int], overrides: Sequence[str]) -> list[tuple[Scene, tuple[int, ...]]]:
    """Each chain a cost study will run, as the guards see it (the element and the finest
    levels decide its memory): the reference's, and each discretisation's (P1 on to the
    scaling levels)."""
    element, ref_n = reference
    out = [(load_scene(case, [*overrides, f"scene.element={element}"]),
            tuple(sorted({n for n in levels if n < ref_n} | {ref_n})))]
    for name in discretisations:
        scene = load_scene(case, [*overrides, *DISCRETISATIONS[name].overrides])
        chain = [n for n in levels if n <= ref_n] + (list(scaling_levels) if name == "P1" else [])
        out.append((scene, tuple(sorted(set(chain)))))
    return out


def run_cost(
    case: Path,
    levels: Sequence[int],
    discretisations: Sequence[str],
    reference: tuple[str, int],
    scaling_levels: Sequence[int],
    overrides: Sequence[str],
    results: Path,
    force: bool = False,
    progress: Progress = stderr_line,
    scripts: Path = Layout().freefem,
) -> CostStudy:
    layout = Layout(results=results / "runs", freefem=scripts)
    base = load_scene(case, overrides)
    check_solver_files(base, layout)
    freefem.freefem_version()
    load = os.getloadavg()[0]
    startup = freefem_startup_s()
    progress(f"FreeFEM start-up (empty script, median of 5): {startup:.3f} s; 1-min load {load:.2f}")
    ref_element, ref_n = reference

    # The reference: a chain in the reference's element up to ref_n, measuring nothing.
    ref_scene = load_scene(case, [*overrides, f"scene.name={base.name}-reference", f"scene.element={ref_element}"])
    ref_levels = sorted({n for n in levels if n < ref_n} | {ref_n})
    progress(f"reference: {ref_element} at n = {ref_n} (chain {ref_levels})")
    meshes, mesh_s = timed_meshes(ref_scene, ref_levels, layout)
    ref_runs = runs_of(run_levels(ref_scene, meshes, layout, force=force, progress=progress, pipelined=False))
    ref_run = ref_runs[ref_n]
    ref_options = [
        f"reference.mesh={json.dumps(str(meshes[ref_n].resolve()))}",
        f"reference.state={json.dumps(str((ref_run.directory / 'state.txt').resolve()))}",
        f"reference.element={ref_element}",
    ]
    rows = [row_of(base.name, f"{ref_element} (reference)", ref_element, ref_runs[n], mesh_s[n], startup)
            for n in ref_levels]

    norms: dict[str, float] = {}
    for name in discretisations:
        disc = DISCRETISATIONS[name]
        scene = load_scene(case, [*overrides, *disc.overrides, f"scene.name={base.name}-{name}", *ref_options])
        # A level of the reference's own element and mesh would measure the reference against itself.
        disc_levels = [n for n in levels if n <= ref_n and not (n == ref_n and scene.element == ref_element)]
        if disc.adaptive:
            progress(f"{name}: {disc.description}")
            rows += adaptive_rows(base.name, scene, rows, ref_n, layout, force, startup, progress)
            continue
        progress(f"{name}: {disc.description}, levels {disc_levels}")
        meshes, mesh_s = timed_meshes(scene, disc_levels, layout, disc.grading)
        runs = runs_of(run_levels(scene, meshes, layout, force=force, progress=progress, pipelined=False))
        rows += [row_of(base.name, name, scene.element, runs[n], mesh_s[n], startup) for n in disc_levels]
        norms = norms or reference_norms(runs[disc_levels[0]].record)
        if name == "P1":
            rows += [dict(r, scene=base.name) for r in scaling_rows(
                scene, [n for n in scaling_levels if n not in runs], runs, meshes, layout, force, startup, progress)]

    table = add_chain_costs(pd.DataFrame(rows))
    scaling = table[table["discretisation"] == "P1"].reset_index(drop=True)
    study = CostStudy(base.name, reference, table, scaling, startup, load, norms)
    analyse(study, discretisations)
    return study


def adaptive_rows(
    scene_name: str, scene: Scene, rows: list[dict[str, Any]], ref_n: int, layout: Layout, force: bool, startup: float,
    progress: Progress,
) -> list[dict[str, Any]]:
    """The adaptive loop's steps, each measured against the study's reference like a level,
    until a step has as many unknowns as the P1 level n_ref/2. A step has no h: its row gets
    that of the uniform P1 level with as many unknowns (log-log interpolation between P1's
    levels), so that the fits and the frontier put it on the same axis; `step` and `dofs` say
    what it is. Its chain time is the loop's: every step's mesh and run up to it."""
    p1 = pd.DataFrame([r for r in rows if r["discretisation"] == "P1" and math.isfinite(float(r.get("dofs") or math.nan))])
    if p1.empty:
        raise SceneError("discretisation 'P1-adaptive' is placed beside P1 (a step's h is that of the P1 level with "
                         "as many unknowns): ask for P1 too")
    p1 = p1.sort_values("dofs")
    budget = p1.loc[p1["n"] == ref_n // 2, "dofs"]
    adaptation = adapt(scene, None, layout, ADAPT_STEPS, DEFAULT_BULK, int(budget.iloc[0]) if len(budget) else None,
                       force, progress, progress)
    out = []
    for step in adaptation.steps:
        row = row_of(scene_name, "P1-adaptive", "P1", step.run, step.mesh_s, startup)
        h = float(np.exp(np.interp(np.log(float(row["dofs"])), np.log(p1["dofs"].astype(float)),
                                   np.log(p1["h"].astype(float)))))
        row.update(n=round(1.0 / h), h=h, step=step.index)
        out.append(row)
    return out


def scaling_rows(
    scene: Scene, levels: Sequence[int], runs: dict[int, RunResult], meshes: dict[int, Path], layout: Layout,
    force: bool, startup: float, progress: Progress,
) -> list[dict[str, Any]]:
    """The P1 chain continued to finer levels, for time and memory against dofs only. A
    level that fails (out of memory, say) ends the chain with a row saying why, not the study."""
    if not levels:  # a study without scaling levels (or with all of them among its own)
        return []
    rows = []
    below = max(runs)
    finer = InlineMeshes(scene, levels, layout)
    outcomes = run_levels(scene, finer, layout, force=force, progress=quiet, pipelined=False,
                          warm=runs[below].warm_start(meshes[below]))
    for n, outcome in outcomes.items():
        if outcome.run is None:
            progress(f"scaling n={n} FAILED: {outcome.detail}")
            rows.append({"scene": scene.name, "discretisation": "P1", "element": "P1", "n": n, "h": 1.0 / n,
                         "mesh_s": finer.seconds.get(n, math.nan), "startup_s": startup, "failure": outcome.detail})
            break
        progress(f"scaling n={n} done in {outcome.wall_s:.1f} s")
        rows.append(row_of(scene.name, "P1", "P1", outcome.run, finer.seconds[n], startup, finer_than_reference=True))
    return rows


def reference_norms(record: RunRecord) -> dict[str, float]:
    norms = dict(record.reference_norms or {})
    if norms:
        norms["total"] = sum(norms.values())
    return norms


def analyse(study: CostStudy, discretisations: Sequence[str], error_min_n: int = 4, cost_min_n: int = 16) -> None:
    """Fits per discretisation and the frontier. The error fits use the levels 4 <= n <=
    n_ref/2 (h = 1/2 is pre-asymptotic; at the reference's own h, P1's error against P2
    carries ~10 % of the reference's own error) and, for the reference's own element,
    n <= n_ref/4 (the level next to the reference carries the reference's own error in
    full). The time and memory fits use the same levels from n = 16 on (below, start-up
    and the harness dominate)."""
    ref_element, ref_n = study.reference
    for name in discretisations:
        rows = study.table[study.table["discretisation"] == name]
        if rows.empty:
            continue
        element = rows["element"].iloc[0]
        top = ref_n // 4 if element == ref_element else ref_n // 2
        levels = [n for n in rows["n"] if error_min_n <= n <= top]
        if len(levels) < 2:  # a short study: the last two levels that have errors
            levels = list(rows[np.isfinite(rows[error_column(TOTAL)].astype(float))]["n"])[-2:]
        study.fits[name] = fit_discretisation(rows, levels, cost_min_n)
    study.frontier = pd.DataFrame(frontier_rows(study.fits, study.norms))


def fits_table(study: CostStudy) -> pd.DataFrame:
    rows = []
    for disc, fit in study.fits.items():
        for name, law in fit.errors.items():
            rows.append({
                "discretisation": disc, "field": name, "C": law.coefficient, "p": law.exponent,
                "error_points": law.points, "h_min": fit.h_range[0], "h_max": fit.h_range[1],
                "D": fit.time.coefficient, "q": -fit.time.exponent, "G": fit.memory.coefficient,
                "r": -fit.memory.exponent,
                # Time grows 10^(q/p) per digit of accuracy in this field.
                "time_factor_per_digit": 10 ** (-fit.time.exponent / law.exponent) if law.valid else math.nan,
            })
    return pd.DataFrame(rows)


def frontier_markdown(study: CostStudy) -> str:
    f = study.frontier
    lines = [
        f"# {study.scene}: what accuracy costs",
        "",
        f"Reference: {study.reference[0]} at h = 1/{study.reference[1]}. Fits E(h) = C h^p "
        f"(levels 4 <= n <= n_ref/2, n <= n_ref/4 for the reference's element), T(h) = D h^-q "
        f"(chain wall seconds, the same levels from n = 16), M(h) = G h^-r (peak MB). tau is relative to "
        f"the reference's own seminorm of the field; `*` marks an extrapolation beyond the "
        f"fitted levels, and beyond a factor {MAX_EXTRAPOLATION:g} in h there is no prediction.",
        "",
        markdown_table(("discretisation", "field", "p", "q", "time x per digit"),
                       ([r["discretisation"], r["field"], f"{r['p']:.2f}", f"{r['q']:.2f}",
                         f"{r['time_factor_per_digit']:.3g}"] for _, r in fits_table(study).iterrows())).rstrip("\n"),
    ]
    for name in ERROR_NAMES:
        part = f[f["field"] == name] if not f.empty else f
        if part.empty:
            continue
        discs = list(dict.fromkeys(part["discretisation"]))
        rows = []
        for tau_rel, group in part.groupby("tau_rel", sort=False):
            cells = []
            for disc in discs:
                r = group[group["discretisation"] == disc]
                if r.empty or not math.isfinite(r["h"].iloc[0]):
                    cells.append("-")
                    continue
                r = r.iloc[0]
                if r["extrapolation"] > MAX_EXTRAPOLATION:
                    cells.append(f"(h = 1/{r['n_needed']:.0f}: too far out)")
                    continue
                star = "*" if r["extrapolated"] else ""
                cells.append(f"h = 1/{r['n_needed']:.0f}{star}, {r['time_s']:.3g} s, {r['memory_mb']:.0f} MB")
            rows.append([f"{tau_rel:g}", f"{group['tau'].iloc[0]:.3g}", *cells])
        lines += ["", f"## {name}: to reach E <= tau you need", "",
                  markdown_table(("tau (rel)", "tau", *discs), rows).rstrip("\n")]
    best = cheapest(f) if not f.empty else {}
    if best:
        lines += ["", "## Cheapest per field (smallest predicted time)", ""]
        for name, by_tau in best.items():
            lines.append(f"- {name}: " + ", ".join(f"tau {t}: {d}" for t, d in by_tau.items()))
    return "\n".join(lines) + "\n"


def summary(study: CostStudy) -> dict[str, Any]:
    table = study.table
    p1 = table[table["discretisation"] == "P1"]
    finest = p1.iloc[-1] if not p1.empty else None
    return {
        "scene": study.scene,
        "reference": {"element": study.reference[0], "n": study.reference[1]},
        "reference_norms": study.norms,
        "freefem_startup_s": study.startup_s,
        "load_1min_at_start": study.load_1min,
        "reused_runs": int(table["reused"].sum()),
        "p1_finest": None if finest is None else {
            k: finest[k] for k in ("n", "dofs", "wall_s", "chain_s", "newton_over_linear", "peak_rss_mb")
        },
        "fits": fits_table(study).to_dict(orient="records"),
        "cheapest": cheapest(study.frontier) if not study.frontier.empty else {},
        "scaling": study.scaling[[c for c in ("n", "dofs", "newton_iterations", "wall_s", "peak_rss_mb",
                                              "rss_source", "newton_over_linear", "failure") if c in study.scaling]]
        .to_dict(orient="records") if not study.scaling.empty else [],
        "scaling_exponents": scaling_exponents(study.scaling),
    }


def write_outputs(study: CostStudy, directory: Path) -> list[Path]:
    written = [
        write_csv(study.table, directory / "cost.csv"),
        write_csv(fits_table(study), directory / "fits.csv"),
        write_csv(study.frontier, directory / "frontier.csv"),
        write_text(frontier_markdown(study), directory / "frontier.md"),
        write_csv(study.scaling, directory / "scaling.csv"),
        write_json(summary(study), directory / "summary.json"),
    ]
    plots = {
        "cost_vs_time.png": lambda p: plot_errors(study, "chain_s", "wall seconds (chain up to the level)", p),
        "cost_vs_dofs.png": lambda p: plot_errors(study, "dofs", "dofs", p),
        "time_split.png": lambda p: plot_time_split(study, p),
        "scaling.png": lambda p: plot_scaling(study, p),
    }
    written += [directory / name for name, plot in plots.items() if write_with(plot, directory / name)]
    return written


