import gc
import sys

from harness.signals import install

# Before the heavy imports: a signal during start-up ends with one line and 130, no traceback.
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
