"""One gmsh session at a time: gmsh keeps one library state per process and is not
thread-safe, and gmsh.initialize() resets signal dispositions behind Python's back."""

from __future__ import annotations

import threading
from contextlib import contextmanager
from typing import Iterator

import gmsh

from harness.core import signals

# Re-entrant: a caller that already holds it (engine.InlineMeshes) may mesh through a
# function that takes it again.
GMSH = threading.RLock()


@contextmanager
def session(threads: int = 1) -> Iterator[None]:
    """An initialised gmsh, silent, with `threads` threads (1: the same mesh every time),
    finalised on the way out whatever happens."""
    with GMSH:
        # interruptible=False: gmsh must not install a SIGINT handler (fails off the main thread).
        gmsh.initialize(readConfigFiles=False, interruptible=False)
        signals.reassert()  # gmsh.initialize resets SIGTERM, SIGHUP and SIGPIPE to their defaults
        try:
            gmsh.option.setNumber("General.Terminal", 0)
            gmsh.option.setNumber("General.NumThreads", threads)
            yield
        finally:
            gmsh.finalize()
            signals.reassert()
