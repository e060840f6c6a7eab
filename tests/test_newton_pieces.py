"""The Newton method's pieces are called, not just included: the linear solver
(linear_solver.idp), the line search (line_search.idp) and the stop rule (newton_stop.idp)
drive a Newton method for a small system with a known root, outside the scheme."""

from __future__ import annotations

import subprocess
from pathlib import Path

from harness.core import freefem
from harness.core.layout import REPO

FREEFEM = REPO / "freefem"

# R(x) = K x + x^3 - b on 5 unknowns, K tridiagonal (2, -1), b chosen so that x* = (1..5)/5;
# the tangent is K + T(x), T = diag(3 x^2). From x = 0 the full step overshoots (the
# simplified Newton correction there is larger than the step), so the line search must
# damp at least once.
TOY = """
macro LINEARSOLVER UMFPACK //
real tSolve = 0, tFactor = 0, tFirstFactor = -1;
int n = 5, maxIt = 30;
real[int, int] Kd(n, n); Kd = 0;
for (int i = 0; i < n; ++i) { Kd(i, i) = 2; if (i > 0) Kd(i, i - 1) = -1; if (i < n - 1) Kd(i, i + 1) = -1; }
matrix K = Kd;
real[int] xStar(n); for (int i = 0; i < n; ++i) xStar[i] = 20. * (i + 1) / n;
real[int] b = K * xStar; { real[int] c = xStar .* xStar; c = c .* xStar; b += c; }
include "{dir}/linear_solver.idp"
macro residual(xs, r) { r = K * xs; real[int] c = xs .* xs; c = c .* xs; r += c; r -= b; } //
include "{dir}/line_search.idp"
real[int] histAlpha(maxIt + 1), histIncU(maxIt + 1), histErrU(maxIt + 1);
int[int] histConsistent(maxIt + 1), histChanges(maxIt + 1);
histAlpha = 0; histIncU = 0; histErrU = 0; histConsistent = 1; histChanges = 0;
macro newtonFields(DO) DO(U, u, x, Xh, 1, 1, "u") //
include "{dir}/newton_stop.idp"
real[int] x(n), r(n); x = 0; residual(x, r)
real merit = r.l2, meritFloor = 1e-13 * merit;
int damped = 0, iter;
bool stop = false;
for (iter = 1; iter <= maxIt && !stop; ++iter) {
  real[int] Td(n); Td = x .* x; Td *= 3;
  real[int, int] Tdd(n, n); Tdd = 0; for (int i = 0; i < n; ++i) Tdd(i, i) = Td[i];
  T = Tdd;
  real[int] dx(n); int its;
  linearSolve(r, dx, its)
  dx = -dx;
  real[int] x0 = x, rNew(n); real alpha, meritNew; bool passed;
  lineSearch(x0, dx, merit, meritFloor, x, rNew, meritNew, alpha, passed)
  r = rNew; merit = meritNew; damped += (alpha < 1);
  histAlpha[iter] = alpha; histIncU[iter] = dx.linfty / max(x.linfty, 1e-14);
  newtonStop(iter, alpha, true, 0, 1e-12, stop)
}
real[int] err = x - xStar;
cout << "RESULT " << iter - 1 << " " << damped << " " << err.linfty << " " << merit << endl;
"""


def test_the_pieces_solve_a_nonlinear_system(tmp_path: Path):
    script = tmp_path / "toy.edp"
    script.write_text(TOY.replace("{dir}", str(FREEFEM)))
    out = subprocess.run(freefem.command(script, []), cwd=tmp_path, env=freefem.environment(),
                         capture_output=True, text=True, timeout=60)
    line = next((l for l in out.stdout.splitlines() if l.startswith("RESULT")), None)
    assert line is not None, out.stdout[-2000:]
    iterations, damped, error, merit = line.split()[1:]
    assert 3 <= int(iterations) <= 20 and int(damped) >= 1
    assert float(error) < 1e-10 and float(merit) < 1e-8


