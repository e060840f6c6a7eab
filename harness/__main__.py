"""`python -m harness`: the signal handlers first, before the heavy imports, then the command line."""

import signal
import sys

# First, before any import that takes time: SIGINT, SIGTERM and SIGHUP (signals.HANDLED) are
# held back until the command runs (faults.guarded lets them in), so a signal during start-up
# ends with one line and 130, never a traceback from inside an import or a thread's start.
# Not in Dask's spawned workers, which import this module again and never reach that point.
if __name__ == "__main__":
    signal.pthread_sigmask(signal.SIG_BLOCK, (signal.SIGINT, signal.SIGTERM, signal.SIGHUP))

import gc  # noqa: E402

from harness.core.signals import install  # noqa: E402

install()
try:
    from harness.cli import main
except KeyboardInterrupt as exc:
    print(f"error: interrupted by {exc.args[0] if exc.args else 'SIGINT'} during start-up", file=sys.stderr)
    sys.exit(130)

# Guarded: Dask's worker processes (spawned) import the parent's main module again.
if __name__ == "__main__":
    code = main()
    # Everything is written and closed by now: the interpreter's last garbage collection over
    # numpy's, gmsh's and the harness's objects (40 ms of a `solve`) has nothing to finalise.
    gc.freeze()
    sys.exit(code)
