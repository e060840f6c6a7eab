"""Versions of every tool a result depends on, for the study summary."""

from __future__ import annotations

import platform

import gmsh
import matplotlib
import meshio
import numpy
import pandas

from harness.core.freefem import freefem_version


def tool_versions() -> dict[str, str]:
    return {
        "freefem": freefem_version(),
        "gmsh": gmsh.__version__,
        "meshio": meshio.__version__,
        "numpy": numpy.__version__,
        "pandas": pandas.__version__,
        "matplotlib": matplotlib.__version__,
        "python": platform.python_version(),
    }
