"""A run's quantities (the table of harness/scene/quantities.py): the case's probes and averages
as main.edp's macros (freefem/quantities.idp), a probe refused when it lies outside a gmsh
body's mesh (the study's coarsest level before anything runs, and each level before it runs), run.json's `quantities` read from the keys the table names, and contact.csv ordered by
position."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import meshio
import numpy as np
import pandas as pd

from harness.core.atomic import write_atomic
from harness.core.contract import ROLE_MACROS
from harness.core.errors import SceneError
from harness.core.gmsh_api import GMSH
from harness.mesh.mesh import checked_level
from harness.scene.gmsh_geometry import GmshGeometry
from harness.scene.quantities import read_source
from harness.scene.scene import Scene

# A probe's or an average's field -> its physical P1 field in freefem/output.idp.
FREEFEM_FIELDS = {"u_x": "uP1", "u_y": "uP2", "u_z": "uP3", "phi": "physP", "theta": "physT"}
CONTACT_TABLE = "contact.csv"


def freefem_definitions(scene: Scene) -> list[str]:
    """main.edp's lists of probes and averages (none: freefem/quantities.idp's empty ones)."""
    lines = []
    if scene.probes:
        calls = " ".join(f"DO({j}, {FREEFEM_FIELDS[p.field]}, {', '.join(repr(c) for c in p.at)})"
                         for j, p in enumerate(scene.probes))
        lines += [f"macro probeList(DO) {calls} //", f"macro probeCount {len(scene.probes)} //"]
    if scene.averages:
        calls = " ".join(f"DO({j}, {FREEFEM_FIELDS[a.field]}, {ROLE_MACROS[a.on]})" for j, a in enumerate(scene.averages))
        lines += [f"macro averageList(DO) {calls} //", f"macro averageCount {len(scene.averages)} //"]
    return lines


def quantities_of(scene: Scene, data: dict[str, Any]) -> dict[str, float]:
    """Every quantity of the scene by name, from run.json's `data` (NaN where the run has none)."""
    out = {}
    for quantity in scene.quantities:
        value = read_source(quantity.source, data)
        out[quantity.name] = math.nan if value is None else value
    return out


def inside_mesh(points: np.ndarray, cells: np.ndarray, at: np.ndarray, tol: float = 1e-9) -> bool:
    """Whether `at` lies in one of the simplices (barycentric coordinates >= -tol)."""
    corners = points[cells]                      # (cells, d + 1, d)
    base = corners[:, 0, :]
    edges = np.transpose(corners[:, 1:, :] - base[:, None, :], (0, 2, 1))  # (cells, d, d)
    good = np.abs(np.linalg.det(edges)) > 0
    lam = np.linalg.solve(edges[good], (at - base[good])[..., None])[..., 0]
    return bool(np.any((lam >= -tol).all(axis=1) & (lam.sum(axis=1) <= 1 + tol)))


def needs_mesh_check(scene: Scene) -> bool:
    """Only a gmsh body's probes are checked against a mesh: a rectangle's or a box's were checked
    against the body's extent, which is the body, when the scene loaded (harness/scene/quantities.py)."""
    return bool(scene.probes) and isinstance(scene.geometry, GmshGeometry)


def check_points(scene: Scene, points: np.ndarray, cells: np.ndarray, n: int) -> None:
    """A SceneError naming the first probe outside level n's mesh, and the case file."""
    for probe in scene.probes:
        if not inside_mesh(points[:, :scene.dimension], cells, np.array(probe.at)):
            raise SceneError(f"{scene.source}: quantities.probes {probe.name!r}: the point {probe.at} is outside "
                             f"the body (the mesh of level n={n})")


def check_probes_on_level(scene: Scene, n: int) -> None:
    """The study's guard, before anything is meshed to disk or run: level n made in memory (the
    coarsest of the study: quick) and every probe located in it."""
    if not needs_mesh_check(scene):
        return
    with GMSH:
        level, _, _ = checked_level(scene.geometry, n, warn=False)
    check_points(scene, level.points, level.cells, n)


def check_probes_in_mesh(scene: Scene, mesh: Path, n: int) -> None:
    """Each level again before it runs, in its own mesh file (a remeshed level is not the
    coarsest's refinement)."""
    if not needs_mesh_check(scene):
        return
    read = meshio.read(mesh)
    kind = "triangle" if scene.dimension == 2 else "tetra"
    cells = np.concatenate([block.data for block in read.cells if block.type == kind])
    check_points(scene, read.points, cells, n)


def order_contact_table(work: Path, dimension: int) -> None:
    """contact.csv's rows by position: x, then y (then z)."""
    path = work / CONTACT_TABLE
    if not path.is_file():
        return
    table = pd.read_csv(path)
    table = table.sort_values(list("xyz"[:dimension]), kind="stable").reset_index(drop=True)
    write_atomic(path, table.to_csv(index=False, float_format="%.17g"))
