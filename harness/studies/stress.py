"""`python -m harness stress` (`make stress`): the stress suite of issue 4, into results/stress/.

Every case file in cases/hard/ is the paper's scene with one thing made hard; its [expect]
section says what (`hard_because`), what the case must show (`requirement`), the outcome
expected (`status`: converged, or known_failure with its `failure` and `why`) and the
tolerance of its test, with why (harness/schema.py). Each case runs its levels as a chain (each level from
the one below, as `make convergence` does; the coarsest from the case's `coarsest_guess`)
and is reported at its finest level, or at the level where it failed:

- status: `converged`, or the classified reason of the failure (`diverged`, `max_iterations`,
  `nan` from FreeFEM's exit code and run.json; `timeout` when the harness killed it;
  `freefem_error` for anything else; harness/contract.py's Failure), or `known_failure`
  for a case whose [expect] says so and that failed with the reason it names;
- Newton's work: iterations (per level too), final relative residual per field, damped
  steps, active-set changes, wall time;
- the physical checks of every converged run (`physical_checks`, tolerances in harness/checks.py).

Writes summary.csv (one row per case), summary.md (the same, short) and
paper_iterations.csv: Newton iterations per level of the paper's scene with each level
started from the coarser one, and with each level started from zero.
Exit status 1 when a case fails unexpectedly, fails a check, or a known failure converges
(so that a fix is noticed and the case's expectation is flipped).
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pandas as pd

from harness import executor
from harness.arguments import add_common, add_levels, layout_of, level_list, name_list
from harness.checks import CHECK_FLAGS, contact_node_count, physical_checks
from harness.contract import Failure
from harness.engine import InlineMeshes, LevelOutcome, quiet, run_chain
from harness.errors import SceneError, VerdictError
from harness.fields import read_fields
from harness.freefem import freefem_version
from harness.layout import REPO, Layout
from harness.record import RunRecord
from harness.run import check_solver_files
from harness.scene import Scene, load_scene
from harness.writers import cell, write_csv, write_text

HARD = REPO / "cases" / "hard"
PAPER = REPO / "cases" / "paper.toml"
RESULTS = REPO / "results" / "stress"
PAPER_LEVELS = (2, 4, 8, 16, 32, 64)

STATUSES = ("converged", "diverged", "max_iterations", "nan", "freefem_error", "timeout", "known_failure")


@dataclass(frozen=True)
class Level:
    n: int
    status: str  # converged or the classified failure
    detail: str  # the harness's message for a failure
    record: RunRecord | None  # run.json (of the failed run for a failure, when written)
    directory: Path
    wall_s: float


@dataclass
class CaseResult:
    case: str
    scene: Scene
    levels: list[Level] = field(default_factory=list)

    @property
    def last(self) -> Level:
        return self.levels[-1]


# The stress table's name of each failure; any other is `freefem_error`.
STATUS_OF = {Failure.DIVERGED: "diverged", Failure.MAX_ITERATIONS: "max_iterations", Failure.NAN: "nan",
             Failure.TIMEOUT: "timeout"}


def classify(failure: Failure | None, record: RunRecord | None) -> str:
    """The reason a run failed: Newton's own (run.json), or the harness's classified failure."""
    reason = record.reason if record else None
    if reason in ("diverged", "max_iterations", "nan"):
        return str(reason)
    return STATUS_OF.get(failure, "freefem_error") if failure else "freefem_error"


def level_of(outcome: LevelOutcome) -> Level:
    status = "converged" if outcome.ok else classify(outcome.failure, outcome.record)
    assert outcome.directory is not None
    return Level(outcome.n, status, outcome.detail, outcome.record, outcome.directory, outcome.wall_s)


def run_case(case: Path, layout: Layout, force: bool = False, levels: Sequence[int] | None = None,
             scene: Scene | None = None) -> CaseResult:
    """The case's levels (or `levels`), coarsest first; a chain stops at its first failure.
    `scene`: the case's scene with overrides (default: the case file as it is)."""
    scene = scene or load_scene(case)
    check_solver_files(scene, layout)
    meshes = InlineMeshes(scene, levels or scene.levels, layout)
    outcomes = run_chain(scene, meshes, layout, force, quiet, pipelined=False)
    return CaseResult(case.stem, scene, [level_of(o) for o in outcomes.values()])


