"""The three-grid procedure of Celik et al. (2008) on sequences whose answer is known, and
the table the harness writes from a study."""

from __future__ import annotations

import math

import pandas as pd
import pytest

from harness.measure.gci import SAFETY, observed_order, three_grid
from harness.run.record import RunRecord
from harness.measure.gci import finest_triples, gci_table


def power_law(f0: float, c: float, p: float, h: tuple[float, ...]) -> tuple[float, ...]:
    return tuple(f0 + c * x**p for x in h)


@pytest.mark.parametrize("p, c", [(1.0, 3.0), (2.0, -0.5), (1.37, 1e-6), (0.8, 40.0)])
def test_an_exact_power_law_gives_its_order_and_limit_back(p, c):
    h = (1 / 32, 1 / 16, 1 / 8)
    f0 = 7.0 * abs(c)  # a limit of the size of the changes, so differences keep their digits
    result = three_grid(h, power_law(f0, c, p, h))
    # Only round-off of logs and differences remains: 1e-10 is ~1e6 ulp.
    assert result.p == pytest.approx(p, abs=1e-10)
    assert result.f_ext == pytest.approx(f0, rel=1e-12)
    assert result.behaviour == "monotone"
    # Celik's GCI_fine = 1.25 |f1 - f2| / (|f1| (r^p - 1)): for the exact law |f1 - f_ext| * 1.25.
    assert result.gci_fine_abs == pytest.approx(SAFETY * abs(c) * h[0] ** p, rel=1e-9)
    assert result.gci_fine == pytest.approx(result.gci_fine_abs / abs(result.f1), rel=1e-12)


def test_a_non_constant_refinement_ratio_is_solved_by_the_fixed_point():
    """h = 0.1, 0.15, 0.3 (r21 = 1.5, r32 = 2): q(p) != 0, the iteration must still find p."""
    h = (0.1, 0.15, 0.3)
    result = three_grid(h, power_law(-2.0, 5.0, 1.6, h))
    assert result.r21 == pytest.approx(1.5) and result.r32 == pytest.approx(2.0)
    assert result.p == pytest.approx(1.6, abs=1e-10)
    assert result.f_ext == pytest.approx(-2.0, rel=1e-10)


def test_celik_table_1_example_is_reproduced():
    """Celik et al. (2008) Table 1, phi = dimensionless reattachment length: N = 18000, 8000,
    4500 cells (2D, r21 = 1.5, r32 = 1.333), phi = 6.063, 5.972, 5.863; the paper reports
    p = 1.53, phi_ext = 6.1685, e_a = 1.5 %, e_ext = 1.7 %, GCI_fine = 2.2 %."""
    h = tuple(1 / math.sqrt(n) for n in (18000, 8000, 4500))
    result = three_grid(h, (6.063, 5.972, 5.863))
    assert result.p == pytest.approx(1.53, abs=0.01)  # the paper rounds to 3 digits
    assert result.f_ext == pytest.approx(6.1685, abs=1e-3)
    assert result.e_a == pytest.approx(0.015, abs=1e-3)
    assert result.e_ext == pytest.approx(0.017, abs=1e-3)
    assert result.gci_fine == pytest.approx(0.022, abs=1e-3)


def test_an_oscillating_sequence_is_classified_as_such():
    h = (1 / 32, 1 / 16, 1 / 8)
    result = three_grid(h, (1.0 + 0.01, 1.0 - 0.04, 1.0 + 0.16))  # signs alternate, |R| = 1/4
    assert result.behaviour == "oscillatory" and result.convergence_ratio == pytest.approx(-0.25)
    assert result.p == pytest.approx(2.0, abs=1e-10)  # |e32/e21| = 4 = 2^2


def test_a_diverging_sequence_is_classified_as_such():
    result = three_grid((1 / 32, 1 / 16, 1 / 8), (1.0, 1.5, 1.75))  # differences grow as h shrinks
    assert result.behaviour == "divergent" and result.convergence_ratio == pytest.approx(2.0)


def test_an_unchanging_value_has_no_order():
    result = three_grid((1 / 32, 1 / 16, 1 / 8), (2.0, 2.0, 2.0))
    assert result.behaviour == "converged" and math.isnan(result.p)
    assert math.isnan(observed_order(2.0, 2.0, 0.0, 1.0))


def test_in_the_asymptotic_range_the_ratio_is_about_one():
    """Roache's check GCI_coarse / (r^p GCI_fine) = f1/f2 for a constant ratio: ~1 when
    the values have converged to a nonzero limit."""
    h = (1 / 64, 1 / 32, 1 / 16)
    result = three_grid(h, power_law(10.0, 1.0, 1.0, h))
    assert result.asymptotic_ratio == pytest.approx(result.f1 / result.f2, rel=1e-12)
    assert abs(result.asymptotic_ratio - 1) < 2e-3


def test_the_table_has_every_triple_of_every_quantity():
    levels = [2, 4, 8, 16]
    errors = pd.DataFrame({"n": levels, "err_u": [4.0, 2.0, 1.0, math.nan], "err_total": [1, 1, 1, math.nan]})
    records = {n: RunRecord(contact_force=5.0 + 1.0 / n**2, max_theta="n/a") for n in levels}
    table = gci_table(errors, records)
    assert set(table["quantity"]) == {"err_u", "contact_force"}  # a non-number output is skipped
    assert table[table["quantity"] == "err_u"]["n_fine"].tolist() == [8]
    assert table[table["quantity"] == "contact_force"]["n_fine"].tolist() == [8, 16]
    finest = finest_triples(table).set_index("quantity")
    assert finest.loc["contact_force", "p"] == pytest.approx(2.0, abs=1e-9)
    assert finest.loc["contact_force", "f_ext"] == pytest.approx(5.0, rel=1e-12)
    assert finest.loc["err_u", "p"] == pytest.approx(1.0, abs=1e-12)
    assert finest.loc["err_u", "f_ext"] == pytest.approx(0.0, abs=1e-12)
