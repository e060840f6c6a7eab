"""SIGINT, SIGTERM and SIGHUP end the whole process tree: the FreeFEM runs (each in its own
session, so a signal to the harness's group does not reach them), the forked mesh worker,
and the runs' temp dirs; the command then exits 130.

The handler raises `Interrupted` in the main thread, so every `finally` on the way out
runs (a run in progress is abandoned, a level never half-swapped); before raising it kills
the registered children at once, so worker threads blocked in wait4 return and cannot keep
the process alive."""

from __future__ import annotations

import contextlib
import ctypes
import os
import shutil
import signal
import threading
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import Iterator

HANDLED = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class Interrupted(KeyboardInterrupt):
    """A handled signal: a KeyboardInterrupt, so code that cleans up on Ctrl-C cleans up here too."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


@dataclass
class Children:
    """What must not outlive the harness: process groups it started and temp dirs it made.

    One per process (`CHILDREN`): signal handlers are process-wide, and the objects that
    start children (runs, the mesh pool) are created deep inside a study."""

    groups: set[int] = field(default_factory=set)
    pids: set[int] = field(default_factory=set)
    dirs: set[Path] = field(default_factory=set)
    lock: threading.Lock = field(default_factory=threading.Lock)
    signum: int | None = None  # the signal that ended the run, once one has

    def add_group(self, pgid: int) -> None:
        with self.lock:
            self.groups.add(pgid)

    def drop_group(self, pgid: int) -> None:
        with self.lock:
            self.groups.discard(pgid)

    def add_pid(self, pid: int) -> None:
        with self.lock:
            self.pids.add(pid)

    def drop_pid(self, pid: int) -> None:
        with self.lock:
            self.pids.discard(pid)

    def add_dir(self, path: Path) -> None:
        with self.lock:
            self.dirs.add(path)

    def drop_dir(self, path: Path) -> None:
        with self.lock:
            self.dirs.discard(path)

    def live_dirs(self) -> set[Path]:
        with self.lock:
            return set(self.dirs)

    def kill_all(self) -> None:
        """SIGKILL every registered process group and process (they are reaped by whoever waits on them)."""
        with self.lock:
            groups, pids = list(self.groups), list(self.pids)
        for pgid in groups:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(pgid, signal.SIGKILL)
        for pid in pids:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.kill(pid, signal.SIGKILL)

    def remove_dirs(self) -> None:
        with self.lock:
            dirs, self.dirs = list(self.dirs), set()
        for path in dirs:
            shutil.rmtree(path, ignore_errors=True)


CHILDREN = Children()


def _handler(signum: int, frame: FrameType | None) -> None:
    if CHILDREN.signum is not None:
        return  # already on the way out: a second Ctrl-C must not interrupt the clean-up
    CHILDREN.signum = signum
    CHILDREN.kill_all()
    raise Interrupted(signum)


def deliver() -> None:
    """Let the handled signals in: `python -m harness` holds them back from its first line
    (harness/__main__.py; raised inside an import or a thread's start, the handler's
    KeyboardInterrupt left a traceback and exit 1 instead of one line and 130) until
    `faults.guarded` calls this, where one that came meanwhile is handled. A no-op in any
    other caller. The one thread started before (the FreeFEM version query) keeps the mask,
    and so does its FreeFEM; SIGKILL, which `kill_all` sends, still ends it."""
    signal.pthread_sigmask(signal.SIG_UNBLOCK, HANDLED)


def install() -> None:
    """Handle SIGINT, SIGTERM and SIGHUP in this (main) thread from now on."""
    CHILDREN.signum = None
    for signum in HANDLED:
        signal.signal(signum, _handler)


@contextlib.contextmanager
def handled() -> Iterator[Children]:
    """Handle the signals for the duration, then put back the previous handlers; on the way out
    after a signal (or any exception), kill what is left and remove the temp dirs."""
    if threading.current_thread() is not threading.main_thread():
        yield CHILDREN  # only the main thread may set handlers; its caller handles the signals
        return
    previous = {signum: signal.getsignal(signum) for signum in HANDLED}
    install()
    try:
        yield CHILDREN
    except BaseException:
        CHILDREN.kill_all()
        CHILDREN.remove_dirs()
        raise
    finally:
        for signum, action in previous.items():
            signal.signal(signum, action)


def reassert() -> None:
    """Put the dispositions Python believes in back in force in the kernel. Native code may
    reset one behind Python's back: gmsh.initialize() sets SIGTERM, SIGHUP and SIGPIPE to
    their defaults, after which a SIGTERM killed the harness outright, leaving its FreeFEM
    runs' temp dirs behind, and a write to a closed pipe killed it silently (exit 141, no
    `error:` line) instead of raising BrokenPipeError. Only the main thread may set a Python
    handler; SIGPIPE, which Python ignores, is put back from any thread (an ignored signal
    has no handler to run)."""
    if signal.getsignal(signal.SIGPIPE) == signal.SIG_IGN:
        ignore_sigpipe()
    if threading.current_thread() is not threading.main_thread():
        return
    for signum in HANDLED:
        handler = signal.getsignal(signum)
        if handler is not None:
            signal.signal(signum, handler)


def ignore_sigpipe() -> None:
    """SIGPIPE ignored process-wide, from any thread: libc's signal(), as Python's own start-up
    sets it (signal.signal would refuse outside the main thread)."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGPIPE, signal.SIG_IGN)
        return
    libc = ctypes.CDLL(None, use_errno=True)
    libc.signal.restype = ctypes.c_void_p
    libc.signal.argtypes = (ctypes.c_int, ctypes.c_void_p)
    libc.signal(int(signal.SIGPIPE), int(signal.SIG_IGN))


def in_forked_child() -> None:
    """For a forked worker (the mesh pool): the parent ends it, so ignore SIGINT (a Ctrl-C
    reaches the whole foreground group and would print the worker's traceback), die on
    SIGTERM/SIGHUP without Python's handler, and die with the parent if the parent is
    SIGKILLed (Linux PR_SET_PDEATHSIG), instead of blocking on its pipe for ever."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGHUP, signal.SIG_DFL)
    CHILDREN.groups.clear()
    CHILDREN.pids.clear()
    CHILDREN.dirs.clear()
    with contextlib.suppress(OSError, AttributeError):
        import ctypes

        pr_set_pdeathsig = 1
        ctypes.CDLL(None, use_errno=True).prctl(pr_set_pdeathsig, signal.SIGKILL)
    if os.getppid() == 1:  # the parent died before prctl took effect
        os._exit(1)


def track_pool(pool: object) -> list[int]:
    """Register the worker processes of a started ProcessPoolExecutor (its `_processes`:
    the executor has no public list of them) so a signal ends them too."""
    pids = list(getattr(pool, "_processes", None) or {})
    for pid in pids:
        CHILDREN.add_pid(pid)
    return pids


def end_pool(pids: list[int]) -> None:
    for pid in pids:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.kill(pid, signal.SIGKILL)


def untrack_pool(pids: list[int]) -> None:
    for pid in pids:
        CHILDREN.drop_pid(pid)
