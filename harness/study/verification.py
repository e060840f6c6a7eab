"""Verification beyond self-convergence, the library of `make verify`
(harness/studies/verify.py): the manufactured cases' true errors per level, field and norm
(cases/mms/*.toml, harness/scene/mms.py) and their fitted slopes against the accepted bands."""

from __future__ import annotations

import math
from typing import Mapping, Sequence

import pandas as pd

from harness.study.engine import InlineMeshes, Progress, run_levels, runs_of, stderr_line
from harness.core.errors import RunError
from harness.core.freefem import freefem_version
from harness.core.layout import REPO, Layout
from harness.measure.norm_table import MMS_NORMS
from harness.measure.rates import slope_fit
from harness.run.run import RunResult, check_solver_files
from harness.scene.scene import Scene

MMS_CASES = {"bulk": REPO / "cases" / "mms" / "bulk.toml", "contact": REPO / "cases" / "mms" / "contact.toml",
             "coulomb": REPO / "cases" / "mms" / "contact_coulomb.toml",
             "wedge": REPO / "cases" / "mms" / "contact_wedge.toml",
             "interface": REPO / "cases" / "mms" / "interface.toml"}
MMS_LEVELS = (4, 8, 16, 32)
# The 3D cases (issue 12) on their own levels: h = 1/32 of the 2x1x1 box is ~350,000 dofs.
MMS_CASES_3D = {"bulk3d": REPO / "cases" / "mms" / "bulk3d.toml", "contact3d": REPO / "cases" / "mms" / "contact3d.toml",
                "tilted3d": REPO / "cases" / "mms" / "tilted3d.toml"}
MMS_LEVELS_3D = (4, 8, 16)
# Cases on levels of their own: the turned box's gmsh tetrahedra start at h = 1/2 (split
# levels), and its n = 16 (359k tetrahedra) took 455 s and 9.6 GB with MUMPS.
CASE_LEVELS = {"tilted3d": (2, 4, 8)}
# P1's order on a smooth solution and the accepted slopes, per norm (norm_table.MMS_NORMS,
# which says why the bands are what they are).
EXPECTED = {n.key: n.order for n in MMS_NORMS}
BANDS = {n.key: n.band for n in MMS_NORMS}
BANDS_3D = {n.key: n.band_3d for n in MMS_NORMS}


def band(dimension: int, norm: str) -> tuple[float, float]:
    return (BANDS_3D if dimension == 3 else BANDS)[norm]


def known_dimensions() -> dict[str, int]:
    """The built-in cases' dimensions, by name."""
    return {**{c: 2 for c in MMS_CASES}, **{c: 3 for c in MMS_CASES_3D}}


def mms_runs(scene: Scene, levels: Sequence[int], layout: Layout, jobs: int = 2, force: bool = False,
             progress: Progress = stderr_line) -> dict[int, RunResult]:
    """The manufactured case's runs, by level."""
    if not scene.manufactured:
        raise RunError(f"{scene.source} has no [manufactured] solution")
    check_solver_files(scene, layout)
    freefem_version()
    meshes = InlineMeshes(scene, levels, layout).made()
    return runs_of(run_levels(scene, meshes, layout, force=force, progress=progress,
                              chain=scene.initial_guess == "coarser", jobs=jobs))


def mms_errors(scene: Scene, levels: Sequence[int], layout: Layout, jobs: int = 2, force: bool = False,
               progress: Progress = stderr_line) -> pd.DataFrame:
    """One row per level, field and norm: the error FreeFEM measured against the exact field,
    and the exact field's own norm (run.json's mms_errors, mms_norms)."""
    return error_table(scene, mms_runs(scene, levels, layout, jobs, force, progress))


def error_table(scene: Scene, runs: dict[int, RunResult]) -> pd.DataFrame:
    rows = []
    for n, run in sorted(runs.items()):
        errors, norms = run.record.mms_errors, run.record.mms_norms
        if not isinstance(errors, dict) or not isinstance(norms, dict):
            raise RunError(f"{run.directory}/run.json has no mms_errors/mms_norms: the scheme did not "
                           "run the manufactured solution (freefem/mms.idp, IFMACRO(MMS))")
        for field in scene.fields:
            for norm in EXPECTED:
                rows.append({"n": n, "h": 1.0 / n, "field": field, "norm": norm,
                             "error": float(errors[field][norm]), "exact_norm": float(norms[field][norm]),
                             "newton_iterations": run.record.newton_iterations})
    table = pd.DataFrame(rows)
    table["relative_error"] = table["error"] / table["exact_norm"]
    return table


def effectivity_table(scene: Scene, runs: dict[int, RunResult]) -> pd.DataFrame:
    """One row per level and field: the recovery estimate eta of the field's error in its norm
    of E^h (freefem/estimator.idp), the true error in that norm against the exact field, and
    the effectivity index eta / error (1: the estimate is exact)."""
    rows = []
    for n, run in sorted(runs.items()):
        eta, error = run.record.estimator, run.record.mms_measure_errors
        if not isinstance(eta, dict) or not isinstance(error, dict):
            raise RunError(f"{run.directory}/run.json has no estimator/mms_measure_errors (freefem/estimator.idp)")
        for field in scene.fields:
            rows.append({"n": n, "h": 1.0 / n, "dofs": run.record.dofs, "field": field,
                         "eta": float(eta[field]), "error": float(error[field]),
                         "effectivity": float(eta[field]) / float(error[field])})
    return pd.DataFrame(rows)


def mms_rates(errors: pd.DataFrame, dimensions: Mapping[str, int] | None = None) -> pd.DataFrame:
    """One row per (case, field, norm): the fitted slope and its standard error over all
    levels, the last pairwise order, and the finest level's error; its band is that of the
    case's dimension (`dimensions`, by case; the built-in cases' by default)."""
    dimensions = known_dimensions() if dimensions is None else dimensions
    rows = []
    for (case, field, norm), group in errors.groupby(["case", "field", "norm"], sort=False):
        low, high = band(dimensions[case], norm)
        group = group.sort_values("h", ascending=False)
        fit = slope_fit(group["h"], group["error"])
        e, h = group["error"].to_numpy(), group["h"].to_numpy()
        last_order = math.log(e[-2] / e[-1]) / math.log(h[-2] / h[-1]) if len(e) > 1 else math.nan
        rows.append({
            "case": case, "field": field, "norm": norm, "expected": EXPECTED[norm],
            "slope": fit.slope, "slope_stderr": fit.stderr, "last_pair_order": last_order,
            "n_finest": int(group["n"].iloc[-1]), "err_finest": e[-1],
            "rel_err_finest": group["relative_error"].iloc[-1], "levels": len(e),
            "within_band": bool(low <= fit.slope <= high),
        })
    return pd.DataFrame(rows)


