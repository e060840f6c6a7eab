"""Where a solve's time and memory go, piece by piece (docs/solvers.md, "Profile").

    python -m harness profile [CASE] [--levels 16,32] [--repeats 3] [--out results/solvers/profile3d.csv]

Each level is run `--repeats` times alone from the chain below it (solved once, cached), as
the solver table's levels are. Per run FreeFEM records each piece's CPU seconds and by how
much it raised the peak resident memory (run.json's profile, freefem/profile.idp: the raises
sum to the run's peak); the table holds, per level and piece, the median seconds, its share
of the run's summed CPU seconds (a share survives a loaded machine better than seconds), the
calls and the median raise, and the machine's load average while the level ran. Written as
CSV and Markdown, beside each other.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
from pathlib import Path
from typing import Any

import pandas as pd

from harness.arguments import add_memory_override, positive_int
from harness.study.engine import quiet, run_levels, runs_of, timed_meshes
from harness.core.layout import REPO, Layout
from harness.study.pipeline import Guarded, Plan, run_pipeline
from harness.run.record import RunRecord
from harness.run.run import run_level
from harness.scene.scene import load_scene
from harness.core.writers import markdown_table, write_csv, write_text

DEFAULT_CASE = REPO / "cases" / "paper3d.toml"
DEFAULT_OUT = Path("results") / "solvers" / "profile3d.csv"
# Whole-run rows beside the pieces: FreeFEM's CPU seconds summed over the pieces, the
# harness's wall clock of the process, and FreeFEM's peak (VmHWM).
TOTAL, WALL, PEAK = "all pieces (CPU)", "process wall", "process peak"


def level_rows(n: int, records: list[RunRecord], loads: list[float]) -> list[dict[str, Any]]:
    """The table's rows of one level from its repeats: per piece the median seconds, share,
    calls and peak raise; then the totals. A piece some repeat lacks counts 0 there."""
    profiles = [r.profile or {} for r in records]
    names = list(dict.fromkeys(name for p in profiles for name in p))
    totals = [sum(v[0] for v in p.values()) for p in profiles]
    common = {"n": n, "dofs": records[-1].dofs, "repeats": len(records), "load_average": statistics.median(loads)}
    rows = []
    for name in names:
        seconds = [p.get(name, [0.0, 0, 0.0])[0] for p in profiles]
        rows.append({**common, "piece": name, "seconds": statistics.median(seconds),
                     "share": statistics.median(s / max(t, 1e-12) for s, t in zip(seconds, totals)),
                     "calls": int(max(p.get(name, [0, 0, 0])[1] for p in profiles)),
                     "raised_mb": statistics.median(p.get(name, [0.0, 0, 0.0])[2] for p in profiles)})
    rows.append({**common, "piece": TOTAL, "seconds": statistics.median(totals), "share": 1.0, "calls": 1,
                 "raised_mb": statistics.median(sum(v[2] for v in p.values()) for p in profiles)})
    rows.append({**common, "piece": WALL, "seconds": statistics.median(float(r.wall_s or 0) for r in records),
                 "share": float("nan"), "calls": 1, "raised_mb": float("nan")})
    rows.append({**common, "piece": PEAK, "seconds": float("nan"), "share": float("nan"), "calls": 1,
                 "raised_mb": statistics.median(float(r.peak_rss_mb or 0) for r in records)})
    return rows


def markdown(table: pd.DataFrame, case: str) -> str:
    """Per level the seconds, share and peak raise, a row per piece."""
    levels = sorted(table["n"].unique())
    lines = [f"# Profile of {case} (python -m harness profile)", "",
             "Medians of the repeats of each level, each run alone from the chain below it. CPU seconds "
             "per piece (FreeFEM's clock(), the PETSc plugin's std::clock), their share of all pieces, and "
             "the MiB by which each piece raised the peak resident memory (VmHWM; the raises sum to the peak).",
             ""]
    header = ["piece"]
    for n in levels:
        sub = table[table["n"] == n].iloc[0]
        header += [f"1/{n} s", f"1/{n} share", f"1/{n} MiB raised"]
        lines.append(f"- h = 1/{n}: {int(sub['dofs']):,} dofs, {int(sub['repeats'])} repeats, "
                     f"load average {sub['load_average']:.1f}")
    lines.append("")
    rows = []
    for piece in dict.fromkeys(table["piece"]):
        row = [piece]
        for n in levels:
            hit = table[(table["n"] == n) & (table["piece"] == piece)]
            if hit.empty:
                row += ["", "", ""]
                continue
            r = hit.iloc[0]
            row += ["" if pd.isna(r["seconds"]) else f"{r['seconds']:.2f}",
                    "" if pd.isna(r["share"]) else f"{100 * r['share']:.1f} %",
                    "" if pd.isna(r["raised_mb"]) else f"{r['raised_mb']:,.0f}"]
        rows.append(row)
    return "\n".join(lines) + "\n" + markdown_table(header, rows)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("case", nargs="?", type=Path, default=DEFAULT_CASE,
                        help="the case file whose levels are profiled (default: cases/paper3d.toml)")
    parser.add_argument("--levels", type=lambda t: [positive_int(x) for x in t.split(",")], default=[16, 32],
                        help="comma-separated levels n = 1/h (default 16,32)")
    parser.add_argument("--repeats", type=positive_int, default=3,
                        help="how many times each level is solved and timed (default: 3)")
    parser.add_argument("--out", type=Path, default=Path.cwd() / DEFAULT_OUT, metavar="CSV",
                        help="the CSV file to write, the Markdown table beside it (default: "
                        f"{DEFAULT_OUT} under the working directory)")
    add_memory_override(parser)


def run(args: argparse.Namespace) -> int:
    def say(text: str) -> None:
        print(text, file=sys.stderr, flush=True)

    scene = load_scene(args.case, ['scene.name="profile-' + args.case.stem + '"'])
    layout = Layout(results=args.out.parent / "runs")
    levels = sorted(set(args.levels))
    chain = sorted({m for m in scene.levels if m < max(levels)} | set(levels))
    plan = Plan(args.out.parent, (Guarded(scene, tuple(chain)),), outputs=(args.out.parent,),
                locked=(layout.case_dir(scene.name),), ignore_memory=args.ignore_memory)

    def measure() -> pd.DataFrame:
        meshes, _ = timed_meshes(scene, chain, layout)
        rows: list[dict[str, Any]] = []
        for n in levels:
            below = {m: p for m, p in meshes.items() if m < n}
            runs = runs_of(run_levels(scene, below, layout, progress=quiet)) if below else {}
            warm = runs[max(below)].warm_start(meshes[max(below)]) if below else None
            records, loads = [], []
            for i in range(args.repeats):
                before = os.getloadavg()[0]
                records.append(run_level(scene, meshes[n], n, layout, force=True, warm=warm).record)
                loads.append((before + os.getloadavg()[0]) / 2)
                say(f"{scene.name} n={n} #{i + 1}: {records[-1].wall_s:.1f} s, "
                    f"{records[-1].peak_rss_mb:,.0f} MiB, load {loads[-1]:.1f}")
            rows += level_rows(n, records, loads)
        return pd.DataFrame(rows)

    def report(table: pd.DataFrame) -> None:
        write_csv(table, args.out)
        text = markdown(table, args.case.name)
        write_text(text, args.out.with_suffix(".md"))
        print(text)

    run_pipeline(plan, measure, report)
    return 0
