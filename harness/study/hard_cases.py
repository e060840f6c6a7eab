"""The stress suite's library (cases/hard/, `make stress`, harness/studies/stress.py): each
case's levels run as a chain and classified, its summary row (Newton's work, the physical
quantities, the physical checks' verdict from harness/measure/run_checks.py), the paper scene's
iterations per level, and each case's cost (the order a cluster takes the cases in)."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import pandas as pd

from harness.measure.checks import contact_node_count
from harness.core.contract import Failure
from harness.study.engine import InlineMeshes, LevelOutcome, quiet, run_levels
from harness.core.errors import SceneError
from harness.measure.fields import read_fields
from harness.core.guards import geometry_depth, memory_estimate
from harness.core.layout import REPO, Layout
from harness.measure.norm_table import FIELD_NAMES
from harness.run.record import RunRecord
from harness.run.run import check_solver_files
from harness.measure.run_checks import judge
from harness.scene.scene import Scene, load_scene

HARD = REPO / "cases" / "hard"
PAPER = REPO / "cases" / "paper.toml"
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
    outcomes = run_levels(scene, meshes, layout, force=force, progress=quiet, pipelined=False)
    return CaseResult(case.stem, scene, [level_of(o) for o in outcomes.values()])


# ---- the table ---------------------------------------------------------------------------

def relative_residuals(record: RunRecord) -> dict[str, float]:
    """Final residual of each field over the largest in its history (the first one, unless
    the initial guess zeroes that field's residual, as zero does for phi and theta)."""
    out = {}
    for name in FIELD_NAMES:
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
        row.update(judge(record, result.scene).values)
    return row


def passed(row: dict[str, Any]) -> bool:
    """A case is fine when it converged with every check passing, or is a known failure."""
    if row["status"] == "known_failure":
        return True
    return row["status"] == "converged" and bool(row.get("checks_ok")) and not row["note"]


# ---- cold starts: every level from the case's own start ---------------------------------

def own_start(scene: Scene) -> str:
    """The start a case's coarsest level takes (zero, or pressed for the *_pressed cases)."""
    return scene.sections.scene.coarsest_guess


def cold_start_scene(case: Path) -> Scene:
    scene = load_scene(case)
    return load_scene(case, [f"scene.name={case.stem}_cold", f'scene.initial_guess="{own_start(scene)}"'])


# A field's unit in run.json's scales (freefem/scaling.idp): 1e-14 of it is round-off, the
# floor of the relative difference (lift_off's theta is 1e-118 K, zero up to round-off).
SCALE_OF = {"u": "U", "phi": "Phi", "theta": "Theta"}


def field_difference(a: Path, b: Path, scales: dict[str, float]) -> float:
    """The largest difference of two solutions' u, phi, theta, node by node, each relative to
    that field's largest value in `a` (at least 1e-14 of its scale): how far a cold start
    ended from the chain's solution."""
    fa, fb = read_fields(a / "solution.vtu"), read_fields(b / "solution.vtu")
    worst = 0.0
    for name in FIELD_NAMES:
        if name in fa.values:
            va, vb = fa.field(name), fb.field(name)
            size = max(float(abs(va).max()), 1e-14 * scales.get(SCALE_OF[name], 0.0), 1e-300)
            worst = max(worst, float(abs(va - vb).max()) / size)
    return worst


def cold_starts(result: CaseResult, layout: Layout, force: bool = False) -> list[dict[str, Any]]:
    """Each level of the case's chain again on its own, from the case's own start, no
    coarser solution: Newton's iterations, whether it restarted from the pressed state or
    moved Gamma_3 onto the foundation (freefem/newton.idp), and how far its solution is from
    the chain's at that level (the same solution, or another branch)."""
    case = result.scene.source
    scene = cold_start_scene(case)
    levels = {level.n: level for level in result.levels}
    outcomes = run_levels(scene, InlineMeshes(scene, sorted(levels), layout), layout, force=force, progress=quiet,
                          chain=False)
    rows = []
    for cold in map(level_of, outcomes.values()):
        record = cold.record or RunRecord()
        chain = levels[cold.n]
        same = (field_difference(chain.directory, cold.directory, record.scales or {})
                if cold.status == chain.status == "converged" else math.nan)
        rows.append({"case": result.case, "start": own_start(scene), "n": cold.n, "status": cold.status,
                     "newton_iterations": record.newton_iterations, "restarted_at": record.restarted_at,
                     "moved_onto_foundation_at": record.moved_onto_foundation_at,
                     "difference_from_chain": same, "wall_s": cold.wall_s})
    return rows


# ---- the paper's scene: iterations per level ---------------------------------------------

# The paper scene's starts of the iteration table: the chain of `make convergence`, and zero.
PAPER_STARTS = {"coarser": ("scene.name=paper_coarser",),
                "zero": ("scene.name=paper_zero", "scene.initial_guess=zero")}


def paper_scene(start: str) -> Scene:
    return load_scene(PAPER, PAPER_STARTS[start])


def paper_iterations(layout: Layout, levels: Sequence[int], force: bool = False) -> pd.DataFrame:
    """Newton iterations per level of the paper's scene, each level started from the next
    coarser solution (the chain of `make convergence`) and each started from zero."""
    rows = []
    for start in PAPER_STARTS:
        scene = paper_scene(start)
        outcomes = run_levels(scene, InlineMeshes(scene, levels, layout), layout, force=force, progress=quiet,
                              pipelined=False)
        for level in map(level_of, outcomes.values()):
            record = level.record or RunRecord()
            row = {"start": start, "n": level.n, "status": level.status, **newton_work(level.record)}
            if level.status == "converged":
                row.update({"wall_s": record.wall_s, "max_theta": record.max_theta,
                            "contact_force": record.contact_force})
            rows.append(row)
    return pd.DataFrame(rows)


def case_cost(case: Path, levels: Sequence[int] | None = None) -> float:
    """A case's work, for the order a cluster takes the cases in: its finest level's unknowns
    (the guards' estimate), which a direct solve's cost grows with."""
    scene = load_scene(case)
    geometry = scene.geometry
    return memory_estimate(geometry.width, geometry.height, max(levels or scene.levels), scene.effects,
                           scene.element, geometry_depth(geometry), nodes_at=getattr(geometry, "nodes_at", None))[0]


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


