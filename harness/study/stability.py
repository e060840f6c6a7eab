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

from harness.core.layout import REPO, Layout
from harness.measure.agreement import TOLERANCE, exact_points, field_differences, resultant_differences
from harness.measure.fields import read_fields
from harness.measure.norm_table import FIELD_NAMES
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
LOAD_STEP = 1e-12
JITTER = 1e-9


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


# The paper's block with both ends free, at n = 8 from zero: nothing but Tresca's grip holds it
# along Gamma_3, and every point of it slips. Which state Newton returned, or whether it failed,
# once changed with the BLAS kernel and with every perturbation here; the slide is now read from
# the translation itself (freefem/rigid_slide.idp) and the row must be stable: not unique, on every
# kernel (docs/hard-cases.md). Beside it, the same scene held by a roller on one end, which converges.
EXTRA = (Config("paper_free_ends", SCENES / "paper.toml",
                ('geometry.left="free"', 'geometry.right="free"', 'scene.initial_guess="zero"'), (8,), "zero"),
         Config("paper_free_ends_roller", SCENES / "paper.toml",
                ('geometry.left="roller_x"', 'geometry.right="free"', 'scene.initial_guess="zero"'), (8,), "zero"))


@dataclass(frozen=True)
class Remedy:
    """What makes a sensitive configuration's answer deterministic: its row's name and case
    keys, and why they do."""

    name: str
    overrides: tuple[str, ...]
    why: str


# Sensitive configurations known and documented (docs/hard-cases.md, "Branch stability"),
# each with its remedy, solved too with its perturbations: that row must be stable. None today:
# the one there was (paper_free_ends) is deterministic now, and a row of EXTRA.
KNOWN_SENSITIVE: dict[str, Remedy] = {}


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
    mesh: Path | None = None  # the compared level's mesh file

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
    return Solved(perturbation, scene, last, config.n, its, meshes[config.n] if last.n == config.n else None)


@dataclass(frozen=True)
class Comparison:
    """A perturbed solve against the unperturbed one."""

    fields: dict[str, float]
    resultants: dict[str, float]
    nodal: float
    changed: tuple[str, ...]  # what else changed: status, checks
    judged: bool = True  # whether the differences count (both converged), or are only shown

    @property
    def field_max(self) -> float:
        return max(self.fields.values(), default=0.0)

    @property
    def resultant_max(self) -> float:
        return max(self.resultants.values(), default=0.0)

    @property
    def sensitive(self) -> bool:
        moved = self.field_max > TOLERANCE or self.resultant_max > TOLERANCE
        return bool(self.changed) or (self.judged and moved)


def verdict_changes(base: Solved, other: Solved) -> tuple[str, ...]:
    changed = []
    if base.status != other.status:
        changed.append(f"status {base.status} -> {other.status}")
    if base.checks_ok != other.checks_ok:
        changed.append(f"checks {base.checks_ok} -> {other.checks_ok}")
    return tuple(changed)


def compare(base: Solved, other: Solved) -> Comparison:
    """`other` against `base`. Two converged solves are judged by their differences too; where
    either failed, its answer is its status, and the differences of the states the failed run
    left (its solution.vtu) are shown beside it, not judged: a slide that nothing determines
    may end anywhere along its family."""
    changed = verdict_changes(base, other)
    judged = base.outcome.ok and other.outcome.ok
    dirs = (base.outcome.directory, other.outcome.directory)
    if not all(d is not None and (d / "solution.vtu").is_file() for d in dirs) or base.outcome.n != other.outcome.n:
        return Comparison({}, {}, math.nan, changed, judged)
    a, b = (d / "solution.vtu" for d in dirs if d is not None)
    scales = base.record.scales or {}
    fields = field_differences(exact_points(read_fields(a), base.mesh), exact_points(read_fields(b), other.mesh), scales)
    nodal = field_difference(a.parent, b.parent, scales)
    return Comparison(fields, resultant_differences(base.record, other.record), nodal, changed, judged)


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


def solution_summary(solved: Solved, root: Path, comparison: Comparison | None = None) -> dict[str, Any]:
    """What a branch is, in a few numbers: its status, Newton's work and the physical
    quantities of run.json, where its fields are (under the study's `root`), and with
    `comparison` how far it is from the unperturbed solve."""
    record = solved.record
    directory = solved.outcome.directory
    out = {"perturbation": solved.perturbation.name, "status": solved.status,
           **{key: record.value(key) for key in SUMMARY_KEYS},
           "directory": str(directory.relative_to(root)) if directory and directory.is_relative_to(root) else str(directory)}
    if comparison is not None:
        out.update({"changed": list(comparison.changed), "field_differences": comparison.fields,
                    "resultant_differences": comparison.resultants})
    return out
