"""The peer's Newton method (docs/model.md section 4): exact tangent, damping by Deuflhard's
natural monotonicity test, the per-field stopping rule, one restart from the pressed state.

All on the dimensionless unknowns of terms.py. Dirichlet dofs are removed from the system:
they keep their start value (0) and are never updated. A floating electrode's phi dofs are
one unknown (Unknowns.floating): the system is P^T R = q, P^T J P, with P the prolongation
that copies the electrode's first dof to the others (docs/model.md, "Floating electrodes").
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy.sparse import csc_matrix, csr_matrix
from scipy.sparse.linalg import splu

HALVINGS = 6  # the step length is halved at most 6 times
STALLED = 5  # steps in a row that pass no trial: no progress


@dataclass
class Unknowns:
    """The model's variables and, per field, its dof range and constrained dofs; `given`, per
    field, the constrained dofs whose value is not 0 and that value (scaled): an electrode's."""

    md: object
    fields: list[str]
    dirichlet: dict[str, np.ndarray]
    given: dict[str, tuple[np.ndarray, float]] = field(default_factory=dict)
    # phi's dofs of each floating electrode and its net free charge over phi's equation scale:
    # the electrode's equation is the sum of its dofs' residuals, R_phi(1 on the electrode) = Q.
    floating: list[tuple[np.ndarray, float]] = field(default_factory=list)

    def ranges(self) -> dict[str, np.ndarray]:
        out = {}
        for name in self.fields:
            start, size = self.md.interval_of_variable(name)
            out[name] = np.arange(start, start + size)
        return out

    def electrodes(self) -> list[tuple[np.ndarray, float]]:
        """Each floating electrode's global dofs (the first its master) and scaled charge."""
        phi = self.ranges().get("phi")
        return [] if phi is None else [(phi[dofs], charge) for dofs, charge in self.floating]

    def free(self) -> np.ndarray:
        """The dofs of the reduced system: neither constrained nor an electrode's non-master."""
        mask = np.ones(self.md.nbdof(), dtype=bool)
        for name, r in self.ranges().items():
            mask[r[self.dirichlet[name]]] = False
        for dofs, _ in self.electrodes():
            if not mask[dofs].all():
                raise ValueError("a floating electrode shares a node with a part of fixed potential")
            mask[dofs[1:]] = False
        return np.flatnonzero(mask)

    def reduction(self) -> Reduction:
        free = self.free()
        if not self.floating:
            return Reduction(free)
        column = np.full(self.md.nbdof(), -1)
        column[free] = np.arange(len(free))
        charges = np.zeros(len(free))
        for dofs, charge in self.electrodes():
            column[dofs] = column[dofs[0]]
            charges[column[dofs[0]]] = charge
        rows = np.flatnonzero(column >= 0)
        prolong = csr_matrix((np.ones(len(rows)), (rows, column[rows])), shape=(self.md.nbdof(), len(free)))
        return Reduction(free, prolong, charges)

    def impose(self, x: np.ndarray) -> None:
        """x with the Dirichlet values at the constrained dofs (Newton's increments keep them),
        and each floating electrode at one potential, its master's."""
        for name, r in self.ranges().items():
            x[r[self.dirichlet[name]]] = 0.0
            if name in self.given:
                dofs, value = self.given[name]
                x[r[dofs]] = value
        for dofs, _ in self.electrodes():
            x[dofs] = x[dofs[0]]

    def get(self) -> np.ndarray:
        return np.concatenate([np.asarray(self.md.variable(n), dtype=float) for n in self.fields])

    def set(self, x: np.ndarray) -> None:
        for name, r in self.ranges().items():
            self.md.set_variable(name, x[r])


@dataclass(frozen=True)
class Reduction:
    """From the model's dofs to the reduced system's and back: the free dofs alone, or with
    floating electrodes the prolongation P (model = P reduced) and the electrodes' charges."""

    free: np.ndarray
    prolong: csr_matrix | None = None
    charges: np.ndarray | None = None

    def residual(self, r: np.ndarray) -> np.ndarray:
        return r[self.free] if self.prolong is None else self.prolong.T @ r - self.charges

    def tangent(self, jac: csc_matrix) -> csc_matrix:
        if self.prolong is None:
            return jac[self.free][:, self.free].tocsc()
        return (self.prolong.T @ jac @ self.prolong).tocsc()

    def expand(self, dy: np.ndarray, size: int) -> np.ndarray:
        if self.prolong is None:
            out = np.zeros(size)
            out[self.free] = dy
            return out
        return self.prolong @ dy


@dataclass
class NewtonResult:
    converged: bool = False
    reason: str = ""
    iterations: int = 0
    restarted_at: int = 0
    increments: dict[str, list[float]] = field(default_factory=dict)
    damping: list[float] = field(default_factory=list)
    changes: list[int] = field(default_factory=list)
    assembly_s: float = 0.0
    factorisation_s: float = 0.0
    solve_s: float = 0.0
    newton_s: float = 0.0


def system(md, free: Reduction, result: NewtonResult, tangent: bool = True):  # noqa: ANN001, ANN201
    """The residual R (and the tangent J) of the reduced system."""
    clock = time.perf_counter()
    md.assembly("build_all" if tangent else "build_rhs")
    residual = free.residual(-np.asarray(md.rhs(), dtype=float))  # GetFEM's rhs is -R
    jac = None
    if tangent:
        k = md.tangent_matrix()
        indptr, indices = k.csc_ind()
        jac = free.tangent(csc_matrix((k.csc_val(), indices, indptr), shape=k.size()))
    result.assembly_s += time.perf_counter() - clock
    return residual, jac


