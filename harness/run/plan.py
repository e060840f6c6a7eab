"""One level's run plan, made before anything runs: main.edp's text, FreeFEM's options, the
coarser meshes those options name, the sequential pass a distributed solve needs after it,
and the content key of the whole (harness/run/cache.py).

Making a plan meshes nothing, builds nothing and starts no FreeFEM: it reads the scene, the
mesh file (for the key) and the solver sources. The executor (harness/run/run.py) makes
the meshes a plan names, builds the solver's plugin, runs the plan and keeps its outputs.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from harness.core import freefem
from harness.core.errors import SceneError
from harness.core.layout import Layout
from harness.mesh import cut as mesh_cut
from harness.mesh.mesh import coarser_meshes, family_levels
from harness.mesh.msh import marked_coarser, small_cells_marker
from harness.run import launcher, petsc_plugin
from harness.run.cache import run_inputs, sha256_file
from harness.run.goals import goal_definitions
from harness.run.quantities import freefem_definitions
from harness.run.script import main_script
from harness.scene.floating import floating_macros
from harness.scene.gmsh_geometry import GmshGeometry
from harness.scene.materials import included_files
from harness.scene.regions import region_definitions
from harness.scene.scene import Scene

# Options that name files: their content is keyed (mesh, start), not where they are.
PATH_OPTIONS = frozenset({"-mesh", "-out", "-init.mesh", "-init.state", "-mg.mesh", "-ddm.coarse_mesh", "-parallel.parts"})
# Where the distributed solve leaves its gathered state for the sequential pass (freefem/parallel_output.idp).
PARALLEL_STATE = "parallel_state.txt"
# The value of -out until the executor names the run's directory.
UNBOUND = "-"
# Where in the run's directory the mesh's parts for the ranks are cut (harness/mesh/cut.py); removed
# once FreeFEM is done (their content is the mesh's and the rank count, both in the key).
PARTS = "parts"


@dataclass(frozen=True)
class WarmStart:
    """A converged state to start Newton from: its mesh and its state.txt (output.idp)."""

    mesh: Path
    state: Path
    key: str | None = None  # the coarser run's cache key: stands for its state in this run's key


def start_of(scene: Scene, warm: WarmStart | None) -> tuple[str, WarmStart | None]:
    """FreeFEM's initial_guess and the state it reads, from the scene and an optional coarser run."""
    guess = scene.initial_guess
    if guess == "coarser":
        return ("file", warm) if warm else (scene.sections.scene.coarsest_guess, None)
    if guess == "file":
        given = WarmStart(Path(scene.sections.scene.initial_mesh), Path(scene.sections.scene.initial_state))
        for what, path in (("initial_mesh", given.mesh), ("initial_state", given.state)):
            if not path.is_file():
                raise SceneError(f"initial_guess = file: scene.{what} {str(path)!r} is not a file")
        return "file", given
    return guess, None


@dataclass(frozen=True)
class Invocation:
    """One FreeFEM process: its main script, its options (-out not yet bound to a directory)
    and the coarser meshes (level, file) the options name, which must exist before it starts."""

    script: str
    options: tuple[str, ...]
    meshes: tuple[tuple[int, Path], ...] = ()
    cut: tuple[Path, int] | None = None  # the mesh to cut into parts before it starts, and how many

    def bound(self, work: Path) -> list[str]:
        """The options of a run in `work`: its outputs there, a distributed solve's state read from there."""
        out = list(self.options)
        for i, item in enumerate(out[:-1]):
            if item == "-out" and out[i + 1] == UNBOUND:
                out[i + 1] = str(work.resolve())
            elif item == "-init.state" and out[i + 1] == PARALLEL_STATE:
                out[i + 1] = str((work / PARALLEL_STATE).resolve())
            elif item == "-parallel.parts" and out[i + 1] == PARTS:
                out[i + 1] = str((work / PARTS).resolve())
        return out

    @property
    def keyed_options(self) -> tuple[str, ...]:
        """The options without the files they name (the key holds those files' content)."""
        out: list[str] = []
        words = iter(self.options)
        for item in words:
            if item in PATH_OPTIONS:
                next(words, None)
                continue
            out.append(item)
        return tuple(out)


@dataclass(frozen=True)
class RunPlan:
    """Everything one level's run is, decided before it runs."""

    scene: Scene            # as the level runs it (on as many ranks as it can take)
    n: int
    mesh: Path
    guess: str              # FreeFEM's initial_guess
    start: WarmStart | None
    main: Invocation
    post: Invocation | None  # the sequential pass after a distributed solve, if any (harness/run/launcher.py)
    inputs: Mapping[str, Any]  # what the key covers, and the key

    @property
    def key(self) -> str:
        return str(self.inputs["key"])


def make_plan(scene: Scene, mesh: Path, n: int, layout: Layout, warm: WarmStart | None) -> RunPlan:
    """Level n of `scene` on `mesh`, started from `warm` (a coarser run) when the scene says so."""
    guess, start = start_of(scene, warm)
    main = invocation(scene, mesh, n, layout, guess, start)
    ranks = launcher.ranks_of(scene)
    post = None
    if ranks.parallel and not launcher.outputs_on_ranks(scene):
        post = invocation(scene, mesh, n, layout, "file", WarmStart(mesh, Path(PARALLEL_STATE)), sequential=True)
    described = {**scene.run_inputs(), "start": guess}
    if ranks.parallel:  # a run on other ranks is another measurement (same solution to round-off)
        described["ranks"] = ranks.count
    if main.cut:  # how the ranks' parts are cut is an input of their run (harness/mesh/cut.py)
        described["mesh_cut"] = sha256_file(Path(mesh_cut.__file__))
    coarser = marked_coarser(mesh) if scene.multigrid_levels else None
    if coarser:  # the key holds no -mg.mesh file: the levels a step was solved with are its input
        described["multigrid_meshes"] = [sha256_file(c) for c in coarser]
    if start and start.key:
        described["start_key"] = start.key
    elif start:
        described["start_state_sha256"] = sha256_file(start.state)
    files = [layout.material_file(m) for m in dict.fromkeys([scene.material, *(r.material for r in scene.regions)])]
    # main.edp includes the first material and holds the regions' constants, which FreeFEM
    # printed from each region's file and what it includes: every such file is keyed.
    included = tuple(dict.fromkeys(p for f in files for p in included_files(f)))
    inputs = run_inputs(mesh, described, layout.freefem, freefem.freefem_version(), n,
                        main.script, main.keyed_options, files[0], included)
    return RunPlan(scene, n, mesh, guess, start, main, post, inputs)


