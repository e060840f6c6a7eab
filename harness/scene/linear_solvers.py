"""The linear solvers a scene may name (`run.linear_solver`), one entry each: the FreeFEM
lines that select it in main.edp, how its memory grows (the guard's model), what it adds
to a run's key and options, and what it cannot do. Nothing else in the harness tests a
solver's name: adding a solver is one entry here (and its line in docs/solvers.md).

A FreeFEM plugin that redefines `sparsesolver` (MUMPS_seq, UMFPACK64, SuperLu) is a
solver with `plugin` set. PETSc is the project's own plugin (harness/run/petsc_plugin.py,
built on first use), which reads its options from `run.petsc_options`.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from harness.scene.petsc_options import default_options, factorising, multigrid


class Memory(enum.Enum):
    """How a solve's peak memory grows with its unknowns (harness/core/guards.py's constants)."""

    FACTOR = "factor"          # a sparse LU's fill
    ITERATIVE = "iterative"    # Krylov with AMG or a field split: the matrix a few times
    MULTIGRID = "multigrid"    # Krylov with geometric multigrid over nested meshes


@dataclass(frozen=True)
class LinearSolver:
    name: str           # run.linear_solver
    reported: str       # the name run.json's linear_solver begins with (freefem linearSolverName)
    plugin: str = ""    # the FreeFEM plugin whose load makes it `sparsesolver`; "": none
    # The project's PETSc plugin (harness/run/petsc_plugin.py): the run loads it by path.
    builds_plugin: bool = False
    # The run.* key holding the solver's own options, passed to FreeFEM as -run.<key> and
    # keyed with the run ("" : it has none).
    options_key: str = ""
    # The options when that key is blank, by dimension, Newton fields and ranks (measured defaults).
    default_options: Callable[[int, tuple[str, ...], int], str] | None = None
    # Solves on MPI ranks: a factorisation per subdomain under the script's Schwarz preconditioner
    # (freefem/ranks.idp, parallel_newton.idp), or PETSc across the ranks (freefem/petsc_ranks.idp).
    on_ranks: bool = True
    # A floating electrode's exact elimination is written for FreeFEM's own matrices.
    floating: bool = True

    def macros(self, plugin_path: Path | None = None, ranks: bool = False) -> list[str]:
        """main.edp's lines that select this solver (freefem/effects.idp defaults to UMFPACK);
        `ranks`: for the N-rank backend (freefem/ranks.idp)."""
        if self.builds_plugin:
            if plugin_path is None:
                raise ValueError(f"linear_solver {self.name!r} needs the built plugin's path")
            if ranks:
                # PETSc across the ranks (freefem/petsc_ranks.idp): each rank's bulk matrix goes to the
                # plugin as on one rank (freefem/bulk.idp), which adds it into the distributed one.
                return [f'load "{plugin_path.with_suffix("")}"', "macro PETSCSOLVER 1 //", "macro PETSCRANKS 1 //",
                        "macro LINEARSOLVER UMFPACK //", f'string linearSolverName = "{self.reported}";']
            # The Newton system goes to PETSc (freefem/petsc_linear_solver.idp); the few direct
            # solves left (a staggered theta, the pressed start) to FreeFEM's UMFPACK: a MUMPS
            # plugin would bring a second MUMPS library into the process beside PETSc's.
            return [f'load "{plugin_path.with_suffix("")}"', "macro PETSCSOLVER 1 //",
                    "macro LINEARSOLVER UMFPACK //", f'string linearSolverName = "{self.reported}";']
        if self.plugin:
            # Loading the plugin makes it FreeFEM's `sparsesolver`.
            return [f'load "{self.plugin}"', "macro LINEARSOLVER sparsesolver //",
                    f'string linearSolverName = "{self.reported}";']
        return []

    def memory(self, options: str) -> Memory:
        """The memory model of a solve with these options (the solver's own, or ignored)."""
        if not self.options_key or factorising(options):
            return Memory.FACTOR
        return Memory.MULTIGRID if multigrid(options) else Memory.ITERATIVE

    def wants_coarser_meshes(self, options: str) -> bool:
        """Whether the options ask for a geometric multigrid's coarser meshes."""
        return bool(self.options_key) and multigrid(options)

    def keyed(self, options: str) -> dict[str, str]:
        """What the solver adds to a run's scene inputs (its cache key)."""
        return {self.options_key: options} if self.options_key else {}

    def freefem_options(self, options: str) -> list[str]:
        return [f"-run.{self.options_key}", options] if self.options_key else []


# Sparse direct solvers FreeFEM offers on Debian, and PETSc through the project's plugin.
SOLVERS: dict[str, LinearSolver] = {s.name: s for s in (
    LinearSolver("mumps", "MUMPS_seq", plugin="MUMPS_seq"),
    LinearSolver("umfpack", "UMFPACK"),
    LinearSolver("umfpack64", "UMFPACK64", plugin="UMFPACK64"),
    LinearSolver("petsc", "PETSc", builds_plugin=True, options_key="petsc_options", default_options=default_options,
                 floating=False),
)}


def solver(name: str) -> LinearSolver:
    return SOLVERS[name]


def accepting(ability: str) -> str:
    """The solvers with `ability` ("on_ranks", "floating"), for an error line."""
    return ", ".join(name for name, s in SOLVERS.items() if getattr(s, ability))
