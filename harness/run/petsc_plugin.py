"""The project's FreeFEM plugin for PETSc (freefem/petsc_solver.cpp): run.linear_solver =
"petsc". Compiled on first use against Debian's PETSc (libpetsc-real3.18-dev) by MPI's C++
compiler wrapper, into build/ (harness/core/native.py: cached by the source's hash, atomic).

Debian's `ff-c++ -auto` is broken, so the flags are given here: FreeFEM's headers with the
defines its own plugins are built with (ff-c++'s FFCXXFLAGS), PETSc's headers, and
libpetsc_real with an rpath, so FreeFEM finds it without LD_LIBRARY_PATH.
"""

from __future__ import annotations

import os
from pathlib import Path

from harness.core import native
from harness.core.layout import FREEFEM, REPO

SOURCE = FREEFEM / "petsc_solver.cpp"
# The contact kernel's integrands, generated from freefem/contact_forms.idp (harness/run/contact_forms.py).
# The smoother's lean ILU(0), a PETSc preconditioner of the project's (freefem/lean_ilu.hpp).
HEADERS = (FREEFEM / "contact_forms.hpp", FREEFEM / "lean_ilu.hpp")
BUILD = REPO / "build"
FREEFEM_INCLUDE = Path("/usr/include/freefem++")
# Debian's alternative for the real-scalar PETSc (libpetsc-real3.18-dev).
PETSC_DIR = Path("/usr/lib/petscdir/petsc-real")


def flags(source: Path, out: Path) -> list[str]:
    petsc = Path(os.environ.get("PETSC_DIR", PETSC_DIR))
    return ["-shared", "-fPIC", "-O2", "-w", "-std=c++14", "-DNDEBUG", "-DBAMG_LONG_LONG", "-DNCHECKPTR",
            f"-I{FREEFEM_INCLUDE}", f"-I{HEADERS[0].parent}", f"-I{petsc / 'include'}", "-o", str(out), str(source),
            f"-Wl,-rpath,{petsc / 'lib'}", f"-L{petsc / 'lib'}", "-lpetsc_real"]


def build_spec(build: Path = BUILD, source: Path = SOURCE) -> native.Build:
    return native.Build("the PETSc plugin", source, build, os.environ.get("MPICXX", "mpicxx"), "MPI C++ compiler",
                        'run.linear_solver = "petsc"', flags, headers=HEADERS)


def path(build: Path = BUILD, source: Path = SOURCE) -> Path:
    """Where the plugin for `source` is (or will be) built: its name, without building it."""
    return native.target(build_spec(build, source))


def library(build: Path = BUILD, source: Path = SOURCE) -> Path:
    """The plugin for `source`, compiled into `build` unless already there."""
    return native.library(build_spec(build, source))
