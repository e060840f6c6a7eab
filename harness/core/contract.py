"""The one table of what crosses the Python/FreeFEM boundary as integers: boundary labels,
FreeFEM's exit codes (and the failure each means), and the harness's own exit codes.

`freefem/contract.idp` is generated from it (`python -m harness.core.contract`); a test checks
the committed file is current, so the two languages cannot drift apart.
"""

from __future__ import annotations

import enum
import sys
from pathlib import Path

# Boundary roles -> the integer tag gmsh writes and FreeFEM reads (physical curves/surfaces).
ROLE_LABELS: dict[str, int] = {"clamped": 1, "loaded": 2, "free": 3, "contact": 4,
                               "roller_x": 5, "roller_y": 6, "roller_z": 7, "electrode": 8, "ground": 9,
                               "floating": 10, "floating_2": 11, "floating_3": 12}
# The physical tag of a body's cells when the scene maps no material regions; region i of
# a gmsh scene is tagged i + 1 instead (harness/scene/regions.py), so the first is this one.
BODY_LABEL = 1
# The FreeFEM name of each label (identifiers cannot contain '_').
ROLE_MACROS: dict[str, str] = {"clamped": "labClamped", "loaded": "labLoaded", "free": "labFree", "contact": "labContact",
                               "roller_x": "labRollerX", "roller_y": "labRollerY", "roller_z": "labRollerZ",
                               "electrode": "labElectrode", "ground": "labGround",
                               "floating": "labFloating", "floating_2": "labFloating2", "floating_3": "labFloating3"}
ROLE_MEANING: dict[str, str] = {
    "clamped": "Gamma_1 = Gamma_a: u = 0, phi = 0, theta = 0",
    "loaded": "Gamma_2 = Gamma_b with traction f2: theta = 0",
    "free": "Gamma_2 = Gamma_b, zero traction: theta = 0",
    "contact": "Gamma_3: contact with the conductive foundation",
    "roller_x": "a side normal to x: u_x = 0, zero tangential traction, natural phi and theta",
    "roller_y": "a side normal to y: u_y = 0, zero tangential traction, natural phi and theta",
    "roller_z": "a side normal to z (3D): u_z = 0, zero tangential traction, natural phi and theta",
    "electrode": "Gamma_2 and Gamma_a at a driven potential: zero traction, phi = loads.electrode_potential, theta = 0",
    "ground": "Gamma_2 and Gamma_a, an earthed electrode: zero traction, phi = 0, theta = 0",
    "floating": "Gamma_2, an open electrode: traction f2 as a loaded part, phi uniform and unknown, net free charge loads.floating_charge, theta = 0",
    "floating_2": "a second floating electrode (its own potential), net free charge loads.floating_charge_2",
    "floating_3": "a third floating electrode (its own potential), net free charge loads.floating_charge_3",
}
# The floating electrodes' roles, one electrode each, in the order run.json reports them
# (freefem/floating.idp); each role's net free charge is the [loads] key FLOATING_CHARGES names.
FLOATING_ROLES = ("floating", "floating_2", "floating_3")
FLOATING_CHARGES = {role: "floating_charge" + role.removeprefix("floating") for role in FLOATING_ROLES}


class ExitCode(enum.IntEnum):
    """Exit codes of `python -m harness ...` (documented in the README)."""

    OK = 0
    VERDICT = 1  # the study ran, but a verdict failed: slope outside the band, a physical check
    INPUT = 2  # bad input: case file, override, command line, material
    RUN = 3  # a FreeFEM run failed: diverged, max iterations, NaN, FreeFEM error, timeout
    ENVIRONMENT = 4  # the machine: permissions, full disk, missing tool, not enough memory
    NO_PEER = 5  # crosscheck: GetFEM (python3-getfem) is not installed
    DISAGREE = 6  # crosscheck: FreeFEM and GetFEM differ by more than 1e-8 relative
    BUSY = 7  # another study is writing the same results directory: nothing was run
    INTERRUPTED = 130  # SIGINT, SIGTERM or SIGHUP


