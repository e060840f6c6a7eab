"""Native code of the project compiled on first use: the MPI shim (harness/run/mpi_shim.py)
and the PETSc plugin (harness/run/petsc_plugin.py).

One rule for both. The library goes into the build directory under a name carrying its
source's hash, so an edited source is rebuilt and a stale library is never used. It is
compiled under a temporary name and renamed into place, so two ranks or two Dask workers
building at once never load half a file. Every failure is one EnvironmentFault line.
"""

from __future__ import annotations

import hashlib
import itertools
import os
import shutil
import subprocess
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from harness.core.errors import EnvironmentFault


@dataclass(frozen=True)
class Build:
    what: str                      # "the MPI shim", "the PETSc plugin": for the error lines
    source: Path
    build: Path
    compiler: str                  # a command on PATH
    compiler_kind: str             # "C compiler": for the error line when it is missing
    needed_for: str                # "run.ranks > 1": why a compiler is wanted
    flags: Callable[[Path, Path], list[str]]  # (source, output) -> the compiler's arguments
    timeout_s: float = 300.0
    headers: tuple[Path, ...] = ()  # files the source includes: a change to one rebuilds it too


def target(spec: Build) -> Path:
    try:
        hashed = hashlib.sha256(spec.source.read_bytes())
        for header in spec.headers:
            hashed.update(header.read_bytes())
        digest = hashed.hexdigest()[:16]
    except OSError as exc:
        raise EnvironmentFault(f"cannot read {spec.what}'s source {exc.filename}: {exc.strerror}") from None
    return spec.build / f"{spec.source.stem}-{digest}.so"


def library(spec: Build) -> Path:
    """The shared library of `spec.source`, compiled into `spec.build` unless already there."""
    out = target(spec)
    if out.is_file():
        return out
    if shutil.which(spec.compiler) is None:
        raise EnvironmentFault(f"{spec.needed_for} needs a {spec.compiler_kind} ({spec.compiler!r} not found) to build {out.name}")
    temp = spec.build / f".{out.name}.{os.getpid()}-{uuid.uuid4().hex[:8]}"
    try:
        spec.build.mkdir(parents=True, exist_ok=True)
        done = subprocess.run([spec.compiler, *spec.flags(spec.source, temp)],
                              capture_output=True, text=True, timeout=spec.timeout_s)
        if done.returncode != 0:
            raise EnvironmentFault(f"cannot build {spec.what} {out.name}: {first_error(done.stderr)}")
        os.replace(temp, out)
    except OSError as exc:
        raise EnvironmentFault(f"cannot build {spec.what} in {spec.build}: {exc.strerror}") from None
    except subprocess.TimeoutExpired:
        raise EnvironmentFault(f"building {spec.what} {out.name} took over {spec.timeout_s:.0f} s") from None
    finally:
        temp.unlink(missing_ok=True)
    return out


def first_error(stderr: str) -> str:
    """The compiler's first error line (warnings before it are noise here); without one, its
    first paragraph of text on one line. Banner lines of dashes are left out: OpenMPI's
    wrapper (mpicxx) says it cannot find the compiler it wraps between two of them, the name
    on the paragraph's second line."""
    lines = [line.strip() for line in stderr.splitlines()]
    text = [line for line in lines if not line or any(c.isalnum() for c in line)]
    error = next((line for line in text if "error" in line), None)
    if error:
        return error
    paragraph = itertools.takewhile(bool, itertools.dropwhile(lambda line: not line, text))
    return " ".join(paragraph) or "no message"