def newton(md, unknowns: Unknowns, start: dict[str, np.ndarray] | None, settings: dict,  # noqa: ANN001
           contact_state: Callable[[], np.ndarray], pressed: Callable[[], dict[str, np.ndarray]]) -> NewtonResult:
    """Solve R(x) = 0 from `start` (None: zero). Stop when the last step was a full Newton
    step with no contact state change and every field's error estimate is below rtol
    (newton.rtol): its largest increment relative to the field's largest value (floor 1e-14,
    round-off), or after two full steps in a row with ratio q < 1/2 of the increments,
    the contraction estimate q/(1 - q) times the increment (Deuflhard 2004, sec. 2.1).
    From zero, when Newton makes no progress (the contact state returns to an earlier one,
    5 steps in a row pass no damping trial, or a step is still damped after half of
    max_iterations), restart once from the pressed state."""
    clock = time.perf_counter()
    rtol, max_it = float(settings["rtol"]), int(settings["max_iterations"])
    result = NewtonResult(increments={f: [] for f in unknowns.fields})
    ranges, free = unknowns.ranges(), unknowns.reduction()
    x = np.zeros(md.nbdof()) if start is None else place(start, ranges, md.nbdof())
    unknowns.impose(x)
    unknowns.set(x)
    state, stalled, history, full = contact_state(), 0, [], []
    seen = [state.tobytes()]
    restartable = start is None
    for it in range(1, max_it + 1):
        r, jac = system(md, free, result)
        tick = time.perf_counter()
        lu = splu(jac)  # SuperLU with COLAMD: 2D n = 64 in 70 s; MMD_AT_PLUS_A had not finished after 14 min
        result.factorisation_s += time.perf_counter() - tick
        dy = -solve(lu, r, result)
        dx = free.expand(dy, len(x))
        alpha, passed = damped(md, unknowns, x, dx, dy, free, lu, result)
        x = x + alpha * dx
        unknowns.set(x)
        new_state = contact_state()
        changes = int(np.count_nonzero(new_state != state))
        state = new_state
        result.damping.append(alpha)
        result.changes.append(changes)
        result.iterations = it
        stalled = 0 if passed else stalled + 1
        incs = {f: float(np.abs(alpha * dx[rg]).max(initial=0.0) / max(np.abs(x[rg]).max(initial=0.0), 1e-14))
                for f, rg in ranges.items()}
        for f, v in incs.items():
            result.increments[f].append(v)
        history.append(incs)
        full.append(alpha == 1.0 and changes == 0)
        if not np.isfinite(x).all():
            result.reason = "nan"
            break
        if full[-1] and all(error(history, full, f) <= rtol for f in ranges):
            result.converged, result.reason = True, "converged"
            break
        seen.append(state.tobytes())
        cycling = changes > 0 and seen[-1] in seen[:-2]  # back to an earlier contact state
        if restartable and (cycling or stalled >= STALLED or (it >= max_it // 2 and alpha < 1.0)):
            restartable = False
            result.restarted_at = it
            x = place(pressed(), ranges, md.nbdof())
            unknowns.impose(x)
            unknowns.set(x)
            state, stalled, history, full = contact_state(), 0, [], []
            seen = [state.tobytes()]
    else:
        result.reason = "max_iterations"
    result.newton_s = time.perf_counter() - clock
    return result


def error(history: list[dict[str, float]], full: list[bool], f: str) -> float:
    inc = history[-1][f]
    if len(history) >= 3 and full[-1] and full[-2]:
        ratio = inc / max(history[-2][f], 1e-300)
        if ratio < 0.5:
            return min(inc, inc * ratio / (1 - ratio))
    return inc


def place(values: dict[str, np.ndarray], ranges: dict[str, np.ndarray], size: int) -> np.ndarray:
    x = np.zeros(size)
    for name, rg in ranges.items():
        if name in values:
            x[rg] = values[name]
    return x


def solve(lu, rhs: np.ndarray, result: NewtonResult) -> np.ndarray:  # noqa: ANN001
    tick = time.perf_counter()
    out = lu.solve(rhs)
    result.solve_s += time.perf_counter() - tick
    return out


def damped(md, unknowns: Unknowns, x: np.ndarray, dx: np.ndarray, dy: np.ndarray, free: Reduction, lu,  # noqa: ANN001
           result: NewtonResult):  # noqa: ANN201
    """Deuflhard's natural monotonicity test: the largest alpha = 1, 1/2, ... 1/64 with
    ||J^-1 R(x + alpha dx)|| <= (1 - alpha/4) ||dy|| (the simplified Newton step, with the
    same factorisation; dy the reduced step). None passes: the smallest step, and the step
    counts as stalled."""
    size = np.linalg.norm(dy)
    if size <= 1e-13 * max(np.linalg.norm(x[free.free]), 1e-300):
        return 1.0, True  # a round-off step: nothing to damp
    alpha = 1.0
    for _ in range(HALVINGS + 1):
        unknowns.set(x + alpha * dx)
        r, _ = system(md, free, result, tangent=False)
        if np.linalg.norm(solve(lu, r, result)) <= (1.0 - alpha / 4.0) * size:
            return alpha, True
        alpha /= 2.0
    return alpha * 2.0, False
