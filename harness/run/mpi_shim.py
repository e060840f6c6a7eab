"""The LD_PRELOAD library that lets FreeFem++-mpi load the MUMPS plugins
(freefem/mpi_init_once.c says why), compiled on first use (harness/core/native.py).

Built with the C compiler alone: no MPI headers or libraries, as it calls MPI's PMPI_*
entry points, found at run time in the libmpi FreeFem++-mpi links.
"""

from __future__ import annotations

import os
from pathlib import Path

from harness.core import native
from harness.core.layout import FREEFEM, REPO

SOURCE = FREEFEM / "mpi_init_once.c"
BUILD = REPO / "build"


def library(build: Path = BUILD, source: Path = SOURCE) -> Path:
    """The shared library for `source`, compiled into `build` unless already there."""
    return native.library(native.Build(
        "the MPI shim", source, build, os.environ.get("CC", "cc"), "C compiler", "run.ranks > 1",
        lambda src, out: ["-shared", "-fPIC", "-O2", "-o", str(out), str(src)], timeout_s=120))


def preloaded(env: dict[str, str], shim: Path) -> dict[str, str]:
    """env with the shim first in LD_PRELOAD (a launcher's own preloads kept after it)."""
    earlier = [item for item in env.get("LD_PRELOAD", "").split(":") if item and item != str(shim)]
    return {**env, "LD_PRELOAD": ":".join([str(shim), *earlier])}
