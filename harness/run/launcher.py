"""One level on several MPI ranks (run.ranks > 1): the launcher command, its environment,
and the sequential pass that reads the checks and outputs of the gathered state where the
ranks do not write them themselves.

The distributed Newton solve is freefem/scheme.idp with its N-rank backend (freefem/ranks.idp)
under FreeFem++-mpi, started by
`run.launcher` (default `ff-mpirun -np {ranks}`; on a cluster e.g.
`srun -n {ranks} FreeFem++-mpi`). It writes parallel_state.txt (the state on the global
mesh) and ranks_record.txt (the Newton run, per-rank memory, Krylov solver, wall split). Then
one sequential pass of the ordinary scheme starts from that state with no Newton step
(`-newton.max_iterations 0`): it assembles the residual there (no factorisation) and
writes solution.vtu, state.txt and run.json with every check, exactly as a one-rank run
does, and with the ranks' Newton run and figures read from their record
(freefem/ranks_record.idp): FreeFEM writes run.json whole; nothing here reads or mends it.
A run that fails on the ranks has its run.json written there (the reason, the history).
With PETSc across the ranks (`outputs_on_ranks`) no pass follows: the ranks compute the checks,
the estimator and the norms with reductions over the partition of unity and rank 0 writes
solution.vtu, state.txt and run.json, the same values to round-off (freefem/parallel_output.idp).
`run.ranks = 1` never comes here.
"""

from __future__ import annotations

import os
import shlex
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from harness.core import freefem

from harness.run import mpi_shim
from harness.core.contract import Failure
from harness.core.errors import RunError, SceneError
from harness.core.guards import geometry_depth, level_nodes
from harness.scene.linear_solvers import accepting
from harness.mesh.msh import marked_coarser, node_count

MPI_PLUGIN_PATH = "/usr/lib/freefem++/mpi"  # plugins built against MPI (the others abort in FreeFem++-mpi)
IDP_PATH = "/usr/include/freefem++/idp"  # macro_ddm.idp, from Debian's libfreefem++-dev
# Launchers that pass the arguments after the script through a shell's `eval`, so a path
# with a space or a quote would be split or mangled there: Debian's ff-mpirun builds the
# mpiexec command as a string and runs `eval "${a[*]}"`. Each argument is quoted for it;
# mpiexec, srun and the like pass their arguments on as given.
EVALUATING_LAUNCHERS = ("ff-mpirun",)
# What the distributed solve hands the sequential pass (freefem/parallel_output.idp writes it).
RANKS_RECORD = "ranks_record.txt"


@dataclass(frozen=True)
class Ranks:
    """How a level runs: on `count` MPI ranks through `launcher` (a format with {ranks})."""

    count: int
    launcher: str

    @property
    def parallel(self) -> bool:
        return self.count > 1

    def argv(self, script: Path, options: list[str]) -> list[str]:
        try:
            head = shlex.split(self.launcher.format(ranks=self.count))
        except (KeyError, IndexError, ValueError) as exc:
            raise SceneError(f"run.launcher {self.launcher!r} is not a command with {{ranks}}: {exc}") from None
        args = ["-nw", "-v", "0", *options]
        if head and Path(head[0]).name in EVALUATING_LAUNCHERS:
            args = [shlex.quote(arg) for arg in args]  # that shell splits them once more
        return [*head, script.name, *args]


def ranks_of(scene: Any) -> Ranks:
    return Ranks(scene.sections.run.ranks, scene.sections.run.launcher)


# The fewest mesh nodes a rank's subdomain may have. Below it macro_ddm's overlapping
# decomposition can miss neighbours that share a dof, and parallel_newton.idp rejects the
# run ("too coarse", FreeFEM exit 15). Measured on the paper's 4 x 1 rectangle: n = 2
# (27 nodes) ran on 2 and 3 ranks (9 nodes each) and was rejected on 4 (6.75); n = 4 (85
# nodes) ran on 8 and 16 ranks (5.3 each) and was rejected on 32 (2.7); paper3d's n = 2
# (81 nodes) ran on 2 to 16 ranks. 9 is the smallest share seen to pass wherever a smaller
# one failed.
NODES_PER_RANK = 9


