"""Run one level: reuse a cached result or run FreeFEM in a temp dir, then swap it in atomically."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from harness.core import freefem

from harness.run import launcher, petsc_plugin

from harness.scene import materials
from harness.core.atomic import OLD_PREFIX, RUN_TEMP_PREFIX, write_atomic
from harness.core.contract import Failure
from harness.run.cache import cached_record, run_inputs, sha256_file, write_checksums
from harness.core.errors import EnvironmentFault, HarnessError, RunError, SceneError
from harness.scene.gmsh_geometry import GmshGeometry
from harness.core.faults import disk_full, space_for
from harness.scene.floating import floating_macros
from harness.core.signals import CHILDREN, Interrupted
from harness.core.layout import Layout
from harness.mesh.mesh import coarser_meshes, family_levels
from harness.run.record import RunRecord, read_run_json, write_run_json
from harness.run.tresca import grip_warning
from harness.scene.scene import Scene
from harness.scene.regions import region_definitions
from harness.run.script import main_script


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
class RunResult:
    n: int
    directory: Path
    record: RunRecord  # run.json, with the harness's measurements
    reused: bool
    key: str = ""  # the cache key it was run or reused under

    def warm_start(self, mesh: Path) -> WarmStart:
        """This run as the start of the next finer level."""
        return WarmStart(mesh, self.directory / "state.txt", self.key or None)

    @property
    def solution(self) -> Path:
        return self.directory / "solution.vtu"


def check_solver_files(scene: Scene, layout: Layout) -> None:
    """Fail before meshing or running when the solver scripts (--freefem) are not there, or
    the case names a material that is missing or invalid (harness/scene/materials.py)."""
    if not layout.freefem.is_dir():
        raise HarnessError(f"--freefem {layout.freefem}: the FreeFEM scripts directory does not exist")
    if not layout.scheme_file().is_file():
        raise HarnessError(f"--freefem {layout.freefem}: not a FreeFEM scripts directory (no {layout.scheme_file().name})")
    for material in [scene.material] + [r.material for r in scene.regions]:
        wanted = layout.material_file(material)
        if not wanted.is_file():
            library = layout.material_library()
            available = ", ".join(sorted(p.stem for p in library.glob("*.idp"))) or "none"
            raise SceneError(f"{scene.source}: unknown material {material!r}: no file {wanted} "
                             f"(available: {available} in {library}, or give a path to a .idp file)")
        materials.check(wanted, layout)


def run_level(
    scene: Scene, mesh: Path, n: int, layout: Layout, force: bool = False, warm: WarmStart | None = None
) -> RunResult:
    level = LevelRun(scene, mesh, n, layout, force)
    return level.start(warm) or level.wait()


class LevelRun:
    """One level's run: reuse a cached result, or run FreeFEM in a temp dir and swap it in.

    Pipelined (`launch_early`, for a level warm-started from the one below it): FreeFEM is
    started before that coarser level has finished. It compiles the scheme, loads both
    meshes and assembles the bulk (freefem/bulk.idp), then waits on stdin for the coarser
    state (initial_guess.idp); start() sends it. The run's wall_s leaves out that wait
    (measured from the mtime of the file `ready` FreeFEM writes when it begins waiting).
    """

    def __init__(self, scene: Scene, mesh: Path, n: int, layout: Layout, force: bool = False) -> None:
        check_solver_files(scene, layout)
        launcher.check_parallel(scene)
        scene = launcher.level_scene(scene, n)  # on as many of run.ranks as the level can take
        self.scene, self.mesh, self.n, self.layout, self.force = scene, mesh, n, layout, force
        self.work: Path | None = None
        self.launched: freefem.Launched | None = None
        self.inputs: dict[str, Any] = {}
        self.start_line: tuple[str, WarmStart | None] = ("", None)
        self.resumed_at: float | None = None

    def launch_early(self, coarser_mesh: Path) -> None:
        """Start FreeFEM now; it will wait for the state of the run on `coarser_mesh`."""
        if launcher.ranks_of(self.scene).parallel:  # stdin reaches rank 0 only: no pipelined start
            return
        with self._space():
            self.work = self._new_work_dir()
            self.launched = self._launch("file", WarmStart(coarser_mesh, Path("-")), waits=True)

    def start(self, warm: WarmStart | None) -> RunResult | None:
        """The cached result (and no run) if the inputs are unchanged, else None with the run
        under way (wait() for it)."""
        guess, start = start_of(self.scene, warm)
        described = {**self.scene.run_inputs(), "start": guess}
        ranks = launcher.ranks_of(self.scene)
        if ranks.parallel:  # a run on other ranks is another measurement (same solution to round-off)
            described["ranks"] = ranks.count
        if start and start.key:
            described["start_key"] = start.key
        elif start:
            described["start_state_sha256"] = sha256_file(start.state)
        script, options = solver_inputs(self.scene, self.mesh, self.n, self.layout, guess, start, make_meshes=False)
        self.inputs = run_inputs(self.mesh, described, self.layout.freefem, freefem.freefem_version(), self.n,
                                 script, keyed_options(options), self.layout.material_file(self.scene.material))
        self.start_line = (guess, start)
        cached = cached_result(self.layout.level_dir(self.scene.name, self.n), self.inputs["key"], self.n)
        if cached and not self.force:
            self.abandon()
            return cached
        if self.launched is not None and start is not None and guess == "file":
            self.resumed_at = self.launched.resume(str(start.state.resolve()))
        else:
            self.abandon()  # launched early for a start it will not get: run afresh
            with self._space():
                self.work = self._new_work_dir()
                self.launched = self._launch(guess, start, waits=False)
        return None

    def wait(self) -> RunResult:
        assert self.launched is not None and self.work is not None
        work, scene, n = self.work, self.scene, self.n
        try:
            outcome = freefem.finish(self.launched, scene.timeout_s)
            if launcher.ranks_of(scene).parallel and outcome.returncode == 0:
                post = post_pass_command(work, scene, self.mesh, n, self.layout)
                outcome = launcher.post_pass(work, post, outcome, scene.timeout_s)
            if CHILDREN.signum is not None:  # killed by the signal handler, not a failure of its own
                raise Interrupted(CHILDREN.signum)
            waited = None if self.resumed_at is None else waited_s(work, self.resumed_at)
            with self._space():  # collect writes run.json's final form
                record = collect(work, scene, n, self.layout, outcome, *self.start_line, waited)
        except RunError as exc:
            keep_failed(work, self.layout.failed_dir(scene.name, n))
            CHILDREN.drop_dir(work)
            self.work = None
            if disk_full(work.parent):  # FreeFEM's writes failed for want of space, not the run itself
                raise EnvironmentFault(f"no space left on the device for the outputs of {scene.name} n={n} "
                                       f"in {work.parent} ({exc})") from None
            raise
        except BaseException:
            self.abandon()
            raise
        final = self.layout.level_dir(scene.name, n)
        try:
            with self._space():
                write_atomic(work / "inputs.json", json.dumps(self.inputs, indent=2, sort_keys=True) + "\n")
                write_checksums(work)
                swap_in(work, final)
        except BaseException:
            self.abandon()
            raise
        CHILDREN.drop_dir(work)
        self.work = None
        shutil.rmtree(self.layout.failed_dir(scene.name, n), ignore_errors=True)
        return RunResult(n, final, record, reused=False, key=self.inputs["key"])

    def abandon(self) -> None:
        """Kill a run that will not be waited for and remove its directory."""
        if self.launched is not None:
            self.launched.abandon()
            self.launched = None
        if self.work is not None:
            shutil.rmtree(self.work, ignore_errors=True)
            CHILDREN.drop_dir(self.work)
            self.work = None

    def _space(self) -> contextlib.AbstractContextManager[None]:
        directory = self.layout.level_dir(self.scene.name, self.n).parent
        return space_for(f"the outputs of {self.scene.name} n={self.n}", directory)

    def _new_work_dir(self) -> Path:
        final = self.layout.level_dir(self.scene.name, self.n)
        work = final.with_name(f"{RUN_TEMP_PREFIX}n{self.n}-{uuid.uuid4().hex[:8]}")
        work.mkdir(parents=True)
        CHILDREN.add_dir(work)  # removed on a signal, whichever thread owns it
        return work

    def _launch(self, guess: str, start: WarmStart | None, waits: bool) -> freefem.Launched:
        assert self.work is not None
        argv = solver_command(self.work, self.scene, self.mesh.resolve(), self.n, self.layout, guess, start)
        if launcher.ranks_of(self.scene).parallel:
            return freefem.launch(argv, self.work, env=launcher.environment())
        return freefem.launch(argv, self.work, waits_on_stdin=waits)


def waited_s(work: Path, resumed_at: float) -> float:
    """How long a pipelined run sat idle: from writing `ready` to receiving its start."""
    try:
        return max(0.0, resumed_at - (work / "ready").stat().st_mtime)
    except OSError:  # never got that far (it failed before), or was resumed before it was ready
        return 0.0


def cached_result(directory: Path, key: str, n: int) -> RunResult | None:
    record = cached_record(directory, key)
    if record is not None and (directory / "solution.vtu").is_file():
        return RunResult(n, directory, record, reused=True, key=key)
    return None


# Options that name files: their content is keyed (mesh, start), not where they are.
PATH_OPTIONS = frozenset({"-mesh", "-out", "-init.mesh", "-init.state", "-mg.mesh", "-ddm.coarse_mesh"})


def keyed_options(options: list[str]) -> tuple[str, ...]:
    out: list[str] = []
    skip = False
    for item in options:
        if skip:
            skip = False
            continue
        if item in PATH_OPTIONS:
            skip = True
            continue
        out.append(item)
    return tuple(out)


def solver_inputs(
    scene: Scene, mesh: Path, n: int, layout: Layout, guess: str, start: WarmStart | None, out: Path | None = None,
    sequential: bool = False, make_meshes: bool = True,
) -> tuple[str, list[str]]:
    """main.edp's text and FreeFEM's options. A start state "-" is read from stdin (a pipelined run).
    On several ranks (run.ranks > 1) the text is the distributed scheme's, unless `sequential`.
    The coarser meshes the options name (a multigrid's levels, a coarse space) are made only
    with `make_meshes`: the cache key needs their names alone."""
    macros = {**manufactured_macros(scene, layout), **scene.reference_macros(), **scene.poling_macros(),
              **floating_macros(scene.geometry)}
    parallel = launcher.ranks_of(scene).parallel and not sequential
    petsc = scene.linear_solver == "petsc"
    definitions = region_definitions(scene.regions, layout, scene.dimension) if scene.regions else []
    text = main_script(scene.material, scene.effects, layout, element=scene.element, macros=macros,
                       definitions=definitions,
                       linear_solver=scene.linear_solver, petsc_plugin=petsc_plugin.library() if petsc else None,
                       ranks=parallel, dimension=scene.dimension)
    options = ["-mesh", str(mesh.resolve()), "-out", str(out.resolve() if out else "-"), "-n", str(n)]
    options += freefem.scene_options(scene.solver_parameters(), guess)
    if petsc:
        options += ["-run.petsc_options", scene.petsc_options]
        for coarse in coarser_meshes(scene.geometry, n, scene.multigrid_levels, scene.sections.run.multigrid_coarsest,
                                     mesh.resolve().parent, make_meshes):
            options += ["-mg.mesh", str(coarse)]
    if isinstance(scene.geometry, GmshGeometry) and scene.geometry.small_cells(n):
        options += ["-mesh.small_cells", "1"]
    if parallel:
        options += ["-parallel.krylov_rtol", repr(scene.sections.run.krylov_rtol)]
    if parallel and scene.coarse_levels:
        options += coarse_space_options(scene, n, mesh, make_meshes)
    if start:
        state = str(start.state) if str(start.state) == "-" else str(start.state.resolve())
        options += ["-init.mesh", str(start.mesh.resolve()), "-init.state", state]
    return text, options


def coarse_space_options(scene: Scene, n: int, mesh: Path, make: bool = True) -> list[str]:
    """The two-level Schwarz's coarse mesh on ranks (freefem/coarse_space.idp): the scene's
    mesh run.coarse_levels halvings below n, or the coarsest of the family (n = 2); none
    when n cannot be halved."""
    coarse = coarser_meshes(scene.geometry, n, scene.coarse_levels, 2, mesh.resolve().parent, make)
    if not coarse:
        return []
    coarse_n = family_levels(scene.geometry, n, scene.coarse_levels)[-1]  # the level of coarse[-1]
    return ["-ddm.coarse_mesh", str(coarse[-1]), "-ddm.coarse_n", str(coarse_n)]


def manufactured_macros(scene: Scene, layout: Layout) -> dict[str, str]:
    """The macros of a scene's [manufactured] solution (harness/scene/mms.py): a hook loaded only
    for such a scene, so no other run pays for importing sympy (0.6 s)."""
    if not scene.manufactured:
        return {}
    from harness.scene.mms import scene_macros

    return scene_macros(scene, layout)


def solver_command(
    work: Path, scene: Scene, mesh: Path, n: int, layout: Layout, guess: str, start: WarmStart | None
) -> list[str]:
    """Write main.edp into `work` and return FreeFEM's command line."""
    script = work / "main.edp"
    text, options = solver_inputs(scene, mesh, n, layout, guess, start, out=work)
    script.write_text(text)
    ranks = launcher.ranks_of(scene)
    return ranks.argv(script, options) if ranks.parallel else freefem.command(script, options)


def post_pass_command(work: Path, scene: Scene, mesh: Path, n: int, layout: Layout) -> list[str]:
    """The sequential pass after a distributed solve (harness/run/launcher.py): post.edp from
    the gathered state, no Newton step."""
    script = work / "post.edp"
    start = WarmStart(mesh, work / "parallel_state.txt")
    text, options = solver_inputs(scene, mesh, n, layout, "file", start, out=work, sequential=True)
    script.write_text(text)
    return freefem.command(script, launcher.post_pass_options(options, work))


def collect(
    work: Path, scene: Scene, n: int, layout: Layout, outcome: freefem.Outcome, guess: str, start: WarmStart | None,
    waited: float | None = None,
) -> RunRecord:
    """run.json of a finished run, with the harness's measurements (a pipelined run's wall
    time less its `waited` seconds); a RunError with the reason if it failed."""
    where = f"{scene.name} n={n}"
    log = log_file(work, layout.failed_dir(scene.name, n))
    record = read_run_json(work)
    if outcome.returncode != 0:
        # (A distributed solve that failed wrote its run.json on the ranks.)
        solved_by = record.reason if record else None
        detail = solved_by or freefem.error_detail(read_logs(work))
        reason = freefem.failure_reason(outcome, scene.timeout_s, str(detail), started_pressed(scene, guess))
        raise RunError(f"{where}: {reason} (see {log})", freefem.failure_of(outcome))
    if record is None:
        raise RunError(f"{where}: FreeFEM wrote no readable run.json (see {log})", Failure.NO_OUTPUT)
    if record.converged is not True:
        raise RunError(f"{where}: not converged: {record.reason or 'no reason given'} (see {log})",
                       NEWTON_REASONS.get(str(record.reason), Failure.NOT_CONVERGED))
    if not (work / "solution.vtu").is_file():
        raise RunError(f"{where}: FreeFEM wrote no solution.vtu (see {log})", Failure.NO_OUTPUT)
    record = record.with_(wall_s=outcome.wall_s)
    if waited is not None:
        record = record.with_(pipelined=True, waited_s=waited, wall_s=outcome.wall_s - waited)
    # FreeFEM's own VmHWM (memory.idp); wait4's figure, which cannot read below the harness's
    # resident size at fork time, only where /proc is missing.
    own = (record.peak_rss_mb or -1) > 0
    record = record.with_(peak_rss_source="freefem VmHWM" if own else "harness wait4",
                          peak_rss_mb=record.peak_rss_mb if own else outcome.peak_rss_mb,
                          initial_guess=scene.initial_guess,
                          started_from=guess if not start else f"file {start.state}")
    grip = grip_warning(scene, record)
    if grip:
        record = record.with_(warnings=[grip])
    write_run_json(record, work)
    return record


# run.json's `reason` of a run that stopped without converging (freefem/newton.idp).
NEWTON_REASONS = {"diverged": Failure.DIVERGED, "max_iterations": Failure.MAX_ITERATIONS, "nan": Failure.NAN}


def started_pressed(scene: Scene, guess: str) -> bool:
    """Whether a run started from the pressed guess, itself or down a chain that did."""
    chained = scene.initial_guess == "coarser" and scene.sections.scene.coarsest_guess == "pressed"
    return guess == "pressed" or chained


def read_record(work: Path) -> RunRecord | None:
    """The run.json a run left in `work` (None: none readable)."""
    return read_run_json(work)


def read_logs(work: Path) -> str:
    return "\n".join((work / name).read_text(errors="replace") for name in ("stderr.txt", "stdout.txt"))


def log_file(work: Path, failed: Path) -> Path:
    """The log a user should open once the failed run sits in `failed`: FreeFEM reports its
    errors on stdout, so stderr is only worth pointing at when it says something."""
    name = "stderr.txt" if (work / "stderr.txt").stat().st_size else "stdout.txt"
    return failed / name


def keep_failed(work: Path, failed: Path) -> None:
    """Park a failed run where its logs can be read, never over the last good result."""
    shutil.rmtree(failed, ignore_errors=True)
    os.replace(work, failed)


def swap_in(work: Path, final: Path) -> None:
    old = final.with_name(f"{OLD_PREFIX}{final.name}-{uuid.uuid4().hex[:8]}")
    if final.exists():
        os.replace(final, old)
    os.replace(work, final)
    shutil.rmtree(old, ignore_errors=True)
