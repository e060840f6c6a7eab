"""The LD_PRELOAD library that lets FreeFem++-mpi load the MUMPS plugins
(freefem/mpi_init_once.c says why), compiled on first use.

Built with the C compiler alone (no MPI headers or libraries: it calls MPI's PMPI_* entry
points, found at run time in the libmpi FreeFem++-mpi links), into the build directory under
a name carrying the source's hash, so an edited source is rebuilt and a stale library never
used. The build goes to a temporary name first and is renamed into place, so two ranks'
launches (or two Dask workers) building at once never load half a file.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import uuid
from pathlib import Path

from harness.errors import EnvironmentFault
from harness.layout import REPO

SOURCE = REPO / "freefem" / "mpi_init_once.c"
BUILD = REPO / "build"


def library(build: Path = BUILD, source: Path = SOURCE) -> Path:
    """The shared library for `source`, compiled into `build` unless already there."""
    try:
        digest = hashlib.sha256(source.read_bytes()).hexdigest()[:16]
    except OSError as exc:
        raise EnvironmentFault(f"cannot read the MPI shim's source {source}: {exc.strerror}") from None
    target = build / f"{source.stem}-{digest}.so"
    if target.is_file():
        return target
    compiler = os.environ.get("CC", "cc")
    if shutil.which(compiler) is None:
        raise EnvironmentFault(f"run.ranks > 1 needs a C compiler ({compiler!r} not found) to build {target.name}")
    temp = build / f".{target.name}.{os.getpid()}-{uuid.uuid4().hex[:8]}"
    try:
        build.mkdir(parents=True, exist_ok=True)
        done = subprocess.run([compiler, "-shared", "-fPIC", "-O2", "-o", str(temp), str(source)],
                              capture_output=True, text=True, timeout=120)
        if done.returncode != 0:
            first = next((line for line in done.stderr.splitlines() if line.strip()), "no message")
            raise EnvironmentFault(f"cannot build the MPI shim {target.name}: {first}")
        os.replace(temp, target)
    except OSError as exc:
        raise EnvironmentFault(f"cannot build the MPI shim in {build}: {exc.strerror}") from None
    except subprocess.TimeoutExpired:
        raise EnvironmentFault(f"building the MPI shim {target.name} took over 120 s") from None
    finally:
        temp.unlink(missing_ok=True)
    return target


def preloaded(env: dict[str, str], shim: Path) -> dict[str, str]:
    """env with the shim first in LD_PRELOAD (a launcher's own preloads kept after it)."""
    earlier = [item for item in env.get("LD_PRELOAD", "").split(":") if item and item != str(shim)]
    return {**env, "LD_PRELOAD": ":".join([str(shim), *earlier])}
