"""`python -m harness verify`: verification beyond self-convergence, into
results/verification/.

- Manufactured solutions (cases/mms/*.toml, harness/scene/mms.py): true errors against the exact
  fields, per case, field and norm, with least-squares slopes and standard errors
  (mms_levels.csv, mms.csv, mms.png). Expected: 2 in L2, 1 in the H1 seminorm. Beside
  them the a posteriori estimate of each field's error and its effectivity index
  (effectivity.csv; docs/adaptivity.md).
- The paper's scene without a reference: three-grid observed order, Richardson value and
  GCI (harness/measure/gci.py) of each field's error norm and of scalar outputs of run.json
  (results/paper/gci.csv; its finest triples again in gci.csv here).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import pandas as pd

from harness.arguments import add_common, add_jobs, add_levels, layout_of, name_list
from harness.core.errors import SceneError
from harness.core.guards import Slope
from harness.measure.gci import finest_triples, gci_table
from harness.core.layout import REPO, Layout
from harness.study.pipeline import Guarded, Plan, run_pipeline
from harness.report.plot import plot_mms
from harness.scene.scene import Scene, load_scene
from harness.study.study import run_study
from harness.study.verification import (CASE_LEVELS, MMS_CASES, MMS_CASES_3D, MMS_LEVELS, MMS_LEVELS_3D, band,
                                  effectivity_table, error_table, mms_rates, mms_runs)
from harness.core.writers import PRECISE_CSV_FORMAT, write_csv as write_table


def write_csv(table: pd.DataFrame, path: Path) -> None:
    """Errors and orders at full precision: their slopes are fitted again."""
    write_table(table, path, PRECISE_CSV_FORMAT)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_levels(parser, default=MMS_LEVELS, what="4,8,16,32; the manufactured cases'")
    parser.add_argument("--cases", type=name_list, default=[*MMS_CASES, *MMS_CASES_3D],
                        help="manufactured cases to run, comma-separated: built-in names "
                             f"({', '.join([*MMS_CASES, *MMS_CASES_3D])}) or paths to your own case files with a "
                             "[manufactured] section, run on their own [study] levels; empty: none")
    parser.add_argument("--paper", type=Path, default=REPO / "cases" / "paper.toml",
                        help="the case file whose three finest levels give the Grid Convergence Index table (default: "
                        "cases/paper.toml)")
    parser.add_argument("--skip-gci", action="store_true",
                        help="run the manufactured solutions only, not the Grid Convergence Index table")
    add_jobs(parser, default=2)
    add_common(parser)


@dataclass(frozen=True)
class MmsCase:
    scene: Scene
    levels: tuple[int, ...]


def mms_scenes(cases: Sequence[str], levels: Sequence[int]) -> dict[str, MmsCase]:
    """Each manufactured case's scene and levels, by name: a built-in case on `levels` (2D)
    or its own (3D, CASE_LEVELS); a case file given by its path (it ends in .toml or names a
    folder) on its [study] levels, under its scene name."""
    known = {**MMS_CASES, **MMS_CASES_3D}
    out: dict[str, MmsCase] = {}
    for case in cases:
        if case in known:
            own = CASE_LEVELS.get(case, tuple(levels) if case in MMS_CASES else MMS_LEVELS_3D)
            out[case] = MmsCase(load_scene(known[case]), tuple(own))
        elif case.endswith(".toml") or "/" in case:
            scene = load_scene(Path(case))
            if not scene.manufactured:
                raise SceneError(f"{case}: no [manufactured] section: verify needs the exact fields")
            if scene.name in out or scene.name in known:
                raise SceneError(f"{case}: its scene name {scene.name!r} is already a case of this run")
            out[scene.name] = MmsCase(scene, tuple(scene.levels))
        else:
            raise SceneError(f"no manufactured case {case!r} (known: {', '.join(known)}; or give a case file's path)")
    return out


def verify_mms(scenes: dict[str, MmsCase], layout: Layout, jobs: int, force: bool) -> pd.DataFrame:
    tables, estimates = [], []
    for c, case in scenes.items():
        runs = mms_runs(case.scene, case.levels, layout, jobs, force)
        tables.append(error_table(case.scene, runs).assign(case=c))
        estimates.append(effectivity_table(case.scene, runs).assign(case=c))
    errors = pd.concat(tables, ignore_index=True)
    effectivity = pd.concat(estimates, ignore_index=True)
    rates = mms_rates(errors, {c: case.scene.dimension for c, case in scenes.items()})
    out = layout.results / "verification"
    write_csv(errors[["case", *errors.columns.drop("case")]], out / "mms_levels.csv")
    write_csv(effectivity[["case", *effectivity.columns.drop("case")]], out / "effectivity.csv")
    write_csv(rates, out / "mms.csv")
    plot_mms(errors, rates, out / "mms.png")
    print(rates.to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    return rates


def verify_gci(scene: Scene, layout: Layout, jobs: int, force: bool) -> pd.DataFrame:
    study = run_study(scene, scene.levels, layout, jobs, force)
    gci = gci_table(study.table, {n: run.record for n, run in study.runs.items()})
    write_csv(gci, layout.case_dir(scene.name) / "gci.csv")
    summary = finest_triples(gci).assign(case=scene.name)
    write_csv(summary[["case", *summary.columns.drop("case")]], layout.results / "verification" / "gci.csv")
    columns = ["quantity", "n_fine", "p", "f1", "f_ext", "gci_fine", "asymptotic_ratio", "behaviour"]
    print(summary[columns].to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    return gci


def run(args: argparse.Namespace) -> int:
    """Exit 0, 1 when a manufactured slope leaves its band (verification.BANDS)."""
    layout = layout_of(args)
    scenes = mms_scenes(args.cases, args.levels) if args.cases else {}
    paper = None if args.skip_gci else load_scene(args.paper)
    guarded = [Guarded(case.scene, case.levels, Slope.AGAINST_EXACT) for case in scenes.values()]
    guarded += [Guarded(paper, slope=Slope.AGAINST_FINEST)] if paper is not None else []
    plan = Plan(layout.results, tuple(guarded), scene_dirs=tuple(layout.case_dir(g.scene.name) for g in guarded),
                outputs=(layout.results / "verification",), nested=True, ignore_memory=args.ignore_memory)

    def runs() -> pd.DataFrame:
        rates = verify_mms(scenes, layout, args.jobs, args.force) if scenes else pd.DataFrame()
        if paper is not None:
            verify_gci(paper, layout, args.jobs, args.force)
        return rates

    def verdict(rates: pd.DataFrame) -> str | None:
        outside = rates[~rates["within_band"]] if len(rates) else rates
        bands = {(row["case"], row["norm"]): band(scenes[row["case"]].scene.dimension, row["norm"])
                 for _, row in outside.iterrows()}
        lines = [f"{row['case']} {row['field']} {row['norm']}: slope {row['slope']:.3f} is outside "
                 f"[{bands[row['case'], row['norm']][0]}, {bands[row['case'], row['norm']][1]}]"
                 for _, row in outside.iterrows()]
        return "; ".join(lines) or None

    run_pipeline(plan, runs, lambda rates: None, verdict)
    return 0
