"""What accuracy costs in time: the cost-accuracy frontier of a scene.

    python -m harness cost cases/paper.toml [--levels 2,4,...] [--reference P2:64]
        [--discretisations P1,P2,P1-rtol] [--scaling-levels 128,256] [--set k=v]
        [--results results/cost] [--force]

Every discretisation runs as a chain (each level warm-started from the next coarser one,
as `make convergence` does) and is measured against ONE reference for the scene, by
default P2 on the finest mesh, so that the frontier compares like with like. The errors
are computed inside FreeFEM (freefem/reference_error.idp, in the reference's element: a
P2 run keeps its accuracy, which solution.vtu's P1 vertex values would hide).

Outputs (results/cost/): cost.csv (one row per scene x discretisation x level), fits.csv
(E ~ C h^p, T ~ D h^-q, M ~ G h^-r per discretisation and field), frontier.csv and
frontier.md (to reach E <= tau: h, seconds, MB), scaling.csv, summary.json, and the plots
cost_vs_time.png, cost_vs_dofs.png, time_split.png, scaling.png. The P1 chain goes on to
--scaling-levels (default 128, 256) for time and memory against dofs; its errors there
are not used (a level as fine as the reference, or finer, has no meaningful error).

Costs. `wall_s` is the FreeFEM process's wall time minus the error measurement it did
for this study (reference_s); `chain_s` adds up mesh_s + wall_s over the chain up to the
level: what a user pays to get that level's solution from nothing. The chains run
unpipelined (one FreeFEM at a time), so that no level's time includes another's
contention for the cores. `peak_rss_mb` is the
FreeFEM process's own high-water mark (VmHWM, freefem/memory.idp), read before the error
measurement when there is one.
"""

from __future__ import annotations

import argparse

from harness.arguments import add_case, add_common, add_levels, level_list, name_list
from harness.core.errors import SceneError
from harness.report.frontier import (DISCRETISATIONS, CostStudy, frontier_markdown, planned_scenes, run_cost, scene_names,
                              write_outputs)
from harness.core.layout import Layout
from harness.measure.norm_table import FIELD_NAMES, error_column
from harness.study.pipeline import Guarded, Plan, run_pipeline
from harness.scene.scene import load_scene
from harness.scene.segments import Geometry



def reference_spec(text: str) -> tuple[str, int]:
    element, _, n = text.partition(":")
    if element not in ("P1", "P2") or not n.isdigit():
        raise argparse.ArgumentTypeError(f"{text!r}: expected ELEMENT:N, e.g. P2:128")
    return element, int(n)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_case(parser)
    add_levels(parser)
    parser.add_argument("--reference", type=reference_spec, default=None,
                        help="ELEMENT:N of the reference (default P2 at the finest level)")
    parser.add_argument("--discretisations", type=name_list, default=None,
                        help=f"comma-separated, of {', '.join(DISCRETISATIONS)} (default: all a scene has; "
                             "P1-graded grades a rectangle's mesh only)")
    parser.add_argument("--scaling-levels", type=level_list, default=(128, 256),
                        help="levels the P1 chain goes on to, for time and memory against dofs")
    add_common(parser, under="cost")


def run(args: argparse.Namespace) -> int:
    base = load_scene(args.case, args.overrides)
    levels = tuple(sorted(set(args.levels or base.levels)))
    reference = args.reference or ("P2", max(levels))
    # Grading moves a rectangle's lattice towards the ends of its contact segments
    # (mesh.graded_level); a box or a gmsh scene has no such lattice.
    rectangle = isinstance(base.geometry, Geometry)
    if args.discretisations is None:
        # The adaptive loop warm-starts each step from the one before (harness/study/adapt.py).
        args.discretisations = [d for d in DISCRETISATIONS if (rectangle or DISCRETISATIONS[d].grading == 1.0)
                                and (base.initial_guess == "coarser" or not DISCRETISATIONS[d].adaptive)]
    unknown = [d for d in args.discretisations if d not in DISCRETISATIONS]
    if unknown:
        raise SceneError(f"unknown discretisation {unknown[0]!r} (have {', '.join(DISCRETISATIONS)})")
    graded = [d for d in args.discretisations if DISCRETISATIONS[d].grading != 1.0]
    if graded and not rectangle:
        raise SceneError(f"discretisation {graded[0]!r} grades a rectangle's mesh; {args.case} is not a rectangle")
    scaling = tuple(sorted(set(args.scaling_levels)))
    runs = Layout(results=args.results / "runs")
    planned = planned_scenes(args.case, levels, args.discretisations, reference, scaling, args.overrides)
    plan = Plan(args.results, tuple(Guarded(scene, chain) for scene, chain in planned),
                scene_dirs=tuple(runs.case_dir(name) for name in scene_names(base.name, args.discretisations)),
                outputs=(args.results,), ignore_memory=args.ignore_memory)

    def report(study: CostStudy) -> None:
        written = write_outputs(study, args.results)
        print(study.table[["discretisation", "n", "dofs", "newton_iterations", "wall_s", "chain_s", "peak_rss_mb",
                           *map(error_column, FIELD_NAMES), "newton_over_linear"]]
              .to_string(index=False, float_format=lambda v: f"{v:.4g}"))
        print(frontier_markdown(study))
        print("wrote " + ", ".join(str(p) for p in written))

    run_pipeline(plan, lambda: run_cost(args.case, levels, args.discretisations, reference, scaling, args.overrides,
                                        args.results, args.force, scripts=args.freefem), report)
    return 0