def invocation(scene: Scene, mesh: Path, n: int, layout: Layout, guess: str, start: WarmStart | None,
               sequential: bool = False) -> Invocation:
    """main.edp's text and FreeFEM's options. A start state "-" is read from stdin (a pipelined
    run). On several ranks (run.ranks > 1) the text is the distributed scheme's, unless
    `sequential`."""
    macros = {**manufactured_macros(scene, layout), **scene.reference_macros(), **scene.poling_macros(), **scene.plane_macros(),
              **floating_macros(scene.geometry, scene.sections.scene.materials)}
    parallel = launcher.ranks_of(scene).parallel and not sequential
    solver = scene.solver
    definitions = region_definitions(scene.regions, layout, scene.dimension, scene.plane) if scene.regions else []
    definitions += freefem_definitions(scene)
    definitions += goal_definitions(scene)
    text = main_script(scene.material, scene.effects, layout, element=scene.element, macros=macros,
                       definitions=definitions, linear_solver=solver,
                       plugin=petsc_plugin.path() if solver.builds_plugin else None,
                       ranks=parallel, monolithic=launcher.ranks_of(scene).parallel, dimension=scene.dimension)
    directory = mesh.resolve().parent
    options = ["-mesh", str(mesh.resolve()), "-out", UNBOUND, "-n", str(n)]
    options += freefem.scene_options(scene.solver_parameters(), guess)
    options += solver.freefem_options(scene.solver_options)
    meshes: list[tuple[int, Path]] = []
    if scene.multigrid_levels:
        # An adaptive step names its own levels: the earlier steps it refines (exactly nested),
        # where the scene's uniform family is not nested in it.
        adapted = marked_coarser(mesh)
        if adapted is None:
            multigrid = levels_and_meshes(scene, n, scene.multigrid_levels, scene.sections.run.multigrid_coarsest,
                                          directory)
            meshes += multigrid
            adapted = [coarse for _, coarse in multigrid]
        for coarse in adapted:
            options += ["-mg.mesh", str(coarse)]
    if (isinstance(scene.geometry, GmshGeometry) and scene.geometry.small_cells(n)) or small_cells_marker(mesh).exists():
        options += ["-mesh.small_cells", "1"]
    if parallel:
        options += ["-parallel.krylov_rtol", repr(scene.sections.run.krylov_rtol)]
    cut = None
    if parallel and solver.options_key:
        # PETSc assembles one matrix across the ranks from the rows each holds whole (those where its
        # partition of unity is non-zero): one element layer of overlap gives them all, and the n/8
        # layers the script's Schwarz preconditioner needs would only add to every rank's share. The
        # harness cuts the mesh once into those parts (harness/mesh/cut.py), each rank reads its own.
        options += ["-parallel.overlap", "1", "-parallel.parts", PARTS]
        cut = (mesh.resolve(), launcher.ranks_of(scene).count)
    if parallel and scene.coarse_levels:
        meshes += coarse_space(scene, n, mesh)
        options += coarse_space_options(scene, n, mesh)
    if start:
        state = str(start.state) if str(start.state) in ("-", PARALLEL_STATE) else str(start.state.resolve())
        options += ["-init.mesh", str(start.mesh.resolve()), "-init.state", state]
    return Invocation(text, tuple(options), tuple(meshes), cut)


def levels_and_meshes(scene: Scene, n: int, count: int, coarsest: int, directory: Path) -> list[tuple[int, Path]]:
    """The nested family's levels below n and their mesh files, finest first (not made here)."""
    levels = family_levels(scene.geometry, n, count, coarsest)
    paths = coarser_meshes(scene.geometry, n, count, coarsest, directory, make=False)
    return list(zip(levels, paths))


def coarse_space(scene: Scene, n: int, mesh: Path) -> list[tuple[int, Path]]:
    """The two-level Schwarz's coarse meshes on ranks (freefem/coarse_space.idp), finest
    first: the scene's mesh run.coarse_levels halvings below n, or the coarsest of the
    family (n = 2); none when n cannot be halved. The last is the coarse space's."""
    return levels_and_meshes(scene, n, scene.coarse_levels, 2, mesh.resolve().parent)


def coarse_space_options(scene: Scene, n: int, mesh: Path) -> list[str]:
    """The coarse space's mesh and its level, as FreeFEM reads them."""
    coarse = coarse_space(scene, n, mesh)
    return ["-ddm.coarse_mesh", str(coarse[-1][1]), "-ddm.coarse_n", str(coarse[-1][0])] if coarse else []


def manufactured_macros(scene: Scene, layout: Layout) -> dict[str, str]:
    """The macros of a scene's [manufactured] solution (harness/scene/mms.py): a hook loaded only
    for such a scene, so no other run pays for importing sympy (0.6 s)."""
    if not scene.manufactured:
        return {}
    from harness.scene.mms import scene_macros

    return scene_macros(scene, layout)
