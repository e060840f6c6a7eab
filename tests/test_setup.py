"""The set-up scripts' "is it installed" checks cannot be fooled by what lies beside the caller.

A folder named like a package (the checkout once had `getfem/`) imports as a namespace
package from the current directory or PYTHONPATH; a check run there passes and nothing gets
installed. These tests run the checks where such a folder is in the way, with an interpreter
that lacks the package, and expect them to fail.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
INSTALL_GETFEM = ROOT / "scripts" / "install-getfem.sh"


def _decoy(tmp_path: Path) -> Path:
    """A directory holding empty folders named like the peer's imports."""
    for name in ("getfem", "numpy", "scipy"):
        (tmp_path / name).mkdir()
    return tmp_path


def _check(cwd: Path, interpreter: str, extra_env: dict[str, str]) -> subprocess.CompletedProcess:
    env = {**os.environ, "PEER_PYTHON": interpreter, **extra_env}
    return subprocess.run(["bash", str(INSTALL_GETFEM), "--check"], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=60)


def test_getfem_check_fails_beside_a_decoy_folder(tmp_path: Path) -> None:
    """An interpreter without GetFEM, run from a directory holding `getfem/` and with that
    directory on PYTHONPATH: the check must say it is missing (exit 1)."""
    decoy = _decoy(tmp_path)
    # The decoy alone would fool a plain `python -c "import getfem"`: prove the trap is real.
    fooled = subprocess.run([sys.executable, "-c", "import getfem"], cwd=decoy, capture_output=True)
    assert fooled.returncode == 0
    result = _check(decoy, sys.executable, {"PYTHONPATH": str(decoy)})
    assert result.returncode == 1, result.stderr
    assert "not importable" in result.stderr


def test_getfem_check_fails_from_the_repository_root() -> None:
    """From the checkout's root, with the venv's interpreter (no GetFEM there)."""
    result = _check(ROOT, sys.executable, {"PYTHONPATH": str(ROOT)})
    assert result.returncode == 1, result.stderr


def test_getfem_check_passes_where_it_is_installed(tmp_path: Path) -> None:
    """`make test` installed GetFEM for Debian's Python; the same check finds it, decoy or not."""
    if subprocess.run(["/usr/bin/python3", "-I", "-c", "import getfem"], cwd="/",
                      capture_output=True).returncode != 0:
        pytest.fail("GetFEM is not installed for /usr/bin/python3: run `make getfem` (make test does)")
    assert _check(_decoy(tmp_path), "/usr/bin/python3", {}).returncode == 0


def test_no_top_level_folder_shadows_a_package_the_tools_import() -> None:
    """Debian's Python runs the peer with the checkout nearby; no top-level folder may carry
    the name of a package it or the harness imports."""
    imported = {"getfem", "numpy", "scipy", "meshio", "gmsh", "pandas", "matplotlib", "dask",
                "distributed", "sympy", "pytest"}
    folders = {p.name for p in ROOT.iterdir() if p.is_dir()}
    assert not folders & imported
