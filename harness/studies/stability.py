"""`python -m harness stability` (`make stability`): branch stability, into results/stability/.

Every case of cases/hard/ (as its file asks, and its compared level alone from its coarsest
start, as the stress study's cold starts run it) and every scene of cases/ is solved at one
level (n = 8 in 2D, 4 in 3D, or the case's finest below that), then five more times: with its
loads scaled by 1 + 1e-12, 1 - 1e-12 and 1 +- 2e-12 (alternating over the loads it has), and
with its interior mesh nodes moved by 1e-9 of their shortest edge (two seeds). Each perturbed
solution is compared with the unperturbed one: each field's relative difference in its norm
(V, W, Q), the contact resultants, the status, the physical checks, Newton's iterations. More
than 1e-8 relative, or a changed status or verdict, makes the case branch-sensitive.

Also the paper's scene with both ends free at n = 8 from zero, known to be sensitive, and
beside it the case key that makes it deterministic (`paper_free_ends_roller`: a roller on
one end).

Writes stability.csv (one row per case and perturbation), stability.md (one line per case)
and sensitive.json (each sensitive case's two solutions, in a few numbers, and the
perturbation that switches them). Exit 1 when a case not documented as sensitive is
sensitive, or the remedy of a documented one (its case key that makes it deterministic) is not
stable.
"""

from __future__ import annotations

import argparse
import math
import time
from typing import Any

import pandas as pd

from harness.arguments import add_common, layout_of, name_list
from harness.core.errors import SceneError
from harness.core.freefem import freefem_version
from harness.core.writers import cell, markdown_table, write_csv, write_json, write_text
from harness.measure.agreement import TOLERANCE
from harness.study.pipeline import Guarded, Plan, run_pipeline
from harness.study.stability import (KNOWN_SENSITIVE, PERTURBATIONS, UNPERTURBED, Config, all_configs, compare,
                                     remedy_names, row_of, solution_summary, solve)

HEADER = ("case", "start", "n", "status", "its (perturbed)", "max field difference", "max resultant difference",
          "verdict", "switched by")


def summarise(config: Config, rows: list[dict[str, Any]]) -> dict[str, Any]:
    """A case's line: its unperturbed solve, the largest differences any perturbation made,
    and the perturbations that switched it."""
    base, perturbed = rows[0], rows[1:]
    sensitive = [r for r in perturbed if r["verdict"] == "sensitive"]
    its = sorted({r["newton_iterations"] for r in perturbed if r["newton_iterations"] is not None})

    def largest(key: str) -> float:
        values = [r[key] for r in perturbed if not math.isnan(r.get(key, math.nan))]
        return max(values, default=math.nan)

    verdict = "sensitive" if sensitive else "stable"
    if sensitive and config.name in KNOWN_SENSITIVE:
        verdict = "sensitive (documented)"
    elif not sensitive and config.name in KNOWN_SENSITIVE:
        verdict = "stable here (documented as sensitive)"
    return {"case": config.name, "start": config.start, "n": config.n, "status": base["status"],
            "its": f"{base['newton_iterations']} ({' '.join(map(str, its))})",
            "field_difference": largest("field_difference"), "resultant_difference": largest("resultant_difference"),
            "verdict": verdict,
            "switched_by": "; ".join(f"{r['perturbation']}: {r['changed'] or r['status']}" for r in sensitive)}


def markdown(lines: list[dict[str, Any]]) -> str:
    rows = [[s["case"], s["start"], s["n"], s["status"], s["its"], cell(s["field_difference"]),
             cell(s["resultant_difference"]), s["verdict"], s["switched_by"]] for s in lines]
    return (f"Each case solved unperturbed, then with 5 perturbations; more than {TOLERANCE:g} relative in a field "
            "(its norm of E^h) or a contact resultant, or a changed status or verdict: sensitive.\n\n"
            + markdown_table(HEADER, rows))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--cases", type=name_list, default=[],
                        help="comma-separated names of the table's cases, e.g. paper,gap_open_cold (default: all)")
    add_common(parser, under="stability")


def run(args: argparse.Namespace) -> int:
    layout = layout_of(args)
    configs = all_configs(names=args.cases)
    unknown = sorted(set(args.cases) - {c.name for c in configs})
    if unknown:
        raise SceneError(f"--cases: no case {unknown[0]!r} in the stability table (cases/hard/*.toml and cases/*.toml "
                         "by name, a hard case's cold start as <name>_cold)")
    scenes = [(c, p, c.scene(p)) for c in configs for p in (UNPERTURBED, *PERTURBATIONS)]
    guarded = tuple(Guarded(scene, c.levels) for c, p, scene in scenes if p is UNPERTURBED)
    plan = Plan(args.results, guarded, scene_dirs=tuple(layout.case_dir(s.name) for _, _, s in scenes),
                outputs=(args.results,), ignore_memory=args.ignore_memory)

    def runs() -> tuple[list[dict], list[dict], dict[str, Any]]:
        freefem_version()
        rows, lines, branches = [], [], {}
        began = time.perf_counter()
        for count, config in enumerate(configs, start=1):
            start = time.perf_counter()
            base = solve(config, UNPERTURBED, layout, args.force)
            own = [row_of(config, base, None)]
            switched = []
            for perturbation in PERTURBATIONS:
                other = solve(config, perturbation, layout, args.force)
                comparison = compare(base, other)
                own.append(row_of(config, other, comparison))
                if comparison.sensitive:
                    switched.append(solution_summary(other, args.results, comparison))
            line = summarise(config, own)
            rows += own
            lines.append(line)
            if switched:
                branches[config.name] = {"unperturbed": solution_summary(base, args.results), "switched": switched}
            marks = "".join("S" if r["verdict"] == "sensitive" else "." for r in own[1:])
            print(f"[{count}/{len(configs)}] {config.name:<34} n={config.n:<2} {line['status']:<15} its {line['its']:<12}"
                  f" {marks}  field {cell(line['field_difference']) or '-':<9} resultant"
                  f" {cell(line['resultant_difference']) or '-':<9} {line['verdict']}"
                  f"  ({time.perf_counter() - start:.1f} s)", flush=True)
        print(f"{len(configs)} cases, {len(rows)} solves in {time.perf_counter() - began:.1f} s")
        return rows, lines, branches

    def report(done: tuple[list[dict], list[dict], dict[str, Any]]) -> None:
        rows, lines, branches = done
        if args.cases:  # a part of the table is not the table
            return
        write_csv(pd.DataFrame(rows), args.results / "stability.csv")
        write_text(markdown(lines), args.results / "stability.md")
        write_json(branches, args.results / "sensitive.json")

    def verdict(done: tuple[list[dict], list[dict], dict[str, Any]]) -> str | None:
        lines = done[1]
        bad = [s["case"] for s in lines if s["verdict"] == "sensitive" and s["case"] not in remedy_names()]
        bad += [s["case"] for s in lines if s["case"] in remedy_names() and s["verdict"] != "stable"]
        if bad:
            return (f"{len(bad)} case(s) branch-sensitive and not documented so, or a documented one's remedy "
                    f"not stable: {', '.join(bad)}")
        print(f"{len(lines)} cases: every one stable, or documented as sensitive with a remedy that is stable")
        return None

    run_pipeline(plan, runs, report, verdict)
    return 0
