"""Invoke FreeFem++ in batch: the command line, the environment, the timeout, the exit codes."""

from __future__ import annotations

import contextlib
import functools
import importlib
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import Future
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from harness.core.contract import Failure
from harness.core.errors import EnvironmentFault, RunError
from harness.core.rank_watch import DeadRank, dead_rank
from harness.core.signals import CHILDREN, Interrupted

BINARY = "FreeFem++"
PLUGIN_PATH = "/usr/lib/freefem++"  # Debian's binary looks elsewhere for its plugins
# A rank found dead (a zombie its launcher has not reaped) this long is taken as a launcher
# that will not end the others: Open MPI's own abort takes 1-2 s here.
RANK_POLL_S, RANK_GRACE_S = 1.0, 5.0
INFINITY = "1e300"  # FreeFEM's atof has no "inf"; 1e300 acts as unbounded for every knob

# FreeFEM's exit code -> what it means (harness/core/contract.py, the one table).
EXIT_REASONS = {f.code: f.text for f in Failure if f.code is not None}
# Said after "diverged" unless the run already started pressed (or from a pressed chain).
PRESSED_HINT = " (no solution near this start? try scene.coarsest_guess = pressed)"

# The first line of FreeFEM's own report of what went wrong (it writes to stdout).
ERROR_LINE = re.compile(r"error|assertion fail", re.IGNORECASE)


@dataclass(frozen=True)
class Outcome:
    returncode: int | None  # None: killed on timeout
    wall_s: float
    peak_rss_mb: float = float("nan")  # resident set size high-water mark of FreeFEM


def environment() -> dict[str, str]:
    env = dict(os.environ, FF_LOADPATH=PLUGIN_PATH)
    # One thread per run: the study runs levels in parallel, one per core.
    env.update(OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    return env


def command(script: Path, options: list[str]) -> list[str]:
    return [BINARY, "-nw", "-v", "0", "-ne", script.name, *options]


def format_value(value: Any) -> str:
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, float):
        if math.isinf(value):
            return INFINITY if value > 0 else "-" + INFINITY
        return repr(value)  # repr round-trips a double exactly
    return str(value)


def scene_options(parameters: dict[str, dict[str, Any]], initial_guess: str) -> list[str]:
    options = []
    for section, values in parameters.items():
        for key, value in values.items():
            options += [f"-{section}.{key}", format_value(value)]
    return options + ["-scene.initial_guess", initial_guess]


@dataclass
class Launched:
    """A started FreeFEM process (stdout.txt / stderr.txt in its directory)."""

    proc: subprocess.Popen
    started: float  # time.perf_counter() at launch

    def resume(self, line: str) -> float:
        """Send one line to a process waiting on stdin (a pipelined start); the wall-clock
        time (time.time()) it was sent. A process that already died is left to finish()."""
        with contextlib.suppress(BrokenPipeError, OSError):
            assert self.proc.stdin is not None
            self.proc.stdin.write(line.encode() + b"\n")
            self.proc.stdin.close()
        return time.time()

    def abandon(self) -> None:
        """Kill the whole process group and reap it."""
        if self.proc.returncode is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait()
        # Only now: a child of the group may outlive its leader until the killpg above.
        CHILDREN.drop_group(self.proc.pid)


def with_parent_death_signal(argv: list[str]) -> list[str]:
    """Let the kernel SIGKILL FreeFEM when the thread that started it dies, even when the harness
    itself is SIGKILLed (an OOM kill, a CI runner's hard stop), where no handler runs. util-linux's
    setpriv sets PR_SET_PDEATHSIG and execs FreeFEM in the same process (preexec_fn would do it
    in Python, which is unsafe with the study's threads). Without setpriv, as before."""
    setpriv = shutil.which("setpriv")
    if not setpriv or argv[0] != BINARY or shutil.which(BINARY) is None:
        return argv  # a missing FreeFEM is then Popen's FileNotFoundError, named below
    return [setpriv, "--pdeathsig", "KILL", *argv]


def warm_import(module: str) -> None:
    """Import `module` in a thread while FreeFEM runs: what is read after the run (meshio for
    solution.vtu) is then loaded off the critical path of a whole `solve` process. Called
    when a core is free (the last level of a chain runs), not while the chain below it and
    the finest level's setup hold both cores."""
    if module not in sys.modules:
        threading.Thread(target=importlib.import_module, args=(module,), daemon=True).start()


def launch(argv: list[str], cwd: Path, waits_on_stdin: bool = False, env: dict[str, str] | None = None) -> Launched:
    """Start FreeFEM in `cwd`, its own process group; stdin is a pipe when it will wait for a
    line (Launched.resume), else empty."""
    try:
        with open(cwd / "stdout.txt", "wb") as out, open(cwd / "stderr.txt", "wb") as err:
            proc = subprocess.Popen(
                with_parent_death_signal(argv), cwd=cwd, env=env or environment(), stdout=out, stderr=err,
                stdin=subprocess.PIPE if waits_on_stdin else subprocess.DEVNULL, start_new_session=True,
            )
    except FileNotFoundError:
        raise EnvironmentFault(f"{argv[0]} not found on PATH (`make test` or `make convergence` installs it)") from None
    CHILDREN.add_group(proc.pid)  # its own session: a signal to the harness does not reach it
    launched = Launched(proc, time.perf_counter())
    if CHILDREN.signum is not None:  # a worker thread launching after the signal: end it at once
        launched.abandon()
        raise Interrupted(CHILDREN.signum)
    return launched


