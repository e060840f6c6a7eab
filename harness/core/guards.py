"""Guards before and after a run: levels must be nested, a level must fit in memory and on
disk, and a solution must stay in the small-strain range the model assumes."""

from __future__ import annotations

import csv
import enum
import json
import math
import os
from pathlib import Path
from typing import Callable

import numpy as np

from harness.core.errors import EnvironmentFault, SceneError

# Peak resident memory per unknown of FreeFEM's run (P1, MUMPS): the largest measured ratio,
# rounded up (results/cost/scaling.csv, VmHWM in MiB / dofs, AMD EPYC: 1/64: 66,820 dofs
# 338 MiB, 5.3 kB; 1/128: 264,708 dofs 1,569 MiB, 6.2 kB (two factorisations); 1/256:
# 1,053,700 dofs 5,648 MiB, 5.6 kB). The fixed start-up share (34 MiB at n = 2) is inside
# that margin wherever the guard matters. On MPI ranks on this machine the ranks together
# hold about as much (1.1x at 2 ranks, results/scale/mpi.csv), so the same estimate serves.
BYTES_PER_DOF = 6.3e3
BASE_BYTES = 0.0
# The same in 3D (paper3d, P1, MUMPS; results/paper3d): h = 1/8: 13,365 dofs 268 MB,
# 20 kB; h = 1/16: 93,925 dofs 2.3 GB, 24.5 kB. A 3D factor's fill grows faster than the
# unknowns (nested dissection: O(N^(4/3)) entries, George, SIAM J. Numer. Anal. 10, 1973),
# so past the largest measured level the per-dof figure grows as (N / N_measured)^(1/3):
# h = 1/32 (702,405 dofs) is estimated at 34 GB and refused on a 24 GiB machine.
BYTES_PER_DOF_3D = 26e3
DOFS_3D_MEASURED = 93_925
# A Krylov method with an algebraic multigrid or field-split preconditioner
# (run.linear_solver = "petsc" without a factorisation in run.petsc_options) stores no
# factor: its memory grows like the unknowns. Measured (results/solvers/solvers.csv, VmHWM,
# the field split with BoomerAMG): 3D h = 1/16 1,235 MiB for 93,925 dofs (13.8 kB); 2D
# h = 1/64 425 MiB for 66,820 dofs (6.7 kB: the matrix is held three times, FreeFEM's K and
# K + T and PETSc's copy, beside the AMG hierarchies). Rounded up.
BYTES_PER_DOF_ITERATIVE = {2: 7e3, 3: 14.5e3}
# Geometric multigrid (-pc_type mg over the nested meshes, run.multigrid_levels) holds, per
# unknown, the plugin's one matrix (K, then K + T: FreeFEM holds no K on the PETSc path,
# freefem/bulk.idp), the ILU(0) smoother of the finest level (the plugin's lean one: that
# pattern's values again in single precision, a third of the matrix), the Galerkin levels and
# the Krylov vectors; and, fixed, FreeFEM's start-up and the LU of the coarsest level (n = 8,
# run.multigrid_coarsest's default), whose fill grows faster than its unknowns: like N^(4/3) in
# 3D (nested dissection, George, SIAM J. Numer. Anal. 10, 1973) and, taken as the same power, in
# 2D. Fitted to the paper's scenes (VmHWM, docs/solvers.md "Memory at the peak"): 3D h = 1/2,
# 1/4, 1/8, 1/16, 1/32, 1/64: 68, 77, 188, 344, 1,496, 10,342 MiB for 405, 2,125, 13,365, 93,925,
# 702,405, 5,429,125 dofs (the zero branch; the pressed one within 3 MiB, at 1/64 10,375);
# 2D h = 1/8 ... 1/512: 67, 71, 86, 146, 383, 1,318, 5,068 MiB for 1,188, 4,420, 17,028,
# 66,820, 264,708, 1,053,700 and 4,204,548 dofs. At 3D 1/32 the matrices' share is 1.9 kB per dof (2.6
# with PETSc's own ILU(0), a second matrix of 12 bytes an entry); below n = 8 the level's own LU
# is the coarse solve. The 3D start-up rose by ~3 MiB when the plugin took in the contact kernel
# (3D h = 1/2: 68.4 MiB).
MULTIGRID_START_MIB = {2: 60.0, 3: 63.0}
MULTIGRID_MIB_PER_DOF = {2: 1.2e-3, 3: 1.9e-3}
# The LU of the paper's coarsest level (dofs, MiB): 3D n = 8, 2D n = 8; another size scales it.
MULTIGRID_COARSE_LU = {2: (1_188, 3.5), 3: (13_365, 93.0)}
MULTIGRID_COARSEST = 8
# The measured peaks lie between 5 % above the fit (3D h = 1/2) and 1 % below it (3D h = 1/64);
# the guard counts 10 % above it.
MULTIGRID_MARGIN = 1.1
# MSH 2.2 text per mesh node: a node line (~60 characters) and two triangle lines (~30
# each); in 3D, six tetrahedron lines (~40 each).
MSH_BYTES_PER_NODE = {2: 150, 3: 320}
# Largest displacement gradient (strain or rotation) the small-strain model is trusted at.
SMALL_STRAIN = 0.01
OVERRIDE_FLAG = "--ignore-memory-guard"


