"""The verdict of the physical checks, computed here and only here (`judge`), for every
study that reports them (solve, convergence, stress, branches); the lines `solve` and
`convergence` print; and the small-strain guard. A failed check makes the verdict fail
(exit 1)."""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping

from harness.measure.checks import CHECK_FLAGS, SCENE_FLAGS, physical_checks
from harness.core.errors import FieldsError
from harness.measure.fields import Fields, read_fields
from harness.core.guards import max_displacement_gradient, small_strain_warning
from harness.run.record import RunRecord
from harness.run.run import RunResult
from harness.scene.scene import Scene

# Check flag -> the value(s) worth showing when it fails (harness/measure/checks.py physical_checks).
SHOWN = {
    "force_ok": ("force_imbalance", "force_residual_bound"),
    "sigma_nu_ok": ("max_sigma_nu", "sigma_nu_scale"),
    "sigma_tau_ok": ("sigma_tau_excess",),
    "open_flux_ok": ("heat_flux_open_error", "charge_flux_open_error"),
    "heat_ok": ("heat_imbalance",),
    "charge_ok": ("charge_imbalance",),
    "floating_ok": ("floating_charge_error",),
}

# Check flag -> what to try when it fails (printed after its values).
ADVICE = {
    "force_ok": "tighten newton.rtol: the imbalance is Newton's final residual",
    "sigma_nu_ok": "tighten newton.rtol: a tensile sigma_nu is Newton's residual at a contact node",
    "sigma_tau_ok": "tighten newton.rtol: |sigma_tau| beyond the slip bound is Newton's residual at a contact node",
    "open_flux_ok": "tighten newton.rtol: a flux through an open node is Newton's residual there",
    "heat_ok": "tighten newton.rtol: the balance is exact for a converged residual",
    "charge_ok": "tighten newton.rtol: the balance is exact for a converged residual",
    "floating_ok": "tighten newton.rtol: the electrode's charge is its equation's residual",
}

# Check flag -> the run.json `checks` entries it cannot be judged without.
NEEDS = {
    "force_ok": ("force_imbalance",),
    "sigma_nu_ok": ("max_sigma_nu",),
    "sigma_tau_ok": ("max_abs_sigma_tau",),
    "open_flux_ok": ("max_heat_flux_open", "max_charge_flux_open"),
    "heat_ok": ("heat_out_dirichlet",),
    "charge_ok": ("charge_out_dirichlet",),
    "floating_ok": ("floating_charge",),
}


def flags_of(reported: Mapping[str, Any]) -> tuple[str, ...]:
    """The checks of a run: every run's, and those of the parts its scene has (SCENE_FLAGS)."""
    return CHECK_FLAGS + tuple(flag for flag in SCENE_FLAGS if all(key in reported for key in NEEDS[flag]))


@dataclass(frozen=True)
class Judgement:
    """The physical checks of one converged run: physical_checks' values and flags, the flags
    that failed, and those the solver wrote no quantity for (said to be missing, not failed:
    a scene or dimension checks.idp does not cover yet)."""

    values: dict[str, Any] = field(default_factory=dict)
    failed: tuple[str, ...] = ()
    missing: tuple[str, ...] = ()

    @property
    def passed(self) -> bool:
        return not self.failed

    @property
    def reported(self) -> bool:
        return bool(self.values)


def judge(record: RunRecord, scene: Scene) -> Judgement:
    """Pass or fail of every check of one run (harness/measure/checks.py compares each with its
    tolerance); `checks_ok` among the values is this verdict. No checks in run.json: none
    reported, nothing failed."""
    reported = record.checks
    if not reported:
        return Judgement(missing=CHECK_FLAGS)
    values = physical_checks(record, scene)  # every quantity FreeFEM's (checks.idp)
    flags = flags_of(reported)
    missing = tuple(flag for flag in flags if not all(key in reported for key in NEEDS[flag]))
    failed = tuple(flag for flag in flags if not values.get(flag) and flag not in missing)
    values["checks_ok"] = not failed
    return Judgement(values, failed, missing)


@dataclass(frozen=True)
class Checked:
    n: int
    line: str  # what is printed for the level
    passed: bool  # every check passed (or the solver reported none)
    warnings: tuple[str, ...] = ()


def check_run(scene: Scene, run: RunResult, fields: Fields | None = None) -> Checked:
    """Evaluate the checks of one converged run (harness/measure/checks.py); `fields`: its solution,
    when already parsed (else read here)."""
    fields = fields or solution_fields(run)
    warnings = list(run.record.warnings or ())  # the run's own (harness/run/tresca.py)
    if fields is not None and "u" in fields.values:
        gradient = max_displacement_gradient(fields.points, fields.cells, fields.field("u"))
        warning = small_strain_warning(gradient, f"{scene.name} n={run.n}")
        if warning:
            warnings.append(warning)
    judged = judge(run.record, scene)
    if not judged.reported:
        return Checked(run.n, f"checks n={run.n}: none reported by the solver", True, tuple(warnings))
    if judged.passed:
        done = [f[:-3] for f in flags_of(run.record.checks) if f not in judged.missing]
        note = f"; not reported: {', '.join(f[:-3] for f in judged.missing)}" if judged.missing else ""
        return Checked(run.n, f"checks n={run.n}: pass ({', '.join(done)}){note}", True, tuple(warnings))
    values = judged.values
    detail = "; ".join(f"{flag[:-3]} " + ", ".join(f"{k} {fmt(values.get(k))}" for k in SHOWN[flag])
                       + f" (try: {ADVICE[flag]})" for flag in judged.failed)
    return Checked(run.n, f"checks n={run.n}: FAIL {detail}", False, tuple(warnings))


def solution_fields(run: RunResult) -> Fields | None:
    try:
        return read_fields(run.solution)
    except FieldsError:
        return None


def fmt(value: Any) -> str:
    return f"{value:.3g}" if isinstance(value, float) else str(value)


def print_checks(scene: Scene, runs: Iterable[RunResult],
                 solutions: Mapping[int, Fields] | None = None) -> list[Checked]:
    """Print each run's checks (stdout) and warnings (stderr); the list, for the verdict.
    `solutions`: the runs' parsed fields by level, when a study has them already."""
    out = []
    for run in runs:
        checked = check_run(scene, run, (solutions or {}).get(run.n))
        print(checked.line)
        for warning in checked.warnings:
            print(f"warning: {warning}", file=sys.stderr)
        out.append(checked)
    return out


def failed_checks(checked: list[Checked]) -> str | None:
    """The error line when any check failed, else None."""
    bad = [c for c in checked if not c.passed]
    if not bad:
        return None
    return (f"physical checks failed at n = {', '.join(str(c.n) for c in bad)} "
            f"({bad[0].line.split('FAIL ', 1)[-1]})")