def level_capacity(scene: Any, n: int, mesh: Path | None = None) -> int:
    """The most ranks level n of the scene can be split over (1: only the sequential scheme).
    `mesh`, when it is one no level rule describes (an adaptive step's, harness/mesh/msh.py
    mark_coarser): its own node count, its n being only a label (the step's number)."""
    geometry = scene.geometry
    if mesh is not None and marked_coarser(mesh) is not None:
        nodes = node_count(mesh)
    else:
        nodes = level_nodes(geometry.width, geometry.height, n, "P1", geometry_depth(geometry),
                            getattr(geometry, "nodes_at", None))
    return max(1, nodes // NODES_PER_RANK)


def level_scene(scene: Any, n: int, mesh: Path | None = None) -> Any:
    """The scene as level n (on `mesh`) runs it: on run.ranks, or on as many as the level can
    take (down to one) when it is too small for them. A chain's coarse levels, each only the
    start of the next, so run; a level asked for is checked first (check_level_ranks)."""
    ranks = scene.sections.run.ranks
    return scene if ranks == 1 else scene.on_ranks(min(ranks, level_capacity(scene, n, mesh)))


def check_level_ranks(scene: Any, n: int) -> str | None:
    """Refuse a level asked for on ranks that cannot take even 2 of them (its decomposition
    would be rejected); a warning (or None) when it runs on fewer than run.ranks."""
    ranks = scene.sections.run.ranks
    if ranks == 1:
        return None
    capacity = level_capacity(scene, n)
    if capacity < 2:
        raise SceneError(f"level n = {n} is too small for run.ranks = {ranks}: its mesh cannot be split over even "
                         f"2 ranks (at least {NODES_PER_RANK} nodes each); solve it with run.ranks = 1, or a finer level")
    if capacity < ranks:
        return f"level n = {n} runs on {capacity} of the {ranks} ranks of run.ranks (at least {NODES_PER_RANK} mesh nodes a rank)"
    return None


def check_parallel(scene: Any) -> None:
    """What the distributed scheme cannot do, said before anything runs."""
    if not ranks_of(scene).parallel:
        return
    if scene.element != "P1":
        raise SceneError("run.ranks > 1 needs scene.element = P1 (the partition of unity is P1)")
    if not scene.solver.on_ranks:
        raise SceneError(f"run.ranks > 1 factorises each subdomain with a sparse direct solver: use run.linear_solver "
                         f"= {accepting('on_ranks')} there; {scene.linear_solver!r} solves on one rank")


def outputs_on_ranks(scene: Any) -> bool:
    """Whether the ranks write the run's outputs themselves (freefem/parallel_output.idp, OUTPUTHERE
    in freefem/ranks.idp): with PETSc across them, unless a reference run is to be measured, which
    the sequential pass reads on the whole mesh. Otherwise that pass follows the distributed solve."""
    return ranks_of(scene).parallel and scene.solver.builds_plugin and not scene.reference_macros()


def environment() -> dict[str, str]:
    # The MPI shim lets every rank load the scene's solver plugin, MUMPS included
    # (freefem/mpi_init_once.c): each subdomain is factorised by the scene's run.linear_solver.
    env = mpi_shim.preloaded(freefem.environment(), mpi_shim.library())
    env.update(FF_LOADPATH=MPI_PLUGIN_PATH, FF_INCLUDEPATH=IDP_PATH)
    # A rank waiting for a message yields its core instead of spinning (OpenMPI's
    # mpi_yield_when_idle, on by default only when a node is oversubscribed): the ranks
    # share the cores with a study's other runs. A launcher's own setting wins.
    env.setdefault("OMPI_MCA_mpi_yield_when_idle", "1")
    if os.geteuid() == 0:  # OpenMPI refuses root without both
        env.update(OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    return env


def post_pass_options(options: list[str], work: Path) -> list[str]:
    """The sequential pass's options: the run's, with no Newton step and the ranks' record
    (freefem/ranks_record.idp reads their Newton run from it)."""
    return without_newton_steps(options) + ["-ranks.record", str(work / RANKS_RECORD)]


def without_newton_steps(options: list[str]) -> list[str]:
    """The run's options with -newton.max_iterations 0 (FreeFEM reads the first value given)."""
    out = list(options)
    for i, item in enumerate(out[:-1]):
        if item == "-newton.max_iterations":
            out[i + 1] = "0"
            return out
    return out + ["-newton.max_iterations", "0"]


def post_pass(work: Path, argv: list[str], first: freefem.Outcome, timeout_s: float) -> freefem.Outcome:
    """After a converged distributed solve in `work`: the sequential pass (argv, main.edp
    already written, options of `post_pass_options`), which writes the run's run.json. Its
    Outcome spans both processes."""
    if not (work / RANKS_RECORD).is_file():
        raise RunError(f"the MPI run wrote no {RANKS_RECORD} (see {work / 'stdout.txt'})")
    (work / "mpi_stdout.txt").write_bytes((work / "stdout.txt").read_bytes())
    (work / "run.json").unlink(missing_ok=True)
    second = freefem.invoke(argv, work, max(timeout_s - first.wall_s, 1.0))
    if second.returncode != 0:
        return freefem.Outcome(second.returncode, first.wall_s + second.wall_s, second.peak_rss_mb)
    return freefem.Outcome(0, first.wall_s + second.wall_s, first.peak_rss_mb)