class Slope(enum.IntEnum):
    """How many distinct levels a study needs for its slopes. A slope is a least-squares line
    through at least two errors (harness/measure/rates.py); a study whose errors are measured against
    its own finest level (convergence, scenes, verify's GCI) needs that reference level
    besides; one whose errors are against an exact solution (verify's manufactured cases) does
    not. The value is the count of levels. A study whose verdict is not a slope (branches:
    the physical checks) tables its slopes only when it has the levels for them."""

    NONE = 0
    AGAINST_EXACT = 2
    AGAINST_FINEST = 3


def check_slope_levels(levels: tuple[int, ...], slope: Slope, where: str = "") -> None:
    """Refuse, before anything runs, a level set too small for the study's slopes."""
    distinct = sorted(set(levels))
    if len(distinct) >= slope:
        return
    why = ("the finest is the reference, each slope needs two errors against it" if slope == Slope.AGAINST_FINEST
           else "each slope needs two errors")
    given = ",".join(map(str, distinct)) or "none"
    raise SceneError(f"{where + ': ' if where else ''}levels {given} cannot give a slope: the study needs "
                     f"{int(slope)} distinct levels ({why}), e.g. 2,4,8")


def check_nested(levels: tuple[int, ...]) -> None:
    """Refuse a level set whose meshes are not nested: the transfer between levels (the warm
    start, and the error against the finest level) is exact only when each level's h is a
    whole multiple of the next finer one's."""
    ordered = sorted(set(levels))
    for coarse, fine in zip(ordered, ordered[1:]):
        if fine % coarse:
            raise SceneError(f"levels {','.join(map(str, ordered))} are not nested: {fine} is not a multiple "
                             f"of {coarse} (use levels that double, e.g. 2,4,8,16)")


def check_not_shallower(case_dir: Path, levels: tuple[int, ...]) -> None:
    """Refuse a study that would replace a finer one already in `case_dir`: a batch run
    (`scenes`) on a scene's own levels must not silently throw away a deeper study someone
    ran by hand, which may have taken hours. The user extends the levels, removes the old
    study, or writes elsewhere."""
    summary = case_dir / "summary.json"
    try:
        facts = json.loads(summary.read_text())
        recorded = [int(n) for n in facts.get("levels", [])]
    except (OSError, ValueError, TypeError, AttributeError):
        return  # no complete study there (or an unreadable one, which the transaction replaces)
    if is_adaptive(facts):
        raise SceneError(f"{case_dir} holds an adaptive study (`adapt`: adapt.csv, summary.json), which this "
                         f"convergence study would replace; write elsewhere with --results DIR, or remove {case_dir} first")
    if recorded and levels and max(recorded) > max(levels):
        raise SceneError(f"{case_dir} holds a study to n = {max(recorded)} and this one stops at n = {max(levels)}: "
                         f"it would replace the finer study. Run levels {','.join(map(str, sorted(set(levels) | set(recorded))))}, "
                         f"write elsewhere with --results DIR, or remove {case_dir} first")


def is_adaptive(summary: object) -> bool:
    """Whether a summary.json's content is an adaptive study's (harness/studies/adapt.py)."""
    return isinstance(summary, dict) and "bulk" in summary and "steps" in summary and "levels" not in summary


