"""Branch stability, the library of `python -m harness stability` (harness/studies/stability.py):
each hard case and each scene solved at one level as its case file asks, then five more times
with a perturbation far below anything physical (the loads scaled by 1 +- a few 1e-12, or the
interior nodes jittered by 1e-9 of their shortest edge, harness/mesh/jitter.py), and each
perturbed solution compared with the unperturbed one: each field's relative difference in its
norm of E^h (docs/model.md section 7), the contact resultants of run.json, the status, the
physical checks and Newton's iterations. A solution that moves by more than 1e-8 relative, or
a status or verdict that changes, makes the case branch-sensitive: round-off decides its answer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Mapping, Sequence

import numpy as np

from harness.core.layout import REPO, Layout
from harness.measure.fields import Fields, read_fields
from harness.measure.norm_table import FIELD_NAMES, measure_of
from harness.measure.norms import P1_INTEGRANDS, error_norms, simplex_seminorm
from harness.measure.run_checks import judge
from harness.mesh.jitter import Jitter
from harness.mesh.mesh import GMSH, build_mesh
from harness.run.record import RunRecord
from harness.run.run import check_solver_files
from harness.scene.scene import Scene, load_scene
from harness.study.engine import LevelOutcome, quiet, run_levels
from harness.study.hard_cases import HARD, field_difference, own_start

SCENES = REPO / "cases"
# The level each case is compared at: moderate, so that the whole study stays within minutes
# (a case whose levels stop below it is compared at its finest).
LEVEL = {2: 8, 3: 4}
# Two solutions agree when every field and resultant differs by at most this, relative: 1e4
# times the perturbations (1e-12 of the loads moves a solution by about 1e-12, 1e-9 h of the
# nodes by about 1e-9 h |grad|: measured at most 1e-9, docs/hard-cases.md), far below any
# distance between two branches (the paper's two differ by O(1)).
TOLERANCE = 1e-8
LOAD_STEP = 1e-12
JITTER = 1e-9
# A difference is relative to the larger of the two values and a floor, the size of what it
# is measured against: a field's norm against 1e-14 of its scale over the body (run.json's
# scales, freefem/scaling.idp; lift_off's theta is 1e-118 K, zero up to round-off), a contact
# resultant against what it balances, so that the barely touching branch's 3.7e-6 N/m of
# contact force, which 1e-12 of the 200 N/m applied moves by 2e-10, is not a switch.
SCALE_OF = {"u": "U", "phi": "Phi", "theta": "Theta"}
FIELD_FLOOR = 1e-14
RESULTANTS = {"contact_force": "force", "friction_force": "force", "heat_in_contact": "heat_contact_reading",
              "charge_in_contact": "charge_contact_reading"}


# ---- what is perturbed --------------------------------------------------------------------

@dataclass(frozen=True)
class Perturbation:
    """One perturbed solve: the nonzero loads scaled by 1 + steps[i] (cycled over them in the
    schema's order), or the mesh jittered."""

    name: str
    slug: str
    steps: tuple[float, ...] = ()
    jitter: Jitter | None = None

    def overrides(self, scene: Scene) -> list[str]:
        """--set overrides of the scaled loads (repr round-trips every digit to FreeFEM)."""
        if not self.steps:
            return []
        loaded = [(key, value) for key, value in scene.table["loads"].items() if value != 0]
        return [f"loads.{key}={value * (1.0 + self.steps[i % len(self.steps)])!r}"
                for i, (key, value) in enumerate(loaded)]


PERTURBATIONS = (
    Perturbation(f"loads x (1 + {LOAD_STEP:g})", "loads_up", steps=(LOAD_STEP,)),
    Perturbation(f"loads x (1 - {LOAD_STEP:g})", "loads_down", steps=(-LOAD_STEP,)),
    # Alternating signs tilt a load of several components (a shear and a pressure) as well.
    Perturbation(f"loads x (1 +- {2 * LOAD_STEP:g}), alternating", "loads_tilt", steps=(2 * LOAD_STEP, -2 * LOAD_STEP)),
    Perturbation(f"jitter {JITTER:g} h, seed 1", "jitter_1", jitter=Jitter(JITTER, 1)),
    Perturbation(f"jitter {JITTER:g} h, seed 2", "jitter_2", jitter=Jitter(JITTER, 2)),
)
UNPERTURBED = Perturbation("none", "base")


# ---- what is solved -----------------------------------------------------------------------

@dataclass(frozen=True)
class Config:
    """One row group of the table: a case file with overrides, solved as a chain of `levels`
    (the last is compared; one level for a start other than `coarser`)."""

    name: str
    case: Path
    overrides: tuple[str, ...]
    levels: tuple[int, ...]
    start: str  # what the table says of the start: the case's own, or cold from coarsest_guess

    def scene(self, perturbation: Perturbation) -> Scene:
        named = [*self.overrides, f'scene.name="{self.name}__{perturbation.slug}"']
        base = load_scene(self.case, named)
        return load_scene(self.case, [*named, *perturbation.overrides(base)])

    @property
    def n(self) -> int:
        return self.levels[-1]


def compared_level(scene: Scene) -> int:
    wanted = LEVEL[scene.dimension]
    below = [n for n in scene.levels if n <= wanted]
    return wanted if wanted in scene.levels or not below else max(below)


def configs_of(case: Path, cold: bool) -> list[Config]:
    """The case as its file asks (a chain up to the compared level when it starts from the
    coarser level), and with `cold` also the compared level alone from the case's coarsest
    start, as the stress study's cold starts run it."""
    scene = load_scene(case)
    n = compared_level(scene)
    chained = scene.initial_guess == "coarser"
    levels = tuple(sorted({m for m in scene.levels if m < n} | {n})) if chained else (n,)
    start = own_start(scene) if chained and len(levels) == 1 else scene.initial_guess
    out = [Config(case.stem, case, (), levels, "chain" if len(levels) > 1 else start)]
    if cold and len(levels) > 1:
        start = own_start(scene)
        out.append(Config(f"{case.stem}_cold", case, (f'scene.initial_guess="{start}"',), (n,), f"{start} (cold)"))
    return out


# A scene whose answer is known to hang on round-off, solved here too so that the table
# shows it: the paper's block with both ends free, at n = 8 from zero (nothing but Tresca's
# grip holds it along Gamma_3; which branch Newton lands on, or whether it fails, changes with
# the BLAS kernel, docs/hard-cases.md).
EXTRA = (Config("paper_free_ends", SCENES / "paper.toml",
                ('geometry.left="free"', 'geometry.right="free"', 'scene.initial_guess="zero"'), (8,), "zero"),)


@dataclass(frozen=True)
class Remedy:
    """What makes a sensitive configuration's answer deterministic: its row's name and case
    keys, and why they do."""

    name: str
    overrides: tuple[str, ...]
    why: str


# Sensitive configurations known and documented (docs/hard-cases.md, "Branch stability"),
# each with its remedy, solved too with its perturbations: that row must be stable.
KNOWN_SENSITIVE: dict[str, Remedy] = {
    "paper_free_ends": Remedy(
        "paper_free_ends_roller", ('geometry.left="roller_x"', 'geometry.right="free"', 'scene.initial_guess="zero"'),
        "a roller on the left end holds the slide along Gamma_3 that only Tresca's grip held (the fix the "
        "failure's own line names)"),
}


def remedies(configs: Sequence[Config]) -> list[Config]:
    return [Config(KNOWN_SENSITIVE[c.name].name, c.case, KNOWN_SENSITIVE[c.name].overrides, (c.n,), c.start)
            for c in configs if c.name in KNOWN_SENSITIVE]


def remedy_names() -> frozenset[str]:
    return frozenset(r.name for r in KNOWN_SENSITIVE.values())


def all_configs(hard: bool = True, scenes: bool = True, names: Sequence[str] = ()) -> list[Config]:
    """Every hard case (and its cold start), every scene of cases/, the extra rows and the
    remedies of the known sensitive ones; only `names` when given."""
    out: list[Config] = []
    if hard:
        for case in sorted(HARD.glob("*.toml")):
            out += configs_of(case, cold=True)
    if scenes:
        for case in sorted(SCENES.glob("*.toml")):
            out += configs_of(case, cold=False)
        out += EXTRA
    out += remedies(out)
    if names:
        out = [c for c in out if c.name in set(names)]
    return out


class JitteredMeshes(Mapping[int, Path]):
    """The chain's meshes, each made when first looked up, jittered or not."""

    def __init__(self, scene: Scene, levels: Sequence[int], layout: Layout, jitter: Jitter | None) -> None:
        self._scene, self._levels, self._layout, self._jitter = scene, sorted(levels), layout, jitter
        self._made: dict[int, Path] = {}

    def __getitem__(self, n: int) -> Path:
        if n not in self._levels:
            raise KeyError(n)
        if n not in self._made:
            with GMSH:
                directory = self._layout.meshes_dir(self._scene.name)
                self._made[n] = build_mesh(self._scene.geometry, n, directory, warn=False, jitter=self._jitter).path
        return self._made[n]

    def __iter__(self) -> Iterator[int]:
        return iter(self._levels)

    def __len__(self) -> int:
        return len(self._levels)


@dataclass
class Solved:
    """One solve of a configuration: the compared level's outcome and its scene."""

    perturbation: Perturbation
    scene: Scene
    outcome: LevelOutcome
    n_wanted: int  # the compared level: a chain may fail below it
    chain_its: list[int | None] = field(default_factory=list)

    @property
    def status(self) -> str:
        if self.outcome.ok:
            return "converged"
        if self.outcome.n != self.n_wanted:
            return f"failed at n={self.outcome.n}"
        failure = self.outcome.failure
        return failure.name.lower() if failure else "failed"

    @property
    def record(self) -> RunRecord:
        return self.outcome.record or RunRecord()

    @property
    def checks_ok(self) -> bool | None:
        if not self.outcome.ok:
            return None
        return bool(judge(self.record, self.scene).values.get("checks_ok"))


def solve(config: Config, perturbation: Perturbation, layout: Layout, force: bool = False) -> Solved:
    scene = config.scene(perturbation)
    check_solver_files(scene, layout)
    meshes = JitteredMeshes(scene, config.levels, layout, perturbation.jitter)
    outcomes = run_levels(scene, meshes, layout, force=force, progress=quiet, pipelined=False)
    last = list(outcomes.values())[-1]
    its = [o.record.newton_iterations if o.record else None for o in outcomes.values()]
    return Solved(perturbation, scene, last, config.n, its)


# ---- how far two solutions are ------------------------------------------------------------

def relative(a: float, b: float, floor: float) -> float:
    """|a - b| over the larger of |a|, |b| and `floor` (0 when both are 0 and so is the floor)."""
    size = max(abs(a), abs(b), floor)
    return abs(a - b) / size if size > 0 else 0.0


def norm_of(fields: Fields, values: np.ndarray, name: str) -> float:
    """A field's norm of E^h (V for u, W for phi, Q for theta) on the mesh of `fields`."""
    stem = measure_of(name).stem
    if fields.tetrahedra is not None:
        return simplex_seminorm(fields.points, fields.cells, values, stem)
    return float(np.sqrt(P1_INTEGRANDS[stem](fields.points, fields.triangles, values)))


def body_measure(fields: Fields) -> tuple[float, float]:
    """The body's area (volume in 3D) and its size (the longest side of its bounding box)."""
    d = fields.cells.shape[1] - 1
    corners = fields.points[fields.cells][:, :, :d]
    measure = float(np.abs(np.linalg.det(corners[:, 1:] - corners[:, :1])).sum()) / math.factorial(d)
    return measure, float(np.ptp(fields.points, axis=0).max())


def field_differences(base: Fields, other: Fields, scales: Mapping[str, float]) -> dict[str, float]:
    """Each field's relative difference in its norm: ||f' - f|| / max(||f||, ||f'||, floor),
    the floor FIELD_FLOOR of the field's scale varying over the body's size. The same mesh
    (a jittered one differs by 1e-9 h, below solution.vtu's single-precision coordinates):
    node by node; any other: the P1 transfer of the convergence study."""
    measure, size = body_measure(base)
    same = base.points.shape == other.points.shape and np.allclose(base.points, other.points, rtol=0, atol=1e-6 * size)
    names = [name for name in FIELD_NAMES if name in base.values and name in other.values]
    apart = ({name: norm_of(base, other.field(name) - base.field(name), name) for name in names} if same
             else error_norms(base, other, names))
    out = {}
    for name in names:
        floor = FIELD_FLOOR * scales.get(SCALE_OF[name], 0.0) * math.sqrt(measure) / size
        size_of = max(norm_of(base, base.field(name), name), norm_of(other, other.field(name), name), floor)
        out[name] = apart[name] / size_of if size_of > 0 else 0.0
    return out


def resultant_floor(record: RunRecord, reading: str) -> float:
    if reading == "force":  # the applied load's magnitude: what the contact force balances
        load = (record.checks or {}).get("applied_load") or [0.0]
        return float(np.linalg.norm(np.asarray(load, dtype=float)))
    return abs(float((record.checks or {}).get(reading) or 0.0))


def resultant_differences(base: RunRecord, other: RunRecord) -> dict[str, float]:
    out = {}
    for key, reading in RESULTANTS.items():
        a, b = getattr(base, key), getattr(other, key)
        if a is None or b is None:
            continue
        out[key] = relative(float(a), float(b), max(resultant_floor(base, reading), resultant_floor(other, reading)))
    return out


@dataclass(frozen=True)
class Comparison:
    """A perturbed solve against the unperturbed one."""

    fields: dict[str, float]
    resultants: dict[str, float]
    nodal: float
    changed: tuple[str, ...]  # what else changed: status, checks

    @property
    def field_max(self) -> float:
        return max(self.fields.values(), default=0.0)

    @property
    def resultant_max(self) -> float:
        return max(self.resultants.values(), default=0.0)

    @property
    def sensitive(self) -> bool:
        return bool(self.changed) or self.field_max > TOLERANCE or self.resultant_max > TOLERANCE


def verdict_changes(base: Solved, other: Solved) -> tuple[str, ...]:
    changed = []
    if base.status != other.status:
        changed.append(f"status {base.status} -> {other.status}")
    if base.checks_ok != other.checks_ok:
        changed.append(f"checks {base.checks_ok} -> {other.checks_ok}")
    return tuple(changed)


def compare(base: Solved, other: Solved) -> Comparison:
    changed = verdict_changes(base, other)
    if not (base.outcome.ok and other.outcome.ok):
        return Comparison({}, {}, math.nan, changed)
    assert base.outcome.directory is not None and other.outcome.directory is not None
    scales = base.record.scales or {}
    fields = field_differences(read_fields(base.outcome.directory / "solution.vtu"),
                               read_fields(other.outcome.directory / "solution.vtu"), scales)
    nodal = field_difference(base.outcome.directory, other.outcome.directory, scales)
    return Comparison(fields, resultant_differences(base.record, other.record), nodal, changed)


# ---- the table ----------------------------------------------------------------------------

def row_of(config: Config, solved: Solved, comparison: Comparison | None) -> dict[str, Any]:
    record = solved.record
    row: dict[str, Any] = {
        "case": config.name, "start": config.start, "n": config.n, "perturbation": solved.perturbation.name,
        "status": solved.status, "newton_iterations": record.newton_iterations,
        "chain_iterations": " ".join("?" if i is None else str(i) for i in solved.chain_its),
        "checks_ok": solved.checks_ok,
    }
    if comparison is not None:
        row.update({f"diff_{name}": comparison.fields.get(name, math.nan) for name in FIELD_NAMES})
        row.update({"field_difference": comparison.field_max if comparison.fields else math.nan,
                    "resultant_difference": comparison.resultant_max if comparison.resultants else math.nan,
                    "nodal_difference": comparison.nodal, "changed": "; ".join(comparison.changed),
                    "verdict": "sensitive" if comparison.sensitive else "stable"})
    else:
        row["verdict"] = "reference"
    return row


SUMMARY_KEYS = ("newton_iterations", "max_abs_u", "min_phi", "max_phi", "max_theta", "contact_force",
                "friction_force", "active_measure", "heat_in_contact", "charge_in_contact")


def solution_summary(solved: Solved) -> dict[str, Any]:
    """What a branch is, in a few numbers: its status, Newton's work and the physical
    quantities of run.json; and where its fields are."""
    record = solved.record
    return {"perturbation": solved.perturbation.name, "status": solved.status,
            **{key: record.value(key) for key in SUMMARY_KEYS},
            "directory": str(solved.outcome.directory or "")}
