"""`RunRecord`: one FreeFEM run's run.json as a typed record, and the only reader of run.json.

FreeFEM writes run.json (freefem/output.idp, freefem/reference_error.idp); the harness adds
its own measurements (`HARNESS_KEYS`) when it collects a finished run. Reading validates the
keys: every key FreeFEM always writes must be there, and a key nobody declared is an error
(a test checks the declared keys against what the .idp files write), so the two languages
cannot drift apart silently. Values that only some runs have (a field's range, manufactured
or reference errors, the harness's pipelining) are None when absent.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from harness.core.errors import FieldsError

# Keys of `checks` (freefem/checks.idp via output.idp); harness/measure/checks.py compares them.
CHECK_KEYS = frozenset({
    "applied_load", "clamp_reaction", "contact_force_on_body", "force_imbalance", "force_residual_bound",
    "max_sigma_nu", "min_sigma_nu", "max_abs_sigma_tau", "S", "open_nodes", "natural_heat_flux",
    "natural_charge_flux", "heat_source", "heat_residual_bound", "charge_residual_bound",
    "heat_out_dirichlet", "heat_imbalance", "max_heat_flux_contact", "max_heat_flux_open",
    "max_heat_flux_open_expected", "charge_source", "charge_out_dirichlet", "charge_imbalance", "electrode_charge",
    "max_charge_flux_contact", "max_charge_flux_open", "max_charge_flux_open_expected",
    # the size of the terms each reading sums (the checks' floors, harness/measure/checks.py)
    "force_reading", "traction_reading", "heat_reading", "heat_flux_reading", "charge_reading", "charge_flux_reading",
    # the size of what the contact flux is formed from, int_Gamma_3 p_r(s) (|theta| + |theta_f|), the same of phi
    "heat_contact_reading", "charge_contact_reading",
    # a floating electrode's potential, its charge read from the residual, the given one, and the
    # size of the terms that reading sums (freefem/floating.idp; only when the scene has one)
    "floating_potential", "floating_charge", "floating_charge_given", "floating_charge_reading",
})


@dataclass(frozen=True)
class RunRecord:
    # -- written by freefem/output.idp on every run
    n: int | None = None
    element: str | None = None
    effects: list[str] | None = None
    fields: list[str] | None = None
    strategy: str | None = None
    dofs: int | None = None
    newton_dofs: int | None = None
    nodes: int | None = None
    unknowns_per_node: int | None = None
    material: str | None = None
    initial_guess: str | None = None  # the harness replaces FreeFEM's start with the scene's
    converged: bool | None = None
    reason: str | None = None
    newton_iterations: int | None = None
    restarted_at: int | None = None  # Newton restarted from the pressed state after it (0: never)
    failure_hint: str | None = None  # why Newton failed, when it can tell (freefem/newton.idp); empty otherwise
    moved_onto_foundation_at: int | None = None  # the free first step from zero replaced by Gamma_3 on the foundation (0: never)
    residuals: dict[str, list[float]] | None = None
    increments: dict[str, list[float]] | None = None
    error_estimates: dict[str, list[float]] | None = None
    staggered_theta_residual: float | None = None
    damping: list[float] | None = None
    consistent_tangent: list[int] | None = None
    linear_iterations: list[int] | None = None
    active_nodes: list[int] | None = None
    slip_nodes: list[int] | None = None
    active_set_changes: list[int] | None = None
    scales: dict[str, float] | None = None
    linear_solver: str | None = None
    factorisations: int | None = None
    peak_rss_mb: float | None = None
    gmres_iterations: int | None = None
    bulk_assembly_s: float | None = None
    assembly_s: float | None = None
    factorisation_s: float | None = None
    first_factorisation_s: float | None = None
    solve_s: float | None = None
    newton_s: float | None = None
    newton_over_linear: float | None = None
    output_s: float | None = None
    total_s: float | None = None
    ready_s: float | None = None
    initial_guess_s: float | None = None
    # each piece of the run: [CPU seconds, calls, MB it raised the peak by] (freefem/profile.idp)
    profile: dict[str, list[float]] | None = None
    max_abs_u: float | None = None
    contact_force: float | None = None
    friction_force: float | None = None  # the magnitude of friction_force_vector
    friction_force_vector: list[float] | None = None  # its x, y(, z) components
    friction_total: float | None = None  # |sigma_tau| integrated over Gamma_3
    friction_open: float | None = None  # the same over its open part
    active_measure: float | None = None  # the closed part of Gamma_3: a length in 2D, an area in 3D
    heat_in_contact: float | None = None
    charge_in_contact: float | None = None
    peak_contact_pressure: float | None = None  # the largest nodal contact pressure on Gamma_3 [N/m^2]
    probes: list[float] | None = None  # the case's [quantities] probes, in its order (freefem/quantities.idp)
    averages: list[float] | None = None  # and its averages
    checks: dict[str, Any] | None = None
    # per boundary role the mesh has: the force its supports exert on the body, the free charge on it,
    # the heat leaving through it, each where the role fixes that field (freefem/reactions.idp)
    reactions: dict[str, dict[str, Any]] | None = None
    # the recovery estimate of each field's error in its norm of E^h, and the field's own norm (estimator.idp)
    estimator: dict[str, float] | None = None
    estimator_norms: dict[str, float] | None = None
    estimate_s: float | None = None
    # each goal's dual-weighted residual estimate of Q_exact - Q_h, the P2 Newton unknowns of its
    # dual and the time of the goals (freefem/goals.idp; only with [quantities] goals)
    goal_estimates: dict[str, float] | None = None
    goal_dofs: int | None = None
    goal_s: float | None = None
    freefem_version: str | None = None
    # -- the range of each scalar field the scene has ("min_" + name, "max_" + name)
    min_phi: float | None = None
    max_phi: float | None = None
    min_theta: float | None = None
    max_theta: float | None = None
    # -- manufactured solutions (IFMACRO(MMS)) and reference errors (IFMACRO(REFERENCE))
    mms_errors: dict[str, dict[str, float]] | None = None
    mms_norms: dict[str, dict[str, float]] | None = None
    mms_measure_errors: dict[str, float] | None = None  # each field's true error in its norm of E^h
    reference_errors: dict[str, float] | None = None
    reference_norms: dict[str, float] | None = None
    reference: dict[str, Any] | None = None
    reference_s: float | None = None
    peak_rss_before_reference_mb: float | None = None
    # -- added by the harness (run.collect)
    wall_s: float | None = None
    pipelined: bool | None = None
    waited_s: float | None = None
    peak_rss_source: str | None = None
    started_from: str | None = None
    warnings: list[str] | None = None  # what the harness warns of this run (harness/run/tresca.py)
    # each material region (in the mesh's label order): its name, its material and the file read for it
    regions: list[dict[str, str]] | None = None
    # every quantity of the scene's effects by name, from the table of harness/run/quantities.py
    quantities: dict[str, float] | None = None
    # -- a run on MPI ranks (run.ranks > 1; freefem/ranks_record.idp): the ranks,
    # freefem/parallel_output.idp's figures, and the sequential pass's own peak and residuals
    ranks: int | None = None
    parallel: dict[str, Any] | None = None
    post_pass_peak_rss_mb: float | None = None
    post_pass_residuals: dict[str, list[float]] | None = None

    def value(self, name: str) -> Any:
        """A declared key by name (a table's column list); NaN when the run has none."""
        value = getattr(self, name)
        return math.nan if value is None else value

    def with_(self, **changes: Any) -> RunRecord:
        return dataclasses.replace(self, **changes)

    def to_json(self) -> dict[str, Any]:
        """The keys the run has, in declaration order (absent ones are left out)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if getattr(self, f.name) is not None}

    @classmethod
    def from_json(cls, data: Any, source: str = "run.json") -> RunRecord:
        if not isinstance(data, dict):
            raise FieldsError(f"{source}: not a JSON object")
        unknown = sorted(set(data) - KEYS - set(RENAMED_KEYS))
        if unknown:
            raise FieldsError(f"{source}: undeclared key {unknown[0]!r} (harness/run/record.py RunRecord)")
        missing = [k for k in ALWAYS_WRITTEN if k not in data]
        if missing and data.get("converged") is True:  # a failed run may stop writing early
            raise FieldsError(f"{source}: FreeFEM did not write {missing[0]!r}")
        checks = data.get("checks") or {}
        odd = sorted(set(checks) - CHECK_KEYS)
        if odd:
            raise FieldsError(f"{source}: undeclared check {odd[0]!r} (harness/run/record.py CHECK_KEYS)")
        return cls(**renamed(data))


# Keys of run.json files written before a rename (issue 21): old name -> new name. In 3D
# `active_length` was an area; `friction_force` was the x component (an old file keeps it).
RENAMED_KEYS = {"active_length": "active_measure"}
KEYS = frozenset(f.name for f in dataclasses.fields(RunRecord))
# What output.idp writes on every converged run (the rest depends on the scene).
ALWAYS_WRITTEN = ("n", "converged", "reason", "newton_iterations", "dofs", "fields")
HARNESS_KEYS = ("wall_s", "pipelined", "waited_s", "peak_rss_source", "started_from", "warnings", "regions",
                "quantities")


def renamed(data: dict[str, Any]) -> dict[str, Any]:
    """`data` with the old key names of RENAMED_KEYS under their new names."""
    return {RENAMED_KEYS.get(key, key): value for key, value in data.items()}


def read_run_json(directory: Path) -> RunRecord | None:
    """The run.json in `directory`; None when there is none or it is not JSON (a run that
    crashed before writing it). A run.json with undeclared or missing keys is an error."""
    path = directory / "run.json"
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return RunRecord.from_json(data, str(path))


def write_run_json(record: RunRecord, directory: Path) -> None:
    from harness.core.atomic import write_atomic

    write_atomic(directory / "run.json", json.dumps(record.to_json(), indent=2) + "\n")