def finish(launched: Launched, timeout_s: float) -> Outcome:
    """Wait for a launched run (at most timeout_s from now, then kill its process group)."""
    code, rss = None, float("nan")
    try:
        code, rss = wait_measured(launched.proc, timeout_s)
    finally:
        launched.abandon()  # only acts on a timeout, or when the caller was interrupted
    return Outcome(code, time.perf_counter() - launched.started, rss)


def invoke(argv: list[str], cwd: Path, timeout_s: float) -> Outcome:
    """Run in `cwd` with stdout.txt / stderr.txt there; on timeout kill the whole process group."""
    return finish(launch(argv, cwd), timeout_s)


def wait_measured(proc: subprocess.Popen, timeout_s: float) -> tuple[int | None, float]:
    """Wait for `proc` (None on timeout) and read its own peak RSS from wait4's rusage,
    which, unlike RUSAGE_CHILDREN, is this child's alone (Linux reports it in KiB).

    A blocking wait4 returns the moment FreeFEM exits (polling added up to 10 ms per run);
    a timer kills the process group at the deadline, and a watcher kills it when a rank has
    died and the launcher has not ended the others within RANK_GRACE_S (rank_watch.py): the
    run then ends with that rank's code, as a launcher would report it."""
    timed_out, done = threading.Event(), threading.Event()
    dead: list[DeadRank] = []

    def kill() -> None:
        timed_out.set()
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)

    def watch() -> None:
        seen: dict[int, int] = {}
        while not done.wait(RANK_POLL_S):
            rank = dead_rank(proc.pid)
            seen = {rank.pid: seen.get(rank.pid, 0) + 1} if rank else {}
            if rank and seen[rank.pid] * RANK_POLL_S >= RANK_GRACE_S:
                dead.append(rank)
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGKILL)
                return

    timer = threading.Timer(timeout_s, kill)
    timer.daemon = True
    timer.start()
    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    try:
        _, status, usage = os.wait4(proc.pid, 0)
    finally:
        timer.cancel()
        done.set()
    proc.returncode = os.waitstatus_to_exitcode(status)
    if dead and not timed_out.is_set():
        return dead[0].returncode, float("nan")
    if timed_out.is_set():
        return None, float("nan")
    return proc.returncode, usage.ru_maxrss / 1024.0


def error_detail(log: str) -> str:
    """The line that says why: the scripts' own "error: ..." line wherever it is (on MPI ranks
    the launcher's stderr comes first, with its own lines about the abort), else the first
    line that looks like an error."""
    lines = [line.strip() for line in log.splitlines()]
    line = next((line for line in lines if line.startswith("error:")), "")
    line = line or next((line for line in lines if ERROR_LINE.search(line)), "")
    return line[:200]


def failure_of(outcome: Outcome) -> Failure:
    """The classified failure of a run that ended with a non-zero code (or none: timed out)."""
    code = outcome.returncode
    if code is None:
        return Failure.TIMEOUT
    return Failure.KILLED if code < 0 or shell_signal(code) else Failure.from_code(code)


def shell_signal(code: int) -> int | None:
    """The signal behind an exit code 128 + N, the form in which a shell or an MPI launcher
    reports a child (a rank) that a signal ended; None for FreeFEM's own codes."""
    if code in EXIT_REASONS or not 128 < code < 128 + 65:
        return None
    return code - 128


def failure_reason(outcome: Outcome, timeout_s: float, detail: str, pressed: bool = False) -> str:
    """One line for a failed run; `pressed`: it started from the pressed guess (directly or
    down a chain that did), so suggesting that start would be no help."""
    code = outcome.returncode
    if code is None:
        return f"timed out after {timeout_s:g} s (process group killed)"
    number = -code if code < 0 else shell_signal(code)
    if number:
        try:
            name = signal.Signals(number).name
        except ValueError:
            name = str(number)
        return f"killed by signal {name}" + (f" (exit code {code}: a rank or the launcher)" if code > 0 else "")
    reason = EXIT_REASONS.get(code, f"FreeFEM exited with code {code}")
    if code == Failure.DIVERGED.code and not pressed:
        reason += PRESSED_HINT
    return f"{reason}: {detail[:360]}" if detail else reason


@functools.cache
def version_query(binary: str) -> Future[str]:
    """FreeFEM's own `version`, asked once per process in a thread from the first call:
    `cli.main` calls this before the study's imports, so the query (a FreeFEM start-up,
    30-60 ms) is off the critical path of a `solve`. Not a daemon thread: the interpreter
    joins it at exit, so its temp dir is always removed."""
    answer: Future[str] = Future()

    def ask() -> None:
        try:
            answer.set_result(_ask_version(binary))
        except BaseException as exc:  # noqa: BLE001 (handed to whoever reads the answer)
            answer.set_exception(exc)

    threading.Thread(target=ask, name="freefem-version").start()
    return answer


@functools.cache
def freefem_version() -> str:
    """FreeFEM's own `version` (part of every cache key)."""
    try:
        return version_query(BINARY).result()
    except RunError:
        # Killed with the runs of an earlier command of this process (signals.handled ends
        # every child on an error), before it answered: asked again, here.
        return _ask_version(BINARY)


def _ask_version(binary: str) -> str:
    with tempfile.TemporaryDirectory(prefix="ff-version-") as tmp:
        script = Path(tmp) / "version.edp"
        script.write_text("cout << version << endl;\n")
        outcome = invoke([binary, *command(script, [])[1:]], Path(tmp), timeout_s=60)
        text = (Path(tmp) / "stdout.txt").read_text().strip()
    if outcome.returncode != 0 or not text:
        raise RunError(f"{binary} does not run (asked for its version, exit code {outcome.returncode})")
    return text.splitlines()[0]