# ---- the table ---------------------------------------------------------------------------

def relative_residuals(record: RunRecord) -> dict[str, float]:
    """Final residual of each field over the largest in its history (the first one, unless
    the initial guess zeroes that field's residual, as zero does for phi and theta)."""
    out = {}
    for name in ("u", "phi", "theta"):
        history = [abs(v) for v in (record.residuals or {}).get(name, [])]
        top = max(history, default=0.0)
        out[f"residual_{name}"] = history[-1] / top if top > 0 else (0.0 if history else math.nan)
    return out


def newton_work(record: RunRecord | None) -> dict[str, Any]:
    if not record:
        return {}
    damping = (record.damping or [])[1:]
    return {
        "newton_iterations": record.newton_iterations,
        **relative_residuals(record),
        # the stopping test's own quantity: the last full Newton step relative to each field
        **{f"increment_{f}": (v or [math.nan])[-1] for f, v in (record.increments or {}).items()},
        "damping_steps": sum(1 for a in damping if a < 1),
        "min_damping": min(damping, default=math.nan),
        "active_set_changes": sum(record.active_set_changes or []),
        "active_nodes": (record.active_nodes or [None])[-1],
        "slip_nodes": (record.slip_nodes or [None])[-1],
    }


def summary_row(result: CaseResult) -> dict[str, Any]:
    last, expect = result.last, result.scene.expect
    known = expect.status == "known_failure"
    status, note = last.status, ""
    if last.status != "converged":
        failure = f"{last.status} at n={last.n}"
        if known and expect.failure == last.status:
            status, note = "known_failure", f"{failure}: {expect.why}"
        else:
            note = f"{failure}: {last.detail}"
    elif known:
        note = (f"expected to fail ({expect.failure}) but converged: set expect.status = \"converged\" "
                f"in {result.scene.source}")
    row: dict[str, Any] = {
        "case": result.case,
        "hard_because": expect.hard_because,
        "status": status,
        "note": note,
        "levels": " ".join(str(r.n) for r in result.levels),
        "n": last.n,
        "iterations_per_level": " ".join(str(r.record.newton_iterations if r.record else "?") for r in result.levels),
        **newton_work(last.record),
        "wall_s": last.wall_s,
        "total_wall_s": sum(r.wall_s for r in result.levels),
    }
    record = last.record or RunRecord()
    for key in ("max_abs_u", "min_phi", "max_phi", "max_theta", "contact_force", "active_measure",
                "heat_in_contact", "charge_in_contact"):
        row[key] = record.value(key)
    if last.status == "converged":
        fields = read_fields(last.directory / "solution.vtu")
        row["gamma3_nodes"] = contact_node_count(result.scene, fields)
        row.update(physical_checks(record, result.scene))
    return row


def passed(row: dict[str, Any]) -> bool:
    """A case is fine when it converged with every check passing, or is a known failure."""
    if row["status"] == "known_failure":
        return True
    return row["status"] == "converged" and bool(row.get("checks_ok")) and not row["note"]


# ---- the paper's scene: iterations per level ---------------------------------------------

def paper_iterations(layout: Layout, levels: Sequence[int], force: bool = False) -> pd.DataFrame:
    """Newton iterations per level of the paper's scene, each level started from the next
    coarser solution (the chain of `make convergence`) and each started from zero."""
    rows = []
    for start, overrides in (("coarser", ["scene.name=paper_coarser"]),
                             ("zero", ["scene.name=paper_zero", "scene.initial_guess=zero"])):
        scene = load_scene(PAPER, overrides)
        outcomes = run_chain(scene, InlineMeshes(scene, levels, layout), layout, force, quiet, pipelined=False)
        for level in map(level_of, outcomes.values()):
            record = level.record or RunRecord()
            row = {"start": start, "n": level.n, "status": level.status, **newton_work(level.record)}
            if level.status == "converged":
                row.update({"wall_s": record.wall_s, "max_theta": record.max_theta,
                            "contact_force": record.contact_force})
            rows.append(row)
    return pd.DataFrame(rows)


# ---- output ------------------------------------------------------------------------------

