"""Every quantity's convergence (the table of harness/scene/quantities.py) over a study's levels:
the levels x quantities table (quantities.csv) and, per quantity, the three finest levels'
observed order, Richardson's extrapolated value and the three-grid GCI (harness/measure/gci.py,
Celik et al. 2008), with each level's relative error against the extrapolated value
(summary.json `quantities`).

Only an asymptotic triple is extrapolated: the three finest values must move one way with
shrinking differences (0 < R = e21/e32 < 1, Celik et al.'s monotone convergence). Differences
that change sign (oscillatory), grow (divergent) or vanish at one level only are reported as
not extrapolable, with their behaviour, and never extrapolated: Richardson's formula assumes
f = f_exact + C h^p with one p, which such a triple contradicts. So is a monotone triple whose
extrapolated value has the other sign than the finest level's: the levels fall too fast to be in
the asymptotic range (the paper scene's friction force on the zero branch, 2.4e-4, 8.8e-5, 7.9e-6
N/m at n = 4, 8, 16, extrapolates to -8.1e-5 N/m, a magnitude below zero). Three values equal to
round-off (differences within ROUND_OFF of the value) are converged: the finest value itself,
with a zero band (a P1 field that is exactly linear, a contact zone that ends at a node of every
level).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import pandas as pd

from harness.measure.gci import three_grid
from harness.run.quantities import quantities_of
from harness.run.record import RunRecord
from harness.scene.scene import Scene

EXTRAPOLATED = "extrapolated"
CONVERGED = "converged"
NOT_EXTRAPOLABLE = "not extrapolable"
TOO_FEW = "too few levels"
MISSING = "not reported"
# Differences this small relative to the value are round-off, not convergence: a level's solve
# stops at relative increments of newton.rtol (1e-9 and below in every case file) after
# quadratic convergence, which leaves ~1e-15; a quantity with a real discretisation error
# moves by far more than 1e-12 between two of the levels a study can afford.
ROUND_OFF = 1e-12


@dataclass(frozen=True)
class QuantityConvergence:
    name: str
    unit: str
    status: str               # one of the five above
    why: str                  # for any status but extrapolated: what the three finest levels did
    levels: tuple[int, ...]   # the three finest, finest first (empty: too few)
    order: float              # the observed order p (NaN unless extrapolated)
    extrapolated: float       # Richardson's f_ext (NaN unless extrapolated or converged)
    gci: float                # GCI_fine, relative to the finest value (Celik et al. eq. 9)
    gci_abs: float            # the same band in the quantity's unit
    convergence_ratio: float  # R = e21/e32
    relative_errors: dict[int, float]  # each level's |f_n - f_ext| / |f_ext| (empty unless extrapolated/converged)

    def summary(self) -> dict[str, Any]:
        return {"unit": self.unit, "status": self.status, **({"why": self.why} if self.why else {}),
                "levels": list(self.levels), "order": self.order, "extrapolated": self.extrapolated,
                "gci": self.gci, "gci_abs": self.gci_abs, "convergence_ratio": self.convergence_ratio,
                "relative_errors": {str(n): e for n, e in sorted(self.relative_errors.items())}}


def quantity_values(scene: Scene, records: Mapping[int, RunRecord]) -> pd.DataFrame:
    """quantities.csv: a row per level (n, h = 1/n, dofs, wall_s), a column per quantity, and
    with goals (docs/goals.md) a column `goal_estimate.<name>` per goal, its dual-weighted
    estimate of Q_exact - Q_n. A run.json written before its quantities existed has them read
    from its keys the same way."""
    rows = []
    for n, record in sorted(records.items()):
        values = record.quantities if record.quantities is not None else quantities_of(scene, record.to_json())
        estimates = record.goal_estimates or {}
        rows.append({"n": n, "h": 1.0 / n, "dofs": record.dofs, "wall_s": record.wall_s,
                     **{q.name: values.get(q.name, math.nan) for q in scene.quantities},
                     **{f"goal_estimate.{g}": estimates.get(g, math.nan) for g in scene.goals}})
    return pd.DataFrame(rows)


def converge(name: str, unit: str, values: Mapping[int, float]) -> QuantityConvergence:
    """One quantity's three finest levels of `values` (level n -> value)."""
    levels = tuple(sorted(values, reverse=True)[:3])

    def outcome(status: str, why: str, **known: Any) -> QuantityConvergence:
        given = {"order": math.nan, "extrapolated": math.nan, "gci": math.nan, "gci_abs": math.nan,
                 "convergence_ratio": math.nan, "relative_errors": {}, **known}
        return QuantityConvergence(name, unit, status, why, levels, **given)

    if len(levels) < 3:
        return outcome(TOO_FEW, f"{len(levels)} level(s); the three-grid estimate needs 3")
    f = [float(values[n]) for n in levels]
    if not all(math.isfinite(v) for v in f):
        return outcome(MISSING, "a run did not report it")
    grid = three_grid(tuple(1.0 / n for n in levels), tuple(f))  # type: ignore[arg-type]
    if grid.behaviour == CONVERGED or max(abs(f[1] - f[0]), abs(f[2] - f[1])) <= ROUND_OFF * max(map(abs, f)):
        return outcome(CONVERGED, "the same value on the three finest levels (to round-off)", extrapolated=f[0],
                       gci=0.0, gci_abs=0.0,
                       relative_errors=relative_errors(values, f[0]))
    ratio = grid.convergence_ratio
    if not (0 < ratio < 1) or not math.isfinite(grid.p) or not math.isfinite(grid.f_ext):
        what = {"oscillatory": "the differences change sign", "divergent": "the differences do not shrink",
                "monotone": "one difference is zero"}.get(grid.behaviour, grid.behaviour)
        return outcome(NOT_EXTRAPOLABLE, f"{grid.behaviour}: {what} (R = e21/e32 = {ratio:.3g})",
                       convergence_ratio=ratio)
    if grid.f_ext * f[0] < 0:
        return outcome(NOT_EXTRAPOLABLE, f"overshoot: Richardson's value {grid.f_ext:.3g} has the other sign than "
                       f"the finest level's {f[0]:.3g} (R = e21/e32 = {ratio:.3g})", convergence_ratio=ratio)
    return outcome(EXTRAPOLATED, "", order=grid.p, extrapolated=grid.f_ext, gci=grid.gci_fine,
                   gci_abs=grid.gci_fine_abs, convergence_ratio=ratio,
                   relative_errors=relative_errors(values, grid.f_ext))


def relative_errors(values: Mapping[int, float], reference: float) -> dict[int, float]:
    return {n: abs(v - reference) / abs(reference) if reference else math.nan for n, v in values.items()}


def quantity_convergence(scene: Scene, table: pd.DataFrame) -> dict[str, QuantityConvergence]:
    """Each quantity of quantities.csv's `table`, by name."""
    levels = table["n"].astype(int).tolist()
    return {q.name: converge(q.name, q.unit(scene.dimension), dict(zip(levels, table[q.name].astype(float))))
            for q in scene.quantities if q.name in table.columns}
