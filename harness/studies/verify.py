"""`python -m harness verify`: verification beyond self-convergence (issue 6), into
results/verification/.

- Manufactured solutions (cases/mms/*.toml, harness/mms.py): true errors against the exact
  fields, per case, field and norm, with least-squares slopes and standard errors
  (mms_levels.csv, mms.csv, mms.png). Expected: 2 in L2, 1 in the H1 seminorm.
- The paper's scene without a reference: three-grid observed order, Richardson value and
  GCI (harness/gci.py) of each field's error norm and of scalar outputs of run.json
  (results/paper/gci.csv; its finest triples again in gci.csv here).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Sequence

import pandas as pd

from harness.arguments import add_common, add_jobs, add_levels, layout_of, name_list
from harness.errors import SceneError
from harness.guards import Slope
from harness.gci import finest_triples, gci_table
from harness.layout import REPO, Layout
from harness.pipeline import Guarded, Plan, run_pipeline
from harness.plot import plot_mms
from harness.scene import Scene, load_scene
from harness.study import run_study
from harness.verification import MMS_CASES, MMS_CASES_3D, MMS_LEVELS, MMS_LEVELS_3D, band, mms_errors, mms_rates
from harness.writers import PRECISE_CSV_FORMAT, write_csv as write_table


def write_csv(table: pd.DataFrame, path: Path) -> None:
    """Errors and orders at full precision: their slopes are fitted again."""
    write_table(table, path, PRECISE_CSV_FORMAT)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_levels(parser, default=MMS_LEVELS, what="4,8,16,32; the manufactured cases'")
    parser.add_argument("--cases", type=name_list, default=[*MMS_CASES, *MMS_CASES_3D],
                        help="manufactured cases to run (bulk, contact, coulomb, wedge, bulk3d, contact3d; empty: none)")
    parser.add_argument("--paper", type=Path, default=REPO / "cases" / "paper.toml", help="scene of the GCI table")
    parser.add_argument("--skip-gci", action="store_true", help="manufactured solutions only")
    add_jobs(parser, default=2)
    add_common(parser)


def mms_scenes(cases: Sequence[str], levels: Sequence[int]) -> dict[str, tuple[Scene, tuple[int, ...]]]:
    """Each manufactured case's scene and levels (the 3D cases on their own)."""
    known = {**MMS_CASES, **MMS_CASES_3D}
    unknown = [c for c in cases if c not in known]
    if unknown:
        raise SceneError(f"no manufactured case {unknown[0]!r} (known: {', '.join(known)})")
    return {c: (load_scene(known[c]), tuple(levels if c in MMS_CASES else MMS_LEVELS_3D)) for c in cases}


def verify_mms(scenes: dict[str, tuple[Scene, tuple[int, ...]]], layout: Layout, jobs: int,
               force: bool) -> pd.DataFrame:
    tables = [mms_errors(scene, levels, layout, jobs, force).assign(case=c) for c, (scene, levels) in scenes.items()]
    errors = pd.concat(tables, ignore_index=True)
    rates = mms_rates(errors)
    out = layout.results / "verification"
    write_csv(errors[["case", *errors.columns.drop("case")]], out / "mms_levels.csv")
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
    guarded = [Guarded(scene, levels, Slope.AGAINST_EXACT) for scene, levels in scenes.values()]
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
        lines = [f"{row['case']} {row['field']} {row['norm']}: slope {row['slope']:.3f} is outside "
                 f"[{band(row['case'], row['norm'])[0]}, {band(row['case'], row['norm'])[1]}]"
                 for _, row in outside.iterrows()]
        return "; ".join(lines) or None

    run_pipeline(plan, runs, lambda rates: None, verdict)
    return 0
