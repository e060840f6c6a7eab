"""Native code built on first use (harness/core/native.py): a failed build is one line that names
what is missing."""

from __future__ import annotations

import stat
from pathlib import Path

import pytest

from harness.core.errors import EnvironmentFault
from harness.core.native import Build, library

# What OpenMPI's mpicxx writes when the C++ compiler it wraps is not installed (mpicxx from
# Debian's libopenmpi-dev with OMPI_CXX naming a missing compiler, copied from a run on this
# machine's OpenMPI 4.1): no line says "error".
OPENMPI_BANNER = """\
--------------------------------------------------------------------------
The Open MPI wrapper compiler was unable to find the specified compiler
g++ in your PATH.

Note that this compiler was either specified at configure time or in
one of several possible environment variables.
--------------------------------------------------------------------------
"""


def fake_compiler(tmp_path: Path, stderr: str) -> Path:
    tool = tmp_path / "mpicxx"
    (tmp_path / "stderr.txt").write_text(stderr)
    tool.write_text(f"#!/bin/sh\ncat '{tmp_path / 'stderr.txt'}' >&2\nexit 1\n")
    tool.chmod(tool.stat().st_mode | stat.S_IXUSR)
    return tool


def build(tmp_path: Path, compiler: Path) -> Build:
    source = tmp_path / "plugin.cpp"
    source.write_text("int f() { return 1; }\n")
    return Build("the PETSc plugin", source, tmp_path / "build", str(compiler), "MPI C++ compiler",
                 "run.linear_solver = petsc", lambda src, out: [str(src), "-o", str(out)])


def test_a_wrapper_without_the_compiler_it_wraps_names_that_compiler(tmp_path):
    with pytest.raises(EnvironmentFault) as info:
        library(build(tmp_path, fake_compiler(tmp_path, OPENMPI_BANNER)))
    message = str(info.value)
    assert "\n" not in message and "---" not in message
    assert "unable to find the specified compiler g++ in your PATH" in message
    assert not list((tmp_path / "build").iterdir())  # no half-built library left


def test_a_compiler_error_is_its_first_error_line(tmp_path):
    stderr = "plugin.cpp: In function 'f':\nplugin.cpp:1:1: warning: unused\nplugin.cpp:2:3: error: expected ';'\n"
    with pytest.raises(EnvironmentFault, match=r"plugin\.cpp:2:3: error: expected ';'$"):
        library(build(tmp_path, fake_compiler(tmp_path, stderr)))

