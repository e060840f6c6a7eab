"""One level on several MPI ranks (run.ranks > 1): the launcher command, its environment,
and the sequential pass that reads the checks and outputs of the gathered state.

The distributed Newton solve is freefem/parallel.idp under FreeFem++-mpi, started by
`run.launcher` (default `ff-mpirun -np {ranks}`; on a cluster e.g.
`srun -n {ranks} FreeFem++-mpi`). It writes parallel_state.txt (the state on the global
mesh) and parallel.json (ranks, per-rank memory, Krylov iterations, wall split). Then one
sequential pass of the ordinary scheme starts from that state with no Newton step
(`-newton.max_iterations 0`): it assembles the residual there (no factorisation) and
writes solution.vtu, state.txt and run.json with every check, exactly as a one-rank run
does. run.json then takes the Newton history and the parallel figures from parallel.json.
`run.ranks = 1` never comes here.
"""

from __future__ import annotations

import json
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
from harness.scene.unknowns import Unknowns

MPI_PLUGIN_PATH = "/usr/lib/freefem++/mpi"  # plugins built against MPI (the others abort in FreeFem++-mpi)
IDP_PATH = "/usr/include/freefem++/idp"  # macro_ddm.idp, from Debian's libfreefem++-dev
PARALLEL_SCHEME = "parallel.idp"
# Launchers that pass the arguments after the script through a shell's `eval`, so a path
# with a space or a quote would be split or mangled there: Debian's ff-mpirun builds the
# mpiexec command as a string and runs `eval "${a[*]}"`. Each argument is quoted for it;
# mpiexec, srun and the like pass their arguments on as given.
EVALUATING_LAUNCHERS = ("ff-mpirun",)
# The Newton history the distributed solve owns (run.json takes these from parallel.json).
NEWTON_KEYS = ("converged", "reason", "newton_iterations", "residuals", "increments", "error_estimates",
               "damping", "consistent_tangent", "active_nodes", "slip_nodes", "active_set_changes")


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


def level_capacity(scene: Any, n: int) -> int:
    """The most ranks level n of the scene can be split over (1: only the sequential scheme)."""
    geometry = scene.geometry
    nodes = level_nodes(geometry.width, geometry.height, n, "P1", geometry_depth(geometry),
                        getattr(geometry, "nodes_at", None))
    return max(1, nodes // NODES_PER_RANK)


def level_scene(scene: Any, n: int) -> Any:
    """The scene as level n runs it: on run.ranks, or on as many as the level can take
    (down to one) when it is too small for them. A chain's coarse levels, each only the
    start of the next, so run; a level asked for is checked first (check_level_ranks)."""
    ranks = scene.sections.run.ranks
    return scene if ranks == 1 else scene.on_ranks(min(ranks, level_capacity(scene, n)))


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
    if Unknowns(scene.effects, scene.dimension).staggered:
        raise SceneError("run.ranks > 1 solves the monolithic Newton system only: this scene's theta is staggered "
                         "(thermal without thermal_contact); solve it on one rank")


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


def without_newton_steps(options: list[str]) -> list[str]:
    """The run's options with -newton.max_iterations 0 (FreeFEM reads the first value given)."""
    out = list(options)
    for i, item in enumerate(out[:-1]):
        if item == "-newton.max_iterations":
            out[i + 1] = "0"
            return out
    return out + ["-newton.max_iterations", "0"]


def merge_records(post: dict[str, Any], parallel: dict[str, Any]) -> dict[str, Any]:
    """run.json of the sequential pass with the distributed solve's Newton history and figures."""
    merged = dict(post)
    for key in NEWTON_KEYS:
        if key in parallel:
            merged[key] = parallel[key]
    per_rank = parallel.get("peak_rss_mb_per_rank", [])
    merged.update(
        ranks=parallel.get("ranks"),
        linear_iterations=parallel.get("krylov_iterations"),
        linear_solver=parallel.get("krylov"),
        factorisations=parallel.get("factorisations"),
        gmres_iterations=sum(parallel.get("krylov_iterations", [])),
        # The largest rank's: what each node of a cluster must hold.
        peak_rss_mb=max(per_rank) if per_rank else merged.get("peak_rss_mb", -1),
        post_pass_peak_rss_mb=post.get("peak_rss_mb"),
        post_pass_residuals=post.get("residuals"),
        parallel={k: parallel[k] for k in ("ranks", "peak_rss_mb_per_rank", "newton_dofs_per_rank",
                                           "contact_nodes_per_rank", "krylov_iterations", "factorisations_by_step", "krylov",
                                           "krylov_tolerance", "overlap_layers", "coarse_space", "wall") if k in parallel},
    )
    return merged


def read_json(path: Path) -> dict[str, Any] | None:
    try:
        value = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return value if isinstance(value, dict) else None


def post_pass(work: Path, argv: list[str], first: freefem.Outcome, timeout_s: float) -> freefem.Outcome:
    """After a converged distributed solve in `work`: the sequential pass (argv, main.edp
    already written), then run.json merged. Its Outcome spans both processes."""
    parallel = read_json(work / "parallel.json")
    if parallel is None:
        raise RunError(f"the MPI run wrote no readable parallel.json (see {work / 'stdout.txt'})")
    (work / "mpi_stdout.txt").write_bytes((work / "stdout.txt").read_bytes())
    (work / "run.json").unlink(missing_ok=True)
    second = freefem.invoke(argv, work, max(timeout_s - first.wall_s, 1.0))
    post = read_json(work / "run.json")
    # With no Newton step FreeFEM reports max_iterations (its code), having written everything.
    if second.returncode not in (0, Failure.MAX_ITERATIONS.code) or post is None:
        return freefem.Outcome(second.returncode, first.wall_s + second.wall_s, second.peak_rss_mb)
    (work / "run.json").write_text(json.dumps(merge_records(post, parallel), indent=2) + "\n")
    return freefem.Outcome(0, first.wall_s + second.wall_s, first.peak_rss_mb)
