"""Run one level's plan (harness/run/plan.py): reuse a cached result or run FreeFEM in a temp dir,
then swap it in atomically."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

from harness.core import freefem
from harness.core.atomic import OLD_PREFIX, RUN_TEMP_PREFIX, write_atomic
from harness.core.contract import Failure
from harness.core.errors import EnvironmentFault, HarnessError, RunError, SceneError
from harness.core.faults import disk_full, space_for
from harness.core.gmsh_api import GMSH
from harness.core.layout import Layout
from harness.core.signals import CHILDREN, Interrupted
from harness.mesh.cut import cut_files
from harness.mesh.mesh import build_mesh
from harness.run import launcher, petsc_plugin
from harness.run.cache import cached_record, write_checksums
from harness.run.plan import PARTS, Invocation, RunPlan, WarmStart, invocation, make_plan
from harness.run.quantities import check_probes_in_mesh, order_contact_table, quantities_of
from harness.run.record import RunRecord, read_run_json, write_run_json
from harness.run.tresca import grip_warning
from harness.scene import materials
from harness.scene.scene import Scene


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
    """The executor of one level's run plan (harness/run/plan.py): reuse a cached result, or
    make the meshes the plan names, build the solver's plugin, run FreeFEM in a temp dir and
    swap its outputs in.

    Pipelined (`launch_early`, for a level warm-started from the one below it): FreeFEM is
    started before that coarser level has finished. It compiles the scheme, loads both
    meshes and assembles the bulk (freefem/bulk.idp), then waits on stdin for the coarser
    state (initial_guess.idp); start() sends it. The run's wall_s leaves out that wait
    (measured from the mtime of the file `ready` FreeFEM writes when it begins waiting).
    """

    def __init__(self, scene: Scene, mesh: Path, n: int, layout: Layout, force: bool = False) -> None:
        check_solver_files(scene, layout)
        launcher.check_parallel(scene)
        scene = launcher.level_scene(scene, n, mesh)  # on as many of run.ranks as the level can take
        self.scene, self.mesh, self.n, self.layout, self.force = scene, mesh, n, layout, force
        self.work: Path | None = None
        self.launched: freefem.Launched | None = None
        self.plan: RunPlan | None = None
        self.resumed_at: float | None = None
        self.cut_s = 0.0  # the harness's cut of the mesh into the ranks' parts, part of the level's wall

    def launch_early(self, coarser_mesh: Path) -> None:
        """Start FreeFEM now; it will wait for the state of the run on `coarser_mesh`."""
        if launcher.ranks_of(self.scene).parallel:  # stdin reaches rank 0 only: no pipelined start
            return
        check_probes_in_mesh(self.scene, self.mesh, self.n)
        early = invocation(self.scene, self.mesh, self.n, self.layout, "file", WarmStart(coarser_mesh, Path("-")))
        with self._space():
            self.work = self._new_work_dir()
            self.launched = self._launch(early, waits=True)

    def start(self, warm: WarmStart | None) -> RunResult | None:
        """The cached result (and no run) if the plan's key is unchanged, else None with the
        run under way (wait() for it)."""
        try:
            check_probes_in_mesh(self.scene, self.mesh, self.n)
        except SceneError:
            self.abandon()
            raise
        plan = self.plan = make_plan(self.scene, self.mesh, self.n, self.layout, warm)
        cached = cached_result(self.layout.level_dir(self.scene.name, self.n), plan.key, self.n)
        if cached and not self.force:
            self.abandon()
            return cached
        if self.launched is not None and plan.start is not None and plan.guess == "file":
            self.resumed_at = self.launched.resume(str(plan.start.state.resolve()))
        else:
            self.abandon()  # launched early for a start it will not get: run afresh
            with self._space():
                self.work = self._new_work_dir()
                self.launched = self._launch(plan.main, waits=False)
        return None

    def wait(self) -> RunResult:
        assert self.launched is not None and self.work is not None and self.plan is not None
        work, scene, n, plan = self.work, self.scene, self.n, self.plan
        try:
            outcome = freefem.finish(self.launched, scene.timeout_s)
            shutil.rmtree(work / PARTS, ignore_errors=True)
            if plan.post is not None and outcome.returncode == 0:
                script = work / "post.edp"
                script.write_text(plan.post.script)
                post = freefem.command(script, launcher.post_pass_options(plan.post.bound(work), work))
                outcome = launcher.post_pass(work, post, outcome, scene.timeout_s)
            if CHILDREN.signum is not None:  # killed by the signal handler, not a failure of its own
                raise Interrupted(CHILDREN.signum)
            waited = None if self.resumed_at is None else waited_s(work, self.resumed_at)
            with self._space():  # collect writes run.json's final form
                record = collect(work, scene, n, self.layout, outcome, plan.guess, plan.start, waited, self.cut_s)
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
                write_atomic(work / "inputs.json", json.dumps(dict(plan.inputs), indent=2, sort_keys=True) + "\n")
                write_checksums(work)
                swap_in(work, final)
        except BaseException:
            self.abandon()
            raise
        CHILDREN.drop_dir(work)
        self.work = None
        shutil.rmtree(self.layout.failed_dir(scene.name, n), ignore_errors=True)
        return RunResult(n, final, record, reused=False, key=plan.key)

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
        work = final.with_name(f"{RUN_TEMP_PREFIX}{final.name}-{uuid.uuid4().hex[:8]}")
        work.mkdir(parents=True)
        CHILDREN.add_dir(work)  # removed on a signal, whichever thread owns it
        return work

    def _launch(self, run: Invocation, waits: bool) -> freefem.Launched:
        """Make what `run` needs (its coarser meshes, the solver's plugin), write its main.edp, start it."""
        assert self.work is not None
        make_meshes(self.scene, run)
        if run.cut:
            start = time.perf_counter()
            cut_files(*run.cut, self.work / PARTS)
            self.cut_s = time.perf_counter() - start
        if self.scene.solver.builds_plugin:
            petsc_plugin.library()
        script = self.work / "main.edp"
        script.write_text(run.script)
        ranks = launcher.ranks_of(self.scene)
        if ranks.parallel:
            return freefem.launch(ranks.argv(script, run.bound(self.work)), self.work, env=launcher.environment())
        return freefem.launch(freefem.command(script, run.bound(self.work)), self.work, waits_on_stdin=waits)


def make_meshes(scene: Scene, run: Invocation) -> None:
    """The coarser meshes `run` names (a multigrid's levels, a coarse space), made or refreshed."""
    if run.meshes:
        with GMSH:
            for level, path in run.meshes:
                build_mesh(scene.geometry, level, path.parent, warn=False)


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


def collect(
    work: Path, scene: Scene, n: int, layout: Layout, outcome: freefem.Outcome, guess: str, start: WarmStart | None,
    waited: float | None = None, cut_s: float = 0.0,
) -> RunRecord:
    """run.json of a finished run, with the harness's measurements (a pipelined run's wall
    time less its `waited` seconds, a run on ranks' plus the `cut_s` seconds the harness took to
    cut its mesh into their parts); a RunError with the reason if it failed."""
    where = f"{scene.name} n={n}"
    log = log_file(work, layout.failed_dir(scene.name, n))
    if outcome.returncode != 0:
        # (A distributed solve that failed wrote its run.json on the ranks; one whose rank was killed may
        # have left it half written, which must not hide why the run failed.)
        try:
            record = read_run_json(work)
        except HarnessError:
            record = None
        solved_by = record.reason if record else None
        if record and record.failure_hint:
            solved_by = f"{solved_by}: {record.failure_hint}"
        detail = solved_by or freefem.error_detail(read_logs(work))
        reason = freefem.failure_reason(outcome, scene.timeout_s, str(detail), started_pressed(scene, guess))
        raise RunError(f"{where}: {reason} (see {log})", freefem.failure_of(outcome))
    record = read_run_json(work)
    if record is None:
        raise RunError(f"{where}: FreeFEM wrote no readable run.json (see {log})", Failure.NO_OUTPUT)
    if record.converged is not True:
        raise RunError(f"{where}: not converged: {record.reason or 'no reason given'} (see {log})",
                       NEWTON_REASONS.get(str(record.reason), Failure.NOT_CONVERGED))
    if not (work / "solution.vtu").is_file():
        raise RunError(f"{where}: FreeFEM wrote no solution.vtu (see {log})", Failure.NO_OUTPUT)
    record = record.with_(wall_s=outcome.wall_s + cut_s)
    if cut_s:
        record = record.with_(parallel={**(record.parallel or {}), "cut_s": cut_s})
    if waited is not None:
        record = record.with_(pipelined=True, waited_s=waited, wall_s=outcome.wall_s - waited)
    # FreeFEM's own VmHWM (memory.idp); wait4's figure, which cannot read below the harness's
    # resident size at fork time, only where /proc is missing.
    own = (record.peak_rss_mb or -1) > 0
    record = record.with_(peak_rss_source="freefem VmHWM" if own else "harness wait4",
                          peak_rss_mb=record.peak_rss_mb if own else outcome.peak_rss_mb,
                          initial_guess=scene.initial_guess,
                          started_from=guess if not start else f"file {start.state}")
    if scene.regions:  # FreeFEM's `material` names the first region's only
        files = [layout.material_file(r.material) for r in scene.regions]
        record = record.with_(regions=[{"name": r.name, "material": f.stem, "file": str(f.resolve())}
                                       for r, f in zip(scene.regions, files)])
    grip = grip_warning(scene, record)
    if grip:
        record = record.with_(warnings=[grip])
    record = record.with_(quantities=quantities_of(scene, record.to_json()))
    order_contact_table(work, scene.dimension)
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