# A linear system whose round-off floor lies above the stop's rtol: the Hilbert matrix of
# order 7 (condition 4.8e8), so a residual at round-off gives increments of ~1e-8 relative,
# far above rtol = 1e-14 and below the round-off stop's 1e-6. After a first step that
# changes the contact state (no contraction estimate from it) the increment test alone runs
# to maxIt; the round-off stop ends it once a full step no longer lowers ||R|| (measured: at
# step 3, with ||R|| 6.3e-16 -> 1.1e-15 and an increment of 1.3e-8).
ILL = """
macro LINEARSOLVER UMFPACK //
real tSolve = 0, tFactor = 0, tFirstFactor = -1;
int n = 7, maxIt = 30;
real[int, int] Hd(n, n);
for (int i = 0; i < n; ++i) for (int j = 0; j < n; ++j) Hd(i, j) = 1. / (i + j + 1);
matrix K = Hd;
real[int] xStar(n); for (int i = 0; i < n; ++i) xStar[i] = 1 + i;
real[int] b = K * xStar;
include "{dir}/linear_solver.idp"
macro residual(xs, r) { r = K * xs; r -= b; } //
include "{dir}/line_search.idp"
real[int] histAlpha(maxIt + 1), histIncU(maxIt + 1), histErrU(maxIt + 1);
int[int] histConsistent(maxIt + 1), histChanges(maxIt + 1);
histAlpha = 0; histIncU = 0; histErrU = 0; histConsistent = 1; histChanges = 0;
histChanges[1] = 1;   // the first step changes the contact state, as the bimorph's does
macro newtonFields(DO) DO(U, u, x, Xh, 1, 1, "u") //
include "{dir}/newton_stop.idp"
real[int, int] Td(n, n); Td = 0; T = Td;
real[int] x(n), r(n); x = 0; residual(x, r)
real merit = r.l2, meritBefore = merit;
int iter, byRoundoff = 0;
bool stop = false;
for (iter = 1; iter <= maxIt && !stop; ++iter) {
  real[int] dx(n); int its;
  linearSolve(r, dx, its)
  dx = -dx;
  x += dx; residual(x, r);
  meritBefore = merit; merit = r.l2;
  histAlpha[iter] = 1; histIncU[iter] = dx.linfty / max(x.linfty, 1e-14);
  newtonStop(iter, 1., true, 0, 1e-14, stop)
  if (!stop && USEFLOOR) { roundoffStop(iter, 1., true, 0, merit, meritBefore, stop) byRoundoff = stop; }
}
real[int] err = x - xStar;
cout << "RESULT " << iter - 1 << " " << byRoundoff << " " << err.linfty / xStar.linfty << endl;
"""


def run_ill_conditioned(tmp_path: Path, use_floor: bool) -> tuple[int, int, float]:
    script = tmp_path / f"ill{int(use_floor)}.edp"
    script.write_text(ILL.replace("{dir}", str(FREEFEM)).replace("USEFLOOR", "true" if use_floor else "false"))
    out = subprocess.run(freefem.command(script, []), cwd=tmp_path, env=freefem.environment(),
                         capture_output=True, text=True, timeout=60)
    line = next((l for l in out.stdout.splitlines() if l.startswith("RESULT")), None)
    assert line is not None, out.stdout[-2000:]
    iterations, by_roundoff, error = line.split()[1:]
    return int(iterations), int(by_roundoff), float(error)


def test_newton_stops_at_the_residuals_round_off_floor(tmp_path: Path):
    """The stop that ends the free bimorph (PZT-5H on brass) when its rtol is out of the
    arithmetic's reach: without it the increment test can pass only by chance."""
    iterations, by_roundoff, error = run_ill_conditioned(tmp_path, use_floor=True)
    assert by_roundoff == 1 and iterations <= 4
    assert error < 1e-6   # the attainable accuracy: condition 4.8e8 times 1.1e-16 and some
    iterations, by_roundoff, _ = run_ill_conditioned(tmp_path, use_floor=False)
    assert iterations == 30 and by_roundoff == 0