def markdown(table: pd.DataFrame) -> str:
    """The summary, short: one line per case."""
    lines = ["| case | status | n | its per level | res u / φ / θ | damped | Δactive | active / slip / Γ3 nodes "
             "| contact force N/m | wall s | checks |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in table.to_dict("records"):
        if row["status"] == "converged":
            failed = [k.removesuffix("_ok") for k in CHECK_FLAGS if not row.get(k)]
            checks = "pass" if not failed else "FAIL " + ", ".join(failed)
        else:
            checks = row["note"].split(":")[0]
        res = " / ".join(cell(row.get(f"residual_{f}")) or "–" for f in ("u", "phi", "theta"))
        nodes = " / ".join(cell(row.get(k)) or "–" for k in ("active_nodes", "slip_nodes", "gamma3_nodes"))
        lines.append(f"| {row['case']} | {row['status']} | {row['n']} | {row['iterations_per_level']} | {res} | "
                     f"{cell(row.get('damping_steps'))} | {cell(row.get('active_set_changes'))} | {nodes} | "
                     f"{cell(row.get('contact_force'))} | {cell(row.get('wall_s'))} | {checks} |")
    return "\n".join(lines) + "\n"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--cases", type=name_list, default=[], help="comma-separated case names of cases/hard/ (default: all)")
    add_levels(parser, what="each case's")
    parser.add_argument("--paper-levels", type=level_list, default=PAPER_LEVELS,
                        help="levels of the paper's iteration table (empty: skip it)")
    add_common(parser, results=RESULTS)
    executor.add_arguments(parser)


def case_cost(case: Path, levels: Sequence[int] | None = None) -> float:
    """A case's work, for the order a cluster takes the cases in: its finest level's unknowns
    (the guards' estimate), which a direct solve's cost grows with."""
    from harness.guards import geometry_depth, memory_estimate

    scene = load_scene(case)
    geometry = scene.geometry
    return memory_estimate(geometry.width, geometry.height, max(levels or scene.levels), scene.effects,
                           scene.element, geometry_depth(geometry))[0]


def case_files(names: Sequence[str]) -> list[Path]:
    files = sorted(HARD.glob("*.toml"))
    if names:
        by_name = {f.stem: f for f in files}
        missing = [n for n in names if n not in by_name]
        if missing:
            raise SceneError(f"no case {missing[0]!r} in {HARD}")
        files = [by_name[n] for n in names]
    return files


def timed_case(case: Path, layout: Layout, force: bool, levels: Sequence[int] | None) -> tuple[CaseResult, float]:
    start = time.perf_counter()
    return run_case(case, layout, force, levels), time.perf_counter() - start


def run(args: argparse.Namespace) -> int:
    layout = layout_of(args)
    freefem_version()
    rows = []
    began = time.perf_counter()
    with executor.from_args(args) as pool:  # each case a task, side by side, on a Dask cluster
        results = executor.each(pool, lambda case: timed_case(case, layout, args.force, args.levels),
                                case_files(args.cases), cost=lambda case: case_cost(case, args.levels))
    for result, seconds in results:
        row = summary_row(result)
        rows.append(row)
        print(f"{row['case']:<30} {row['status']:<15} n={row['n']:<3} its {row['iterations_per_level']:<14}"
              f" checks {'pass' if row.get('checks_ok') else '-'}  ({seconds:.1f} s)"
              + (f"  {row['note'][:100]}" if row["note"] else ""), flush=True)
    print(f"{len(rows)} cases in {time.perf_counter() - began:.1f} s")
    table = pd.DataFrame(rows)
    if not args.cases and not args.levels:
        write_csv(table, args.results / "summary.csv")
        write_text(markdown(table), args.results / "summary.md")
    if args.paper_levels:
        its = paper_iterations(layout, args.paper_levels, args.force)
        write_csv(its, args.results / "paper_iterations.csv")
        print(its[["start", "n", "status", "newton_iterations", "damping_steps", "active_set_changes"]]
              .to_string(index=False))
    bad = [row["case"] for row in rows if not passed(row)]
    if bad:
        raise VerdictError(f"{len(bad)} case(s) failed unexpectedly or failed a check: {', '.join(bad)}")
    print(f"{len(rows)} cases: every one converged with its checks passing, or is a known failure")
    return 0
