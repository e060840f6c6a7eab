"""`python -m harness adapt CASE`: adaptive refinement driven by the a posteriori error
estimate, in 2D and 3D (docs/adaptivity.md), into results/adapt/<case>/.
Its runs are under that folder too: the steps' in step<i>/, the reference's in reference/, the
uniform levels' in uniform/.

Each step solves on the refinement of the step before: Dörfler marking of the recovery
estimate (--bulk), newest-vertex bisection in 2D, longest-edge bisection in 3D. The true error
of every step, and of the case's uniform levels, is measured against one overkill reference
(the last mesh refined uniformly), or against the exact fields of a manufactured case (which
then solves no reference). Writes adapt.csv (per step: dofs, the estimate and the error per
field, Newton iterations, time, memory, mesh quality), uniform.csv, summary.json (rates in N
per field: 1/d is optimal; effectivities; the first step that matches the finest uniform
level), adapt.png (error against dofs, adaptive and uniform) and mesh.png (the last adapted
mesh; in 3D its lowest face). Every step and the reference pass the physical checks or the
verdict fails; a step or reference that would not fit in memory ends it with exit 4, the
steps done reported.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from harness.study.adapt import (DEFAULT_BULK, Adaptation, adapt, adaptive_overrides, check_adaptable,
                                 errors_against, uniform_runs)
from harness.arguments import add_case, add_common, positive_int
from harness.study.engine import quiet
from harness.measure.fields import read_fields
from harness.core.layout import Layout
from harness.measure.norm_table import FIELD_NAMES, error_label
from harness.core.errors import EnvironmentFault
from harness.core.guards import check_adapt_not_shallower
from harness.measure.run_checks import failed_checks, print_checks
from harness.study.pipeline import Guarded, Plan, check_level_memory, level_dofs, run_pipeline, scene_of
from harness.measure.rates import slope_fit
from harness.run.run import check_solver_files
from harness.scene.scene import Scene
from harness.core.writers import PRECISE_CSV_FORMAT, write_csv, write_json, write_with


def bulk_fraction(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0 < value <= 1:
        raise argparse.ArgumentTypeError(f"must be in (0, 1], not {text}")
    return value


# The fewest steps that give a rate: it is fitted over the later half of the steps, and a
# line needs two points.
MIN_STEPS = 3


def step_count(text: str) -> int:
    value = positive_int(text)
    if value < MIN_STEPS:
        raise argparse.ArgumentTypeError(f"{text!r} steps give no rate in N: it is fitted over the later half of "
                                         f"the steps, which needs at least {MIN_STEPS} steps")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_case(parser)
    parser.add_argument("--steps", type=step_count, default=12,
                        help=f"solves at most, the first on the case's coarsest mesh (at least {MIN_STEPS}: the "
                             "rate is fitted over the later half of them; default 12)")
    parser.add_argument("--bulk", type=bulk_fraction, default=DEFAULT_BULK,
                        help="Dörfler's fraction: refine the fewest cells that hold this share of the "
                             f"squared estimate (0 < bulk <= 1; 1 refines everything; default {DEFAULT_BULK})")
    parser.add_argument("--max-dofs", type=positive_int, default=None,
                        help="stop after the first step with at least this many unknowns")
    parser.add_argument("--goal", default=None, metavar="NAME",
                        help="mark by this quantity's dual-weighted indicators instead (docs/goals.md), e.g. "
                             "heat_through_contact: each step's value and estimate into goal_adapt.csv")
    add_common(parser)


def study_layout(results: Path, freefem: Path, name: str) -> Layout:
    """results/adapt/<case>/, everything of the study under it, so that none of it meets a
    convergence study's levels (n<N>/) or another case's folder (a case named <case>_uniform):
    the report (adapt.csv, uniform.csv, summary.json, adapt.png, mesh.png), step<i>/ per step,
    meshes/ (the first level's, every step's and the reference's), and reference/ and uniform/,
    each a scene directory of its own (n<N>/; uniform/meshes/)."""
    out = results / name
    return Layout(results=results, freefem=freefem, stepped=(name,),
                  placed=((f"{name}_reference", out / "reference"), (f"{name}_uniform", out / "uniform")))


def rate_in_dofs(dofs: pd.Series, errors: pd.Series, dimension: int) -> float:
    """The error's decay rate in the number of unknowns N (err ~ N^-rate; 1/d is optimal)."""
    fit = slope_fit((dofs.astype(float) ** (-1.0 / dimension)).tolist(), errors.tolist())
    return fit.slope / dimension


def run_for_goal(args: argparse.Namespace) -> int:
    """The loop marked by a goal's indicators (harness/study/goals.py adapt_for_goal), into
    results/adapt/<case>_goal/goal_adapt.csv."""
    from harness.study.goals import adapt_for_goal

    named = scene_of(args.case, [*args.overrides, f"quantities.goals=[{args.goal!r}]".replace("'", '"')])
    scene = scene_of(args.case, [*args.overrides, f"quantities.goals=[{args.goal!r}]".replace("'", '"'),
                                 f'scene.name="{named.name}_goal"'])
    layout = Layout(results=args.results / "adapt", freefem=args.freefem)
    table = adapt_for_goal(scene, args.goal, layout, args.steps, args.bulk, args.max_dofs,
                           lambda line: print(line, file=sys.stderr))
    out = write_csv(table, layout.case_dir(scene.name) / "goal_adapt.csv", PRECISE_CSV_FORMAT)
    print(f"{scene.name}: {len(table)} steps marked by {args.goal}'s indicators; {out}")
    return 0


def run(args: argparse.Namespace) -> int:
    if args.goal:
        return run_for_goal(args)
    scene = scene_of(args.case, args.overrides)
    check_adaptable(scene)
    # The steps and the reference coarsen through adapted meshes (adaptive_overrides); the
    # uniform levels keep the scene's own solver and their cached runs.
    adaptive = [*args.overrides, *adaptive_overrides(scene)]
    scene = scene_of(args.case, adaptive)
    reference_scene = scene_of(args.case, [*adaptive, f'scene.name="{scene.name}_reference"'])
    uniform_scene = scene_of(args.case, [*args.overrides, f'scene.name="{scene.name}_uniform"'])
    layout = study_layout(args.results / "adapt", args.freefem, scene.name)
    out = layout.case_dir(scene.name)
    # The uniform levels are guarded once the reference says which of them are run (the
    # coarsest here, for its warnings and ranks). The study owns its folder whole (its steps'
    # meshes are made from its runs: an interrupted study must leave the earlier ones as they
    # were), and the reference's and uniform levels' folders in it as scene directories.
    plan = Plan(layout.results, (Guarded(scene, (scene.levels[0],)), Guarded(uniform_scene, (scene.levels[0],))),
                whole=(out,), ignore_memory=args.ignore_memory,
                scene_dirs=(layout.case_dir(reference_scene.name), layout.case_dir(uniform_scene.name)))
    print(f"adapt {scene.name}: up to {args.steps} steps, bulk {args.bulk}, into {out}", file=sys.stderr)
    check_adapt_not_shallower(out, args.steps, args.max_dofs)

    def runs() -> tuple[Adaptation, dict]:
        check_solver_files(scene, layout)
        # A manufactured case measures its errors against its exact fields: no reference to solve.
        adaptation = adapt(scene, None if scene.manufactured else reference_scene, layout, args.steps, args.bulk,
                           args.max_dofs, args.force, quiet, lambda line: print(line, file=sys.stderr, flush=True),
                           memory_guard=not args.ignore_memory)
        # Without a reference (it would not fit) a real scene's uniform levels have nothing to be measured against.
        measured = scene.manufactured or adaptation.reference is not None
        levels = tuple(scene.levels) if scene.manufactured or not measured else \
            uniform_levels_below(uniform_scene, adaptation.reference.record.dofs)
        if not measured or not levels:
            return adaptation, {}
        if not args.ignore_memory:
            try:
                check_level_memory(uniform_scene, levels)
            except EnvironmentFault as exc:  # as a step that would not fit: the steps reported, then exit 4
                print(exc, file=sys.stderr)
                return replace(adaptation, refused=str(exc)), {}
        return adaptation, uniform_runs(uniform_scene, layout, levels, args.force, quiet)

    def report(result: tuple[Adaptation, dict]) -> None:
        adaptation, uniform = result
        fields = solved_fields(adaptation, scene.fields)
        # A manufactured case measures every run against its exact fields, in the same norms; a
        # real scene whose reference would not fit in memory has its estimates alone.
        exact = scene.manufactured
        unmeasured = not exact and adaptation.reference is None
        reference = None if exact or unmeasured else read_fields(adaptation.reference.solution)

        def errors(run) -> dict[str, float]:  # noqa: ANN001 (a RunResult)
            if unmeasured:
                return {f: math.nan for f in fields}
            return dict(run.record.mms_measure_errors) if exact else errors_against(reference, run, fields)

        rows = []
        for step in adaptation.steps:
            r = step.run.record
            err = errors(step.run)
            rows.append({"step": step.index, "dofs": r.dofs, "cells": step.cells, "marked": step.marked,
                         **{f"eta_{f}": (r.estimator or {}).get(f, math.nan) for f in fields},
                         **{f"err_{f}": err[f] for f in fields},
                         "newton_iterations": r.newton_iterations, "wall_s": r.wall_s, "peak_mib": r.peak_rss_mb,
                         **step.quality})
        table = pd.DataFrame(rows)
        coarser = {n: run for n, run in sorted(uniform.items())
                   if exact or run.record.dofs < adaptation.reference.record.dofs}
        flat = pd.DataFrame([{"n": n, "dofs": run.record.dofs,
                              **{f"eta_{f}": (run.record.estimator or {}).get(f, math.nan) for f in fields},
                              **{f"err_{f}": v for f, v in errors(run).items() if f in fields},
                              "newton_iterations": run.record.newton_iterations, "wall_s": run.record.wall_s,
                              "peak_mib": run.record.peak_rss_mb}
                             for n, run in coarser.items()])
        write_csv(table, out / "adapt.csv", PRECISE_CSV_FORMAT)
        write_csv(flat, out / "uniform.csv", PRECISE_CSV_FORMAT)
        # The rate of the error over the later half of the steps that are at least 16 times
        # coarser than the reference (closer to it, the reference's own error biases the
        # measured error low and the rate high); the rate of the estimate, which needs no
        # reference, over the whole later half.
        later = table.iloc[len(table) // 2:]
        window = later if exact or unmeasured else later[later["dofs"] * 16 <= adaptation.reference.record.dofs]
        summary = {
            "case": scene.name, "steps": len(table), "bulk": args.bulk,
            "errors_against": "the exact fields" if exact else "nothing: no reference" if unmeasured else "the reference",
            "reference": None if exact or unmeasured else {"dofs": adaptation.reference.record.dofs,
                                             "mesh": os.path.relpath(adaptation.reference_mesh, out),
                                             "estimate": adaptation.reference.record.estimator},
            "rate_in_dofs": {"optimal": 1.0 / scene.dimension,
                             "adaptive": {f: math.nan if unmeasured else
                                          rate_in_dofs(window["dofs"], window[f"err_{f}"], scene.dimension)
                                          for f in fields},
                             "adaptive_estimate": {f: rate_in_dofs(later["dofs"], later[f"eta_{f}"], scene.dimension)
                                                   for f in fields},
                             "adaptive_steps": window["step"].tolist(),
                             "uniform": {f: rate_in_dofs(flat["dofs"], flat[f"err_{f}"], scene.dimension)
                                         if len(flat) else math.nan for f in fields}},
            "effectivity_last": {f: table[f"eta_{f}"].iloc[-1] / table[f"err_{f}"].iloc[-1] for f in fields},
            "effectivity_range": {f: [float((table[f"eta_{f}"] / table[f"err_{f}"]).min()),
                                      float((table[f"eta_{f}"] / table[f"err_{f}"]).max())] for f in fields},
            "matching_uniform": matching_uniform(table, flat, fields),
        }
        band = list(scene.sections.study.adaptive_band)
        summary["adaptive_band"] = band
        # Fewer than two steps in the later half (the loop stopped at --max-dofs or the memory
        # guard after one or two): no slope, and none to judge.
        summary["slope_of_estimate"] = None if len(later) < 2 else {
            f: scene.dimension * v for f, v in summary["rate_in_dofs"]["adaptive_estimate"].items()}
        judged["summary"] = summary
        write_json(summary, out / "summary.json")
        # Each plot drawn to a temp name and moved over its own: the study's backup holds the
        # earlier one as a hard link, which a write in place would change too.
        write_with(lambda tmp: plot_adapt(table, flat, fields, summary, tmp), out / "adapt.png")
        write_with(lambda tmp: plot_mesh(adaptation.steps[-1].mesh, tmp, scene.name), out / "mesh.png")
        print(table[["step", "dofs", *[f"eta_{f}" for f in fields], *[f"err_{f}" for f in fields],
                     "newton_iterations"]].to_string(index=False, float_format=lambda v: f"{v:.4g}"))
        rates = summary["rate_in_dofs"]
        print("rates in N (optimal {:.2f}): adaptive {} (its estimate {}); uniform {}".format(
            rates["optimal"], *(", ".join(f"{f} {v:.2f}" if math.isfinite(v) else f"{f} none"
                                          for f, v in rates[k].items())
                                for k in ("adaptive", "adaptive_estimate", "uniform"))))

    def verdict(result: tuple[Adaptation, dict]) -> str | None:
        """Every step's and the reference's physical checks, printed as a convergence study
        prints its levels'; a step or reference that would not fit in memory then ends in exit 4
        (the steps done reported); then the case's [study] adaptive_band, on each field's slope
        of its estimate against N^(-1/d) over the later half of the steps (1 optimal): the
        estimate needs no reference, whose own error would bias the measured errors' slopes
        upward."""
        adaptation, _ = result
        runs = [step.run for step in adaptation.steps] + ([adaptation.reference] if adaptation.reference else [])
        failed = failed_checks(print_checks(scene, runs))
        if adaptation.refused:
            raise EnvironmentFault(adaptation.refused)
        summary = judged.get("summary") or {}
        band = summary.get("adaptive_band") or []
        slopes = summary.get("slope_of_estimate")
        if slopes is None:
            print(f"warning: {scene.name}: the loop stopped after {summary.get('steps')} of {args.steps} steps, too few "
                  f"for a slope of the estimate (it is fitted over the later half of the steps, which needs two): "
                  f"[study] adaptive_band {band} is not judged", file=sys.stderr)
            slopes = {}
        outside = [f"{f} {v:.3f}" for f, v in slopes.items() if band and not band[0] <= v <= band[1]]
        if outside:
            return (f"{scene.name}: adaptive slope against N^(-1/{scene.dimension}) outside the band "
                    f"[{band[0]}, {band[1]}]: " + ", ".join(outside))
        return f"{scene.name}: {failed}" if failed else None

    judged: dict = {}
    run_pipeline(plan, runs, report, verdict)
    return 0


def uniform_levels_below(scene: Scene, dofs: int) -> tuple[int, ...]:
    """The scene's uniform levels with fewer unknowns than the reference's `dofs` (counted before
    they are meshed, pipeline.level_dofs): a level at least as fine as the reference cannot be
    measured against it, so it is not run (disc_pad's n = 16 has 907,145 unknowns, its
    reference 804,575; paper3d's levels reach n = 64, about 11 GB)."""
    return tuple(n for n in scene.levels if level_dofs(scene, n) < dofs)


def matching_uniform(table: pd.DataFrame, flat: pd.DataFrame, fields: tuple[str, ...]) -> dict:
    """For the finest uniform level measured, per field: the first step whose error is at most
    that level's, its dofs and their share of the level's; and the same by the estimate, which
    needs no reference (both sides are estimated alike, so its own bias cancels to first order)."""
    if not len(flat):
        return {}
    finest = flat.iloc[-1]
    out: dict = {"n": int(finest["n"]), "dofs": int(finest["dofs"])}
    for kind in ("err", "eta"):
        for f in fields:
            beats = table[table[f"{kind}_{f}"] <= finest[f"{kind}_{f}"]]
            first = beats.iloc[0] if len(beats) else None
            out[f"{kind}_{f}"] = None if first is None else {
                "step": int(first["step"]), "dofs": int(first["dofs"]), "share": float(first["dofs"] / finest["dofs"])}
    return out


def solved_fields(adaptation: Adaptation, fields: tuple[str, ...]) -> tuple[str, ...]:
    """The fields with something to measure: one that is zero on every step (the displacement
    of cases/mms/lshape.toml, whose material has no thermal stress) has no error, no estimate
    and no rate, so it is left out of the tables and plots rather than filled with NaN."""
    def nonzero(field: str) -> bool:
        return any((step.run.record.estimator_norms or {}).get(field, 1.0) > 0 for step in adaptation.steps)
    return tuple(f for f in fields if nonzero(f))


def plot_adapt(table: pd.DataFrame, flat: pd.DataFrame, fields: tuple[str, ...], summary: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    # At least 6 inches: one field's panel (an L-shape case) is narrower than the title.
    figure, axes = plt.subplots(1, len(fields), figsize=(max(4.2 * len(fields), 6.0), 3.8), squeeze=False)
    rates = summary["rate_in_dofs"]
    for ax, f in zip(axes[0], fields):
        ax.loglog(table["dofs"], table[f"err_{f}"], "o-", label=f"adaptive ({rates['adaptive'][f]:.2f})")
        ax.loglog(table["dofs"], table[f"eta_{f}"], ":", color="C0",
                  label=f"its estimate ({rates['adaptive_estimate'][f]:.2f})")
        if len(flat):
            ax.loglog(flat["dofs"], flat[f"err_{f}"], "s--", label=f"uniform ({rates['uniform'][f]:.2f})")
        ax.set_xlabel("unknowns N")
        ax.set_title(error_label(f) if f in FIELD_NAMES else f)
        ax.legend(fontsize=8, title="rate in N", title_fontsize=8)
        ax.grid(True, which="both", alpha=0.3)
    figure.suptitle(f"{summary['case']}: error against unknowns (optimal rate {rates['optimal']:.2f})")
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, format="png", dpi=110)
    plt.close(figure)


def plot_mesh(mesh: Path, path: Path, name: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import meshio

    m = meshio.read(mesh)
    triangles = np.vstack([b.data for b in m.cells if b.type == "triangle"])
    tetrahedra = sum(len(b.data) for b in m.cells if b.type == "tetra")
    title = f"{name}: the last adapted mesh ({len(triangles)} cells)"
    if tetrahedra:  # a 3D mesh: its boundary triangles on the lowest plane, seen from below
        low = m.points[:, 2].min()
        triangles = triangles[np.isclose(m.points[triangles, 2], low, rtol=0, atol=1e-9 * np.ptp(m.points)).all(axis=1)]
        title = f"{name}: the last adapted mesh ({tetrahedra} tetrahedra), its face z = {low:g}"
    figure, ax = plt.subplots(figsize=(8, 4.5) if not tetrahedra else (6.5, 6.5))
    ax.triplot(m.points[:, 0], m.points[:, 1], triangles, linewidth=0.25, color="k")
    ax.set_aspect("equal")
    ax.set_title(title)
    figure.tight_layout()
    figure.savefig(path, format="png", dpi=130)
    plt.close(figure)
