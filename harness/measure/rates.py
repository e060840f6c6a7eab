"""Convergence rates from errors E(h): least-squares slopes and pairwise orders; power laws
y = C x^p fitted in log-log (the cost study's error, time and memory laws)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np


def fitted_slope(h: Sequence[float], errors: Sequence[float]) -> float:
    """Slope p of the least-squares line log E = p log h + c; NaN when fewer than two
    points or any error is not positive (a zero error has no logarithm)."""
    h_arr, e_arr = np.asarray(h, dtype=float), np.asarray(errors, dtype=float)
    if len(h_arr) < 2 or not np.all(e_arr > 0) or not np.all(np.isfinite(e_arr)):
        return math.nan
    slope, _ = np.polyfit(np.log(h_arr), np.log(e_arr), 1)
    return float(slope)


def pairwise_orders(h: Sequence[float], errors: Sequence[float]) -> list[float]:
    """Order between each level and the previous (coarser) one: log(E_prev/E)/log(h_prev/h),
    which is log2(E_2h/E_h) for halving h. The first level has none (NaN)."""
    orders = [math.nan]
    pairs = list(zip(h, errors))
    for (h0, e0), (h1, e1) in zip(pairs, pairs[1:]):
        ok = e0 > 0 and e1 > 0 and h0 != h1
        orders.append(math.log(e0 / e1) / math.log(h0 / h1) if ok else math.nan)
    return orders


@dataclass(frozen=True)
class SlopeFit:
    """log E = slope log h + intercept, by least squares, with the slope's standard error
    sqrt(s^2 / Sxx), s^2 = residual sum of squares / (points - 2) (NaN from two points)."""

    slope: float
    stderr: float
    intercept: float
    points: int

    def level(self, h: float) -> float:
        """The fitted error at h: the error constant, read where the data are."""
        return math.exp(self.intercept + self.slope * math.log(h))


def slope_fit(h: Sequence[float], errors: Sequence[float]) -> SlopeFit:
    h_arr, e_arr = np.asarray(h, dtype=float), np.asarray(errors, dtype=float)
    if len(h_arr) < 2 or not np.all(e_arr > 0) or not np.all(np.isfinite(e_arr)):
        return SlopeFit(math.nan, math.nan, math.nan, len(h_arr))
    x, y = np.log(h_arr), np.log(e_arr)
    slope, intercept = np.polyfit(x, y, 1)
    dof = len(x) - 2
    sxx = float(np.sum((x - x.mean()) ** 2))
    residual = float(np.sum((y - (slope * x + intercept)) ** 2))
    stderr = math.sqrt(residual / dof / sxx) if dof > 0 else math.nan
    return SlopeFit(float(slope), stderr, float(intercept), len(x))


@dataclass(frozen=True)
class PowerLaw:
    """y = coefficient * x^exponent, fitted in log-log by least squares."""

    coefficient: float
    exponent: float
    points: int

    def __call__(self, x: float) -> float:
        return self.coefficient * x**self.exponent

    def solve(self, y: float) -> float:
        """The x where the law reaches y."""
        return (y / self.coefficient) ** (1.0 / self.exponent)

    @property
    def valid(self) -> bool:
        return math.isfinite(self.coefficient) and math.isfinite(self.exponent) and self.exponent != 0


def power_fit(x: Sequence[float], y: Sequence[float]) -> PowerLaw:
    """log y = log C + p log x over the points with positive finite y (NaN law if < 2)."""
    xs, ys = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    keep = np.isfinite(ys) & (ys > 0) & np.isfinite(xs) & (xs > 0)
    if keep.sum() < 2:
        return PowerLaw(math.nan, math.nan, int(keep.sum()))
    fit = slope_fit(xs[keep], ys[keep])
    return PowerLaw(math.exp(fit.intercept), fit.slope, fit.points)


def scaling_exponents(scaling: Any, min_n: int = 32) -> dict[str, float]:
    """T ~ dofs^a and M ~ dofs^b over the levels n >= min_n."""
    if scaling.empty:
        return {}
    big = scaling[scaling["n"] >= min_n]
    return {
        "time_vs_dofs": power_fit(big["dofs"], big["wall_s"]).exponent,
        "memory_vs_dofs": power_fit(big["dofs"], big["peak_rss_mb"]).exponent,
        "from_n": min_n,
    }