def check_adapt_not_shallower(case_dir: Path, steps: int, max_dofs: int | None) -> None:
    """Refuse an adaptive study that would replace a finer one already in `case_dir` (its
    summary.json and adapt.csv), as check_not_shallower refuses a convergence study: one
    allowed fewer steps, or one whose --max-dofs would stop it before the recorded study's last
    step (a recorded step before the last has that many unknowns). A convergence study's
    folder is refused too: the two would replace each other's summary.json."""
    try:
        facts = json.loads((case_dir / "summary.json").read_text())
    except (OSError, ValueError):
        return  # no complete study there (or an unreadable one, which the transaction replaces)
    if isinstance(facts, dict) and "levels" in facts:
        raise SceneError(f"{case_dir} holds a convergence study (summary.json with its levels), which this adaptive "
                         f"study would replace; write elsewhere with --results DIR, or remove {case_dir} first")
    if not is_adaptive(facts):
        return
    try:
        recorded = int(facts["steps"])
        with (case_dir / "adapt.csv").open() as table:
            dofs = [int(float(row["dofs"])) for row in csv.DictReader(table)]
    except (OSError, ValueError, TypeError, KeyError):
        return  # its table is unreadable: nothing to compare with, the transaction replaces it
    if not dofs:
        return
    what = f"{case_dir} holds an adaptive study of {recorded} steps (to {dofs[-1]:,} unknowns)"
    fix = f"write elsewhere with --results DIR, or remove {case_dir} first"
    if steps < recorded:
        raise SceneError(f"{what} and this one stops at {steps}: it would replace the finer study. "
                         f"Run --steps {recorded} or more, {fix}")
    if max_dofs is not None and max(dofs[:-1], default=0) >= max_dofs:
        first = next(i for i, d in enumerate(dofs, start=1) if d >= max_dofs)
        raise SceneError(f"{what} and this one stops at step {first} (--max-dofs {max_dofs:,}): it would replace the "
                         f"finer study. Run --max-dofs {dofs[-1]:,} or more, {fix}")


def unknowns_per_node(effects: tuple[str, ...], dimension: int = 2) -> int:
    return dimension + ("piezoelectric" in effects) + ("thermal" in effects)


def mesh_nodes(width: float, height: float, n: int, element: str = "P1", depth: float | None = None) -> int:
    """Nodes of the structured level n (P2: the vertices of the mesh twice as fine); a box
    when `depth` (its y extent) is given."""
    k = 2 * n if element == "P2" else n
    nodes = (math.ceil(width * k) + 1) * (math.ceil(height * k) + 1)
    return nodes * (math.ceil(depth * k) + 1) if depth is not None else nodes


NodesAt = Callable[[int], int]


def level_nodes(width: float, height: float, n: int, element: str, depth: float | None,
                nodes_at: NodesAt | None) -> int:
    """Nodes of level n: the scene's own count when it has one, else the structured box's
    (P2: the vertices of the mesh twice as fine)."""
    if nodes_at is None:
        return mesh_nodes(width, height, n, element, depth)
    return nodes_at(2 * n if element == "P2" else n)


def memory_estimate(width: float, height: float, n: int, effects: tuple[str, ...], element: str = "P1",
                    depth: float | None = None, factorises: bool = True, multigrid: bool = False,
                    nodes_at: NodesAt | None = None) -> tuple[int, float]:
    """(dofs, peak bytes) of one level's FreeFEM run; 3D when `depth` is given; `factorises`:
    whether the linear solver factorises the Newton matrix (every solver but a PETSc Krylov
    method with an iterative preconditioner); `multigrid`: whether that preconditioner is a
    geometric multigrid; `nodes_at`: the scene's own node count of a level (a gmsh scene),
    instead of the structured box width x height (x depth)."""
    dimension = 2 if depth is None else 3
    per_node = unknowns_per_node(effects, dimension)
    dofs = per_node * level_nodes(width, height, n, element, depth, nodes_at)
    coarse_dofs = (per_node * level_nodes(width, height, min(n, MULTIGRID_COARSEST), element, depth, nodes_at)
                   if multigrid and not factorises else 0)
    return dofs, run_bytes(dofs, dimension, factorises, multigrid, coarse_dofs)


def run_bytes(dofs: int, dimension: int, factorises: bool, multigrid: bool, coarse_dofs: int) -> float:
    """The peak bytes of a run of `dofs` unknowns, whatever its mesh (a level's, an adaptive
    step's); `coarse_dofs`: a geometric multigrid's coarsest level, whose LU it holds."""
    if not factorises:
        if multigrid:
            return multigrid_bytes(dofs, coarse_dofs, dimension)
        return BYTES_PER_DOF_ITERATIVE[dimension] * dofs
    if dimension == 2:
        return BASE_BYTES + BYTES_PER_DOF * dofs
    return BYTES_PER_DOF_3D * dofs * max(1.0, dofs / DOFS_3D_MEASURED) ** (1 / 3)