class Failure(enum.Enum):
    """Why a run failed. `.code` is FreeFEM's exit code for it (None: seen by the harness,
    not reported by FreeFEM); `.macro` its FreeFEM name in contract.idp."""

    COMPILE = (1, "FreeFEM compile error")
    LOAD = (2, "FreeFEM load error (a plugin is missing: is libfreefem++ installed?)")
    EXECUTION = (3, "FreeFEM execution error")
    OUT_OF_MEMORY = (4, "FreeFEM out of memory")
    MESH = (5, "FreeFEM mesh error")
    ASSERTION = (6, "FreeFEM assertion failed")
    INTERNAL = (7, "FreeFEM internal error")
    EXECUTION_UNKNOWN = (8, "FreeFEM execution error")  # ErrorExec's UNKNOWN code in FreeFEM 4.9
    DIVERGED = (10, "Newton diverged: no progress (a cycle, or 5 steps without passing the line search), also from the pressed restart")
    NAN = (11, "NaN/Inf in Newton")
    MAX_ITERATIONS = (12, "Newton hit its maximum number of iterations")
    BAD_INITIAL_GUESS = (13, "unknown initial guess")
    INVALID_MATERIAL = (14, "invalid material")
    BAD_DECOMPOSITION = (15, "MPI decomposition rejected")
    BAD_SOLVER_OPTIONS = (16, "PETSc rejected run.petsc_options")
    LINEAR_SOLVER = (17, "the Krylov solver did not converge")
    BAD_ELECTRODES = (18, "an electrode shares a node with a clamped or ground part (two potentials at one point)")
    BAD_FLOATING = (19, "a floating electrode shares a node with a part of fixed potential (clamped, ground, electrode) or with another floating electrode")
    NOT_UNIQUE = (20, "the solution is not unique: a family of states solves the scene")
    TIMEOUT = (None, "timed out")
    KILLED = (None, "killed by a signal")
    NO_OUTPUT = (None, "FreeFEM wrote no readable output")
    NOT_CONVERGED = (None, "not converged")
    OTHER = (None, "FreeFEM failed")

    def __init__(self, code: int | None, text: str) -> None:
        self.code = code
        self.text = text

    @property
    def macro(self) -> str:
        """`MAX_ITERATIONS` -> `exitMaxIterations`."""
        return "exit" + "".join(part.capitalize() for part in self.name.split("_"))

    @property
    def numerical(self) -> bool:
        """A failure of Newton itself (the scheme ran), as opposed to the software around it."""
        return self in (Failure.DIVERGED, Failure.NAN, Failure.MAX_ITERATIONS, Failure.NOT_CONVERGED)

    @property
    def bad_input(self) -> bool:
        """The run failed on what the user wrote (harness exit code INPUT), not in the solve."""
        return self in (Failure.BAD_SOLVER_OPTIONS, Failure.BAD_ELECTRODES, Failure.BAD_FLOATING,
                        Failure.INVALID_MATERIAL)

    @classmethod
    def from_code(cls, code: int) -> Failure:
        return next((f for f in cls if f.code == code), cls.OTHER)


# The codes FreeFEM scripts of this project raise themselves (the others are FreeFEM's own).
SCRIPT_FAILURES = (Failure.DIVERGED, Failure.NAN, Failure.MAX_ITERATIONS, Failure.BAD_INITIAL_GUESS,
                   Failure.INVALID_MATERIAL, Failure.BAD_DECOMPOSITION, Failure.BAD_SOLVER_OPTIONS,
                   Failure.LINEAR_SOLVER, Failure.BAD_ELECTRODES, Failure.BAD_FLOATING, Failure.NOT_UNIQUE,
                   Failure.INTERNAL)  # INTERNAL: the PETSc plugin refusing a bulk block (freefem/bulk.idp)


def contract_idp() -> str:
    lines = ["// GENERATED by `python -m harness.core.contract` from harness/core/contract.py: do not edit.",
             "IFMACRO(!CONTRACTIDP)", "macro CONTRACTIDP 1 //",
             "// Boundary labels (gmsh physical groups written by harness/mesh/mesh.py)."]
    lines += [f"int {ROLE_MACROS[r]} = {label}; // {ROLE_MEANING[r]}" for r, label in ROLE_LABELS.items()]
    lines.append("// Exit codes of the scripts' own failures (harness/core/contract.py Failure).")
    lines += [f"int {f.macro} = {f.code}; // {f.text}" for f in SCRIPT_FAILURES]
    lines.append("ENDIFMACRO")
    return "\n".join(lines) + "\n"


def contract_path() -> Path:
    # (layout.FREEFEM's folder, named here again: layout imports errors, which imports this module)
    return Path(__file__).resolve().parents[2] / "freefem" / "contract.idp"


if __name__ == "__main__":
    contract_path().write_text(contract_idp())
    sys.stdout.write(f"wrote {contract_path()}\n")
