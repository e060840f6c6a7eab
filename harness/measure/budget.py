"""The error budget of a level (`python -m harness budget`, docs/cost.md): each quantity's error
at level N in three parts, each relative to the quantity's value there and each beside the wall
time its runs took.

- discretisation: Richardson's, from levels N/4, N/2, N (the three-grid procedure of
  harness/measure/quantity_study.py): (f_ext - f_N) / |f_N|, the estimate of Q_exact - Q_N
  (summary.json's relative errors divide by |f_ext|: the same to first order); a
  quantity that is not extrapolable has none (its status says why). When level N's run.json has
  a goal-oriented estimate (`goal_estimates.<name>`, Q_exact - Q_h), it is shown beside:
  estimate / |Q_N|;
- the penalty: level N again at c_nu x10 and x100, (Q(10 c_nu) - Q) / |Q| and
  (Q(100 c_nu) - Q) / |Q|: how far the answer moves as the contact is made stiffer, the way
  penalised contact approaches exact contact; and from the three, Richardson's limit in
  1/c_nu, (Q_inf - Q) / |Q|, when the answer has one (`penalty_limit`);
- Newton: level N solved to newton.rtol = 1e-6 against the case's own rtol,
  (Q(rtol 1e-6) - Q) / |Q|: the error a looser solve would make.

Every part is signed: the other run's (or the extrapolated) value minus level N's, over |level
N's|, so a positive part says the quantity would grow. Dividing by level N's value, not by a
limit, keeps a part finite where the limit is near zero (a friction force that vanishes as the
contact stiffens).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import pandas as pd

from harness.measure.quantity_study import CONVERGED, EXTRAPOLATED, ROUND_OFF, converge
from harness.measure.tolerances import goal_estimate
from harness.run.record import RunRecord

PENALTY_FACTORS = (10, 100)
LOOSE_RTOL = 1e-6


@dataclass(frozen=True)
class BudgetRuns:
    """The records of a budget's runs: the three levels (N/4, N/2, N) and level N at c_nu x10 and
    x100 (absent without contact) and at rtol 1e-6."""

    levels: Mapping[int, RunRecord]
    penalty: Mapping[int, RunRecord]   # factor -> level N's record at that c_nu
    newton: RunRecord

    @property
    def n(self) -> int:
        return max(self.levels)

    @property
    def finest(self) -> RunRecord:
        return self.levels[self.n]


def relative_change(other: float, value: float) -> float:
    """(other - value) / |value|; 0 when both are 0, NaN when only `value` is."""
    if not (math.isfinite(other) and math.isfinite(value)):
        return math.nan
    if value == 0:
        return 0.0 if other == 0 else math.nan
    return (other - value) / abs(value)


def value_of(record: RunRecord, name: str) -> float:
    value = (record.quantities or {}).get(name)
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else math.nan


def wall(records: list[RunRecord]) -> float:
    return float(sum(r.value("wall_s") for r in records)) if records else math.nan


def budget_table(quantities: list[tuple[str, str]], runs: BudgetRuns) -> pd.DataFrame:
    """budget.csv: a row per quantity (`quantities`: its name and unit), its value at level N,
    each part's signed relative size and the wall time of each part's runs."""
    n = runs.n
    coarse = [runs.levels[k] for k in sorted(runs.levels) if k != n]
    goals = any(goal_estimate(runs.finest, name) is not None for name, _ in quantities)
    rows = []
    for name, unit in quantities:
        value = value_of(runs.finest, name)
        three = converge(name, unit, snapped({k: value_of(r, name) for k, r in runs.levels.items()}))
        richardson = 0.0 if three.status == CONVERGED else \
            relative_change(three.extrapolated, value) if three.status == EXTRAPOLATED else math.nan
        row = {"quantity": name, "unit": unit, "value": value,
               "discretisation": richardson,
               "discretisation_status": three.status + (f": {three.why}" if three.why else "")}
        if goals:
            goal = goal_estimate(runs.finest, name)
            row["goal_estimate"] = math.nan if goal is None or not value else goal / abs(value)
        for factor in PENALTY_FACTORS:
            other = runs.penalty.get(factor)
            row[f"penalty_x{factor}"] = math.nan if other is None else relative_change(value_of(other, name), value)
        row["penalty_limit"], row["penalty_limit_status"] = penalty_limit(name, unit, value, runs.penalty)
        row["newton"] = relative_change(value_of(runs.newton, name), value)
        row.update({"value_wall_s": runs.finest.value("wall_s"), "discretisation_wall_s": wall(coarse),
                    "penalty_wall_s": wall(list(runs.penalty.values())), "newton_wall_s": runs.newton.value("wall_s")})
        rows.append(row)
    return pd.DataFrame(rows)


def snapped(values: Mapping[int, float]) -> dict[int, float]:
    """`values` (level -> value) with a difference within round-off of the value (ROUND_OFF) made
    zero, coarsest first: two runs that agree to round-off agree, so a triple's classification
    (one difference zero: divergent; or a sign change: oscillatory) does not follow the last bits
    of a solve (the strip actuator's max theta at c_nu x1 and x10: equal, or 1.2e-16 apart)."""
    out: dict[int, float] = {}
    previous = None
    for k in sorted(values):
        v = values[k]
        if previous is not None and math.isfinite(v) and math.isfinite(previous) \
                and abs(v - previous) <= ROUND_OFF * max(abs(v), abs(previous)):
            v = previous
        out[k] = previous = v
    return out


def penalty_limit(name: str, unit: str, value: float, penalty: Mapping[int, RunRecord]) -> tuple[float, str]:
    """Where the quantity goes as c_nu grows without bound, from c_nu x1, x10, x100: the
    three-grid procedure with 1/c_nu as the grid size (ratio 10; the penalty's error of a
    contact problem falls as a power of 1/c_nu when the contact has a limit), so
    (Q_inf - Q) / |Q|, and its status: a quantity that grows with c_nu (the penalty sets
    it) is divergent, not extrapolated."""
    if set(penalty) != set(PENALTY_FACTORS):
        return math.nan, "no contact"
    three = converge(name, unit, snapped({1: value, **{k: value_of(r, name) for k, r in penalty.items()}}))
    why = three.status + (f": {three.why}" if three.why else "")
    if three.status == CONVERGED:
        return 0.0, why
    if three.status == EXTRAPOLATED:
        return relative_change(three.extrapolated, value), why
    return math.nan, why


def part(value: float) -> str:
    return "–" if not math.isfinite(value) else f"{value:+.2e}" if value else "0"


def seconds(value: float) -> str:
    return f"{value:.2f} s" if math.isfinite(value) else "no runs"


def budget_line(row: Mapping[str, Any]) -> str:
    """One quantity's budget as one printed line."""
    goal = f", goal {part(row['goal_estimate'])}" if "goal_estimate" in row else ""
    mesh = part(row["discretisation"]) if math.isfinite(row["discretisation"]) else \
        str(row["discretisation_status"]).split(":")[0]
    limit = part(row["penalty_limit"]) if math.isfinite(row["penalty_limit"]) else \
        str(row["penalty_limit_status"]).split(":")[0]
    return (f"{row['quantity']} = {row['value']:.6g} {row['unit']}: mesh {mesh}{goal} "
            f"({seconds(row['discretisation_wall_s'])}) | penalty x10 {part(row['penalty_x10'])}, "
            f"x100 {part(row['penalty_x100'])}, limit {limit} ({seconds(row['penalty_wall_s'])}) | "
            f"Newton {part(row['newton'])} ({seconds(row['newton_wall_s'])})")
