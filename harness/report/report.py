"""Write a study's baseline (convergence.csv, summary.json, convergence.png, and each quantity's
convergence: quantities.csv, quantities.png) all or nothing."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import pandas as pd

from harness.core.atomic import sibling_temp
from harness.core.faults import naming
from harness.core.layout import Layout
from harness.measure.norm_table import TOTAL, error_column, error_names
from harness.measure.quantity_study import QuantityConvergence, quantity_convergence, quantity_values
from harness.measure.tolerances import ToleranceVerdict, judge
from harness.report.plot import plot_convergence, plot_quantities
from harness.measure.rates import scaling_exponents
from harness.measure.fields import read_fields
from harness.scene.gmsh_geometry import GmshGeometry
from harness.mesh.simplex import quality
from harness.study.study import Study
from harness.core.versions import tool_versions
from harness.core.writers import PRECISE_CSV_FORMAT, csv_text, json_text

# Physical quantities of each run worth keeping next to the errors (from run.json).
RUN_FACTS = (
    "converged", "newton_iterations", "wall_s", "dofs", "max_theta", "min_phi", "max_phi",
    "max_abs_u", "contact_force", "active_measure", "initial_guess", "peak_rss_mb",
)


def write_report(study: Study, layout: Layout) -> dict[str, Path]:
    """Render every file to a temp name first; only when all three exist are they moved over
    the previous baseline, so a failure part-way leaves the old baseline whole."""
    directory = layout.case_dir(study.scene.name)
    targets = {
        "csv": directory / "convergence.csv",
        "summary": directory / "summary.json",
        "plot": directory / "convergence.png",
        "quantities_csv": directory / "quantities.csv",
        "quantities_plot": directory / "quantities.png",
    }
    values = quantity_values(study.scene, {n: run.record for n, run in study.runs.items()})
    studied = quantity_convergence(study.scene, values)
    temps = {kind: sibling_temp(path) for kind, path in targets.items()}
    try:
        with naming(targets["csv"]):
            temps["csv"].write_text(csv_text(study.table, PRECISE_CSV_FORMAT))
        with naming(targets["summary"]):
            judged = tolerance_verdicts(study, studied)
            temps["summary"].write_text(json_text({**summary(study), "quantities": {
                name: q.summary() for name, q in studied.items()},
                **({"tolerances": {name: v.summary() for name, v in judged.items()}} if judged else {})}))
        with naming(targets["plot"]):
            plot_convergence(study, temps["plot"])
        with naming(targets["quantities_csv"]):
            temps["quantities_csv"].write_text(csv_text(values, PRECISE_CSV_FORMAT))
        with naming(targets["quantities_plot"]):
            plot_quantities(study.scene.name, values, studied, temps["quantities_plot"])
        for kind, target in targets.items():
            os.replace(temps[kind], target)
    finally:
        for tmp in temps.values():
            tmp.unlink(missing_ok=True)
    return targets


def tolerance_verdicts(study: Study, studied: dict[str, QuantityConvergence] | None = None
                       ) -> dict[str, ToleranceVerdict]:
    """The case's tolerances judged on the study's finest level (none: an empty dict)."""
    if not study.scene.tolerances:
        return {}
    if studied is None:
        studied = quantity_convergence(study.scene, quantity_values(
            study.scene, {n: run.record for n, run in study.runs.items()}))
    return judge(study.scene.tolerances, studied, study.runs[study.reference].record)


def summary(study: Study) -> dict[str, Any]:
    low, high = study.scene.slope_band
    finest = study.table.iloc[-2]  # the finest level with an error
    return {
        "case": study.scene.name,
        "description": study.scene.sections.scene.description,
        "material": study.scene.material,
        "initial_guess": study.scene.initial_guess,
        "levels": [int(n) for n in study.table["n"]],
        # Each level's largest cell edge in the model's units (n is a level's label, not a length).
        "h_max": [float(h) for h in study.table["h_max"]],
        "warnings": list(study.warnings),
        "reference_n": study.reference,
        "fields": list(study.fields),
        "slopes": study.slopes,
        "verdict_on": "total slope fitted over every non-reference level",
        "slope_band": [low, high],
        "verdict": "pass" if study.passed else "fail",
        # The three terms carry different units; say which one dominates the sum.
        "share_of_total_at_finest": {f: finest[error_column(f)] / finest[error_column(TOTAL)] for f in study.fields},
        "sweep_wall_s": study.wall_s,
        # What a level costs against its unknowns (wall time, FreeFEM's peak memory), fitted
        # from n = COST_FIT_FROM on: the coarser levels are start-up, not the solver's scaling.
        "cost_vs_dofs": cost_exponents(study),
        # Each level's cache key: a level dir whose inputs.json differs is not this study's run.
        "runs": {str(n): {**{k: getattr(run.record, k) for k in RUN_FACTS}, "key": run.key, **mesh_quality(study, n),
                          **({"warnings": run.record.warnings} if run.record.warnings else {})}
                 for n, run in sorted(study.runs.items())},
        "scene": study.scene.table,
        "tools": tool_versions(),
    }


COST_FIT_FROM = 8


def mesh_quality(study: Study, n: int) -> dict[str, Any]:
    """A gmsh scene's level mesh: min angle (2D) or dihedral (3D) in degrees and max aspect
    (harness/mesh/simplex.py quality), from the mesh level n solved on (its solution, parsed once
    by the study). The other kinds' meshes are structured (or the box's and rectangle's
    distorted ones), their quality known."""
    if not isinstance(study.scene.geometry, GmshGeometry):
        return {}
    fields = study.solutions.get(n) or read_fields(study.runs[n].solution)
    return {"mesh_quality": quality(fields.points.astype(float), fields.cells)}


def cost_exponents(study: Study) -> dict[str, float]:
    rows = [{"n": n, "dofs": run.record.dofs, "wall_s": run.record.wall_s, "peak_rss_mb": run.record.peak_rss_mb}
            for n, run in study.runs.items()]
    fits = scaling_exponents(pd.DataFrame(rows), COST_FIT_FROM)
    return fits if sum(r["n"] >= COST_FIT_FROM for r in rows) >= 2 else {}


def format_table(study: Study) -> str:
    columns = ["n", "h", "h_max", "dofs", "newton_iterations", "wall_s"]
    columns += [error_column(f) for f in error_names(study.fields)] + [f"order_{TOTAL}"]
    return study.table[columns].to_string(index=False, float_format=lambda v: f"{v:.4g}", na_rep="-")