def multigrid_bytes(dofs: int, coarse_dofs: int, dimension: int) -> float:
    """The peak of a geometric multigrid's run of `dofs` unknowns (see MULTIGRID_START_MIB):
    start-up, the matrices per unknown, the LU of the coarsest level (`coarse_dofs`)."""
    reference_dofs, reference_mib = MULTIGRID_COARSE_LU[dimension]
    mib = (MULTIGRID_START_MIB[dimension] + MULTIGRID_MIB_PER_DOF[dimension] * dofs
           + reference_mib * (coarse_dofs / reference_dofs) ** (4 / 3))
    return MULTIGRID_MARGIN * mib * 2**20


def available_memory() -> float:
    """Bytes this process may still use: MemAvailable, or less under a cgroup limit."""
    found = math.inf
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                found = float(line.split()[1]) * 1024
    except OSError:
        pass
    for limit, used in (("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
                        ("/sys/fs/cgroup/memory/memory.limit_in_bytes", "/sys/fs/cgroup/memory/memory.usage_in_bytes")):
        try:
            cap = Path(limit).read_text().strip()
            if cap != "max":
                found = min(found, float(cap) - float(Path(used).read_text()))
        except (OSError, ValueError):
            continue
    return found


def check_memory(width: float, height: float, levels: tuple[int, ...], effects: tuple[str, ...],
                 element: str = "P1", available: float | None = None, depth: float | None = None,
                 factorises: bool = True, multigrid: bool = False, nodes_at: NodesAt | None = None) -> None:
    """Refuse, before meshing, a level set whose finest level does not fit in the memory left.
    The next finer-but-one level runs alongside it (the pipelined chain starts the finest
    while its coarser level runs; a parallel study runs two at once), so its peak counts too."""
    finest, *rest = sorted(set(levels), reverse=True)
    dofs, need = memory_estimate(width, height, finest, effects, element, depth, factorises, multigrid, nodes_at)
    if rest:
        need += memory_estimate(width, height, rest[0], effects, element, depth, factorises, multigrid, nodes_at)[1]
    have = available_memory() if available is None else available
    if need > have:
        raise EnvironmentFault(
            f"level n={finest} would need about {need / 1e9:.3g} GB ({dofs:,} dofs, from the measured bytes per dof) but {have / 1e9:.3g} GB is available; refusing before meshing ({OVERRIDE_FLAG} runs it anyway)")


def geometry_depth(geometry: object) -> float | None:
    """A box's y extent (the third dimension of the guards' estimates); None in 2D."""
    return getattr(geometry, "ly", None) if getattr(geometry, "dimension", 2) == 3 else None


def mesh_file_bytes(geometry: object, n: int) -> int:
    width, height = getattr(geometry, "width", 1.0), getattr(geometry, "height", 1.0)
    depth = geometry_depth(geometry)
    nodes = level_nodes(width, height, n, "P1", depth, getattr(geometry, "nodes_at", None))
    return MSH_BYTES_PER_NODE[2 if depth is None else 3] * nodes


def need_disk(directory: Path, size: int, what: str) -> None:
    """Refuse to start writing `what` (about `size` bytes) where it cannot fit."""
    try:
        stat = os.statvfs(directory)
    except OSError:
        return
    free = stat.f_bavail * stat.f_frsize
    if free < size:
        raise EnvironmentFault(f"no space left on the device for {what} in {directory}: "
                               f"about {size / 1e6:.3g} MB needed, {free / 1e6:.3g} MB free")


def max_displacement_gradient(points: np.ndarray, cells: np.ndarray, u: np.ndarray) -> float:
    """Largest entry of grad u over P1 simplices (triangles or tetrahedra; constant on each):
    a bound on both the strain and the rotation."""
    d = cells.shape[1] - 1
    p = points[cells][:, :, :d]
    edges = p[:, 1:] - p[:, :1]                     # (M, d, d): rows are edge vectors
    du = u[cells][:, :, :d]
    jumps = du[:, 1:] - du[:, :1]                   # (M, d, d): u along each edge
    # edges @ grad = jumps, grad[k, i] = d u_i / d x_k
    grad = np.linalg.solve(edges, jumps) if len(cells) else np.zeros((0, d, d))
    return float(np.abs(grad).max(initial=0.0))


def small_strain_warning(gradient: float, where: str) -> str | None:
    if gradient > SMALL_STRAIN:
        return (f"{where}: max displacement gradient {gradient:.3g} (strain or rotation) exceeds {SMALL_STRAIN:g}: "
                f"the small-strain model no longer holds")
    return None
