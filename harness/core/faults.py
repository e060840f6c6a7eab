"""Environment faults and the harness's exit codes: which exception ends in which code,
and an OSError turned into one line that names the culprit.

The table (also in the README):

    0   OK           success
    1   VERDICT      the runs finished, a verdict failed (slope outside the band, a physical check)
    2   INPUT        bad input: case file, override, command line, material, level set
    3   RUN          a FreeFEM run failed: diverged, max iterations, NaN, FreeFEM error, timeout
    4   ENVIRONMENT  permissions, full disk, read-only or wrong-kind path, missing tool, memory
    5   NO_PEER      crosscheck: GetFEM (python3-getfem) is not installed
    6   DISAGREE     crosscheck: FreeFEM and GetFEM differ by more than 1e-8 relative
    7   BUSY         another study is writing the same results directory
    130 INTERRUPTED  SIGINT, SIGTERM or SIGHUP
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Callable, Iterator

from harness.core import signals
from harness.core.contract import ExitCode
from harness.core.errors import (Disagreement, EnvironmentFault, FieldsError, HarnessError, MeshError, PeerMissing,
                            RunError, SceneError, StudyBusy, VerdictError)

# errno -> what a user should hear about the path involved.
MEANING = {
    errno.ENOSPC: "no space left on the device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.EROFS: "read-only file system",
    errno.ENOTDIR: "a path component is a file, not a directory",
    errno.EEXIST: "exists and is not a directory",
    errno.EISDIR: "is a directory",
    errno.ENOMEM: "out of memory",
    errno.EMFILE: "too many open files",
}


def fault(exc: OSError, doing: str = "") -> EnvironmentFault:
    """One line for an OSError: what the harness was doing, the path, and what errno means."""
    path = exc.filename if exc.filename is not None else ""
    what = MEANING.get(exc.errno or 0, exc.strerror or str(exc))
    where = f" {path}" if path else ""
    prefix = f"{doing}: " if doing else ""
    return EnvironmentFault(f"{prefix}cannot write{where}: {what}" if exc.errno in WRITE_ERRNOS
                            else f"{prefix}{os.fspath(path) or 'I/O'}: {what}")


WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EACCES, errno.EPERM, errno.EROFS,
                          errno.ENOTDIR, errno.EEXIST, errno.EISDIR})
FULL_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT})


@contextlib.contextmanager
def space_for(what: str, directory: Path) -> Iterator[None]:
    """A full disk inside names what was being written, and where: a failed write() carries
    no file name, so the bare OSError would say only "cannot write"."""
    try:
        yield
    except OSError as exc:
        if exc.errno not in FULL_ERRNOS:
            raise
        raise EnvironmentFault(f"{MEANING[exc.errno]} for {what} in {directory}") from None


@contextlib.contextmanager
def naming(path: Path) -> Iterator[None]:
    """An OSError from inside that names no file (a failed write() or close(): a disk that
    fills while a report is written) is given `path`, so its one line says where."""
    try:
        yield
    except OSError as exc:
        if exc.filename is None:
            exc.filename = os.fspath(path)
        raise


def exit_code(exc: BaseException) -> ExitCode:
    """The exit code of an exception that ended a command."""
    if isinstance(exc, KeyboardInterrupt):
        return ExitCode.INTERRUPTED
    if isinstance(exc, PeerMissing):
        return ExitCode.NO_PEER
    if isinstance(exc, Disagreement):
        return ExitCode.DISAGREE
    if isinstance(exc, StudyBusy):
        return ExitCode.BUSY
    if isinstance(exc, VerdictError):
        return ExitCode.VERDICT
    if isinstance(exc, (EnvironmentFault, OSError, MemoryError)):
        return ExitCode.ENVIRONMENT
    if isinstance(exc, RunError) and exc.failure.bad_input:
        return ExitCode.INPUT
    if isinstance(exc, (RunError, FieldsError)):
        return ExitCode.RUN
    if isinstance(exc, (SceneError, MeshError, HarnessError)):
        return ExitCode.INPUT
    return ExitCode.RUN


def check_results_root(results: Path) -> None:
    """Fail early, naming the path, when the results root cannot hold results: it or a parent
    is a file, or the nearest existing directory cannot be written. A probe file rather than
    os.access, which answers from the mode bits (and always yes to root). Creates nothing
    that stays."""
    for parent in [results, *results.parents]:
        if not parent.exists():
            continue
        if not parent.is_dir():
            raise EnvironmentFault(f"results path {parent} is a file, not a directory")
        try:
            probe = tempfile.NamedTemporaryFile(dir=parent, prefix=".probe-")
        except OSError as exc:
            raise EnvironmentFault(f"results path {parent} is not writable: "
                                   f"{MEANING.get(exc.errno or 0, exc.strerror)}") from None
        probe.close()
        return


def guarded(body: Callable[[], int], where: str = "") -> int:
    """Run a command's body with the signals handled; every way it can end is an exit code
    and at most one `error:` line on stderr, never a traceback."""
    try:
        with signals.handled():
            try:
                signals.deliver()  # a signal held back during the start-up is handled here
            except KeyboardInterrupt as exc:
                return report(f"interrupted by {exc.args[0]} during start-up", ExitCode.INTERRUPTED)
            return int(body())
    except KeyboardInterrupt as exc:
        name = exc.args[0] if isinstance(exc, signals.Interrupted) else "SIGINT"
        return report(f"interrupted by {name}; runs stopped, temp dirs removed", ExitCode.INTERRUPTED)
    except HarnessError as exc:
        return report(str(exc), exit_code(exc))
    except OSError as exc:
        return report(str(fault(exc, where)), ExitCode.ENVIRONMENT)
    except MemoryError:
        return report("out of memory", ExitCode.ENVIRONMENT)
    except RuntimeError as exc:
        loop = symlink_loop(exc)
        if loop is None:
            raise
        return report(f"{loop}: a loop of symbolic links", ExitCode.ENVIRONMENT)


def symlink_loop(exc: RuntimeError) -> str | None:
    """The path of Python 3.11's pathlib error for a loop of symbolic links (Path.resolve), which
    is a RuntimeError, not an OSError; None for any other RuntimeError. A path of a case file is
    named as such when the scene loads (harness/core/layout.py case_path), exit 2; this is the one
    line for any other, a results folder for instance."""
    text = str(exc)
    prefix = "Symlink loop from "
    return text.removeprefix(prefix).strip("'\"") if text.startswith(prefix) else None


def report(message: str, code: ExitCode) -> int:
    with contextlib.suppress(OSError):  # stderr itself may be gone (a closed terminal: SIGHUP)
        print(f"error: {message}", file=sys.stderr, flush=True)
    return int(code)


# Below this many free bytes a failed write is taken for a full disk (a mesh or a level's
# outputs at n = 16 are ~0.1-1 MB; a real disk that fails a write has ~0 left).
FULL_DISK_BYTES = 1 << 20


def disk_full(path: Path) -> bool:
    """Whether the file system holding `path` (or its nearest existing parent) is full."""
    for parent in [path, *path.parents]:
        if parent.exists():
            try:
                return shutil.disk_usage(parent).free < FULL_DISK_BYTES
            except OSError:
                return False
    return False
