"""Tolerances as verdicts: a case's `[quantities] tolerances = { <quantity> = <relative error> }`
judged on a convergence study's finest level, by the estimate of its error
(docs/quantities.md):

- the goal-oriented estimate, when the finest level's run.json has one (`goal_estimates.<name>`,
  the signed estimate of Q_exact - Q_h): |estimate| / |Q_h|;
- otherwise Richardson's: the finest level's |f_1 - f_ext| / |f_ext| of the three-grid procedure
  (harness/measure/quantity_study.py), 0 for a quantity converged to round-off.

A quantity that is not extrapolable (or has too few levels, or a run that did not report it) and
has no goal estimate has no estimate of its error, so it cannot be said to meet a tolerance: it
fails, with why.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

from harness.measure.quantity_study import CONVERGED, EXTRAPOLATED, QuantityConvergence
from harness.run.record import RunRecord

GOAL = "goal estimate"
RICHARDSON = "Richardson"


@dataclass(frozen=True)
class ToleranceVerdict:
    name: str
    tolerance: float
    estimate: float   # the finest level's estimated relative error (NaN when there is none)
    by: str           # GOAL or RICHARDSON, or "" when there is no estimate
    met: bool
    why: str          # when there is no estimate: what the quantity's levels did

    def summary(self) -> dict[str, Any]:
        return {"tolerance": self.tolerance, "estimate": self.estimate, "by": self.by or None, "met": self.met,
                **({"why": self.why} if self.why else {})}

    def line(self) -> str:
        if not self.by:
            return f"tolerance {self.name}: cannot be met: {self.why}, so its error has no estimate " \
                   f"(tolerance {self.tolerance:g})"
        word = "met" if self.met else "NOT met"
        return f"tolerance {self.name}: {word}: estimated relative error {self.estimate:.3g} ({self.by}) " \
               f"against the tolerance {self.tolerance:g}"


def goal_estimate(record: RunRecord, name: str) -> float | None:
    """The finest run's signed goal-oriented estimate of Q_exact - Q_h, when it wrote one."""
    estimates = getattr(record, "goal_estimates", None)
    value = estimates.get(name) if isinstance(estimates, dict) else None
    if isinstance(value, dict):  # an entry that holds more than the estimate: its signed value
        value = value.get("estimate")
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return None
    return float(value)


def judge(tolerances: Mapping[str, float], studied: Mapping[str, QuantityConvergence],
          finest: RunRecord) -> dict[str, ToleranceVerdict]:
    """Each tolerance's verdict on the finest level (`finest`: its run.json)."""
    n = finest.n
    values = finest.quantities or {}
    out = {}
    for name, tolerance in tolerances.items():
        convergence = studied.get(name)
        goal = goal_estimate(finest, name)
        value = values.get(name, math.nan)
        if goal is not None and isinstance(value, (int, float)) and math.isfinite(value) and value != 0:
            estimate = abs(goal) / abs(value)
            out[name] = ToleranceVerdict(name, tolerance, estimate, GOAL, estimate <= tolerance, "")
        elif convergence is not None and convergence.status in (EXTRAPOLATED, CONVERGED) \
                and math.isfinite(convergence.relative_errors.get(n, math.nan)):
            estimate = convergence.relative_errors[n]
            out[name] = ToleranceVerdict(name, tolerance, estimate, RICHARDSON, estimate <= tolerance, "")
        else:
            why = "no level reported it" if convergence is None else \
                f"it is {convergence.status}" + (f" ({convergence.why})" if convergence.why else "")
            out[name] = ToleranceVerdict(name, tolerance, math.nan, "", False, why)
    return out


def failure(verdicts: Mapping[str, ToleranceVerdict], case: str) -> str | None:
    """The verdict's one line when a tolerance is not met: each such quantity, its estimate and its
    tolerance; None when all are met."""
    missed = [v for v in verdicts.values() if not v.met]
    if not missed:
        return None
    parts = [f"{v.name} {v.estimate:.3g} ({v.by}) > {v.tolerance:g}" if v.by else
             f"{v.name} has no error estimate ({v.why}), tolerance {v.tolerance:g}" for v in missed]
    return f"{case}: the finest level does not meet its tolerance: " + "; ".join(parts)
