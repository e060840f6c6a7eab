"""Observed order without a reference: the three-grid procedure and the Grid Convergence
Index of Celik, Ghia, Roache, Freitas, Coleman and Raad (2008), "Procedure for estimation
and reporting of uncertainty due to discretization in CFD applications", J. Fluids Eng.
130(7), 078001 (after Roache's GCI).

Grids 1 (finest), 2, 3 with sizes h1 < h2 < h3 and values f1, f2, f3:
  r21 = h2/h1, r32 = h3/h2, e21 = f2 - f1, e32 = f3 - f2, s = sign(e32/e21);
  p = |ln|e32/e21| + q(p)| / ln r21,  q(p) = ln((r21^p - s)/(r32^p - s))   (eqs. 3-5;
      a fixed point, q = 0 for a constant ratio);
  f_ext = (r21^p f1 - f2)/(r21^p - 1)                                       (eq. 6);
  e_a = |(f1 - f2)/f1|,  e_ext = |(f_ext - f1)/f_ext|,
  GCI_fine = 1.25 e_a/(r21^p - 1)                                           (eq. 7-9).
The convergence ratio R = e21/e32 classifies the triple: 0 < R < 1 monotone, R < 0
oscillatory (Celik's "oscillatory convergence" when s < 0), R >= 1 divergent. The
asymptotic-range ratio GCI_coarse/(r21^p GCI_fine) is close to 1 in the asymptotic range
(Roache 1998; for a constant ratio it reduces to f1/f2).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import pandas as pd

from harness.measure.norm_table import FIELD_NAMES, error_column
from harness.run.record import RunRecord

SAFETY = 1.25  # Celik et al.'s factor of safety for three grids


@dataclass(frozen=True)
class ThreeGrid:
    f1: float
    f2: float
    f3: float
    r21: float
    r32: float
    p: float
    f_ext: float
    e_a: float
    e_ext: float
    gci_fine: float           # relative to f1, as Celik et al. report it
    gci_fine_abs: float       # the same band in f's own units (meaningful when f -> 0)
    gci_coarse: float
    asymptotic_ratio: float
    convergence_ratio: float  # R = e21/e32
    behaviour: str            # monotone | oscillatory | divergent | converged (e21 = e32 = 0)

    def row(self) -> dict[str, float | str]:
        return asdict(self)


def observed_order(r21: float, r32: float, e21: float, e32: float, iterations: int = 100) -> float:
    """Celik et al. eqs. 3-5 by fixed-point iteration; NaN when a difference is zero."""
    if e21 == 0 or e32 == 0:
        return math.nan
    s = math.copysign(1.0, e32 / e21)
    ratio = abs(e32 / e21)
    p = abs(math.log(ratio)) / math.log(r21)
    if r21 == r32:
        return p  # q(p) = 0
    for _ in range(iterations):
        try:
            q = math.log((r21**p - s) / (r32**p - s))
        except (ValueError, ZeroDivisionError):
            return math.nan
        new = abs(math.log(ratio) + q) / math.log(r21)
        if abs(new - p) < 1e-14 * max(1.0, p):
            return new
        p = new
    return p


def three_grid(h: tuple[float, float, float], f: tuple[float, float, float]) -> ThreeGrid:
    """h and f ordered finest first (h1 < h2 < h3)."""
    (h1, h2, h3), (f1, f2, f3) = h, f
    if not h1 < h2 < h3:
        raise ValueError(f"grid sizes must grow from fine to coarse, got {h}")
    r21, r32 = h2 / h1, h3 / h2
    e21, e32 = f2 - f1, f3 - f2
    p = observed_order(r21, r32, e21, e32)
    if e21 == 0 and e32 == 0:
        behaviour, ratio = "converged", math.nan
    elif e32 == 0:
        behaviour, ratio = "divergent", math.inf
    else:
        ratio = e21 / e32
        behaviour = "monotone" if 0 <= ratio < 1 else ("oscillatory" if ratio < 0 else "divergent")
    grow = r21**p - 1 if math.isfinite(p) else math.nan
    f_ext = (r21**p * f1 - f2) / grow if grow else math.nan
    e_a = relative(f1 - f2, f1)
    e_ext = relative(f_ext - f1, f_ext)
    gci_fine = SAFETY * e_a / grow if grow else math.nan
    gci_coarse = SAFETY * relative(f2 - f3, f2) / (r32**p - 1) if grow else math.nan
    return ThreeGrid(
        f1=f1, f2=f2, f3=f3, r21=r21, r32=r32, p=p, f_ext=f_ext, e_a=e_a, e_ext=e_ext,
        gci_fine=gci_fine, gci_fine_abs=SAFETY * abs(e21) / grow if grow else math.nan,
        gci_coarse=gci_coarse,
        asymptotic_ratio=gci_coarse / (r21**p * gci_fine) if gci_fine else math.nan,
        convergence_ratio=ratio, behaviour=behaviour,
    )


def relative(difference: float, value: float) -> float:
    return abs(difference / value) if value else math.nan


# Scalar outputs of run.json whose three-grid behaviour the GCI table reports beside the errors.
GCI_OUTPUTS = ("contact_force", "max_abs_u", "max_theta", "heat_in_contact", "active_measure")


def gci_table(errors: pd.DataFrame, records: dict[int, RunRecord]) -> pd.DataFrame:
    """Every consecutive triple of levels, for each field's error norm (`errors`: a study's
    table, n and err_<field>, blank at the reference) and each scalar output of the runs'
    run.json (`records`, by level)."""
    series: dict[str, dict[int, float]] = {}
    for column in (error_column(f) for f in FIELD_NAMES if error_column(f) in errors.columns):
        graded = errors[errors[column].notna()]
        series[column] = dict(zip(graded["n"].astype(int), graded[column].astype(float)))
    for name in GCI_OUTPUTS:
        values = {n: getattr(record, name) for n, record in records.items()}
        if values and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values.values()):
            series[name] = {n: float(v) for n, v in values.items()}
    rows = []
    for quantity, values in series.items():
        levels = sorted(values)
        for coarse, middle, fine in zip(levels, levels[1:], levels[2:]):
            result = three_grid((1 / fine, 1 / middle, 1 / coarse), (values[fine], values[middle], values[coarse]))
            rows.append({"quantity": quantity, "n_fine": fine, "n_medium": middle, "n_coarse": coarse,
                         **result.row()})
    return pd.DataFrame(rows)


def finest_triples(table: pd.DataFrame) -> pd.DataFrame:
    return table.loc[table.groupby("quantity", sort=False)["n_fine"].idxmax()].reset_index(drop=True)
