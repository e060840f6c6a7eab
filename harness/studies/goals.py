"""`python -m harness goals`: the goal estimates' effectivity (docs/goals.md). Each case of
harness/study/goals.py CASES solved on its levels with its goals, each level's dual-weighted
estimate of Q_exact - Q_h (freefem/goals.idp) divided by the true error: against the exact value
on the manufactured solutions in 2D and 3D, against Richardson's value from the three finest
levels on the paper's scene (both branches) and the strip actuator. Writes effectivity.csv and
effectivity.md into results/goals/ (the levels' runs beside them). With --adapt: the adaptive loop
marked by a goal's indicators beside uniform levels (harness/study/goals.py ADAPT_CASES), into
adapt.csv and adapt.md."""

from __future__ import annotations

import argparse

import pandas as pd

from harness.arguments import add_common, layout_of
from harness.study.adapt import DEFAULT_BULK
from harness.study.goals import ADAPT_CASES, CASES, effectivity_table, goal_adapt_rows, write_adapt_tables, write_tables


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--cases", default=None, metavar="LABELS",
                        help="only these cases, comma-separated by the start of their label (e.g. mms,paper)")
    parser.add_argument("--adapt", action="store_true",
                        help="instead: adaptive refinement marked by each goal's indicators beside uniform levels "
                        "(adapt.csv, adapt.md)")
    add_common(parser, under="goals")


def run(args: argparse.Namespace) -> int:
    layout = layout_of(args)
    if args.adapt:
        table = pd.concat([goal_adapt_rows(case, layout, DEFAULT_BULK) for case in ADAPT_CASES], ignore_index=True)
        write_adapt_tables(table, layout.results)
        print((layout.results / "adapt.md").read_text(), end="")
        return 0
    chosen = CASES if not args.cases else tuple(
        c for c in CASES if any(c.label.startswith(s.strip()) for s in args.cases.split(",")))
    table = effectivity_table(chosen, layout)
    out = layout.results
    write_tables(table, out)
    print((out / "effectivity.md").read_text(), end="")
    print(f"wrote {out / 'effectivity.csv'} and {out / 'effectivity.md'}")
    return 0
