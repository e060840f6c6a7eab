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
    sys.exit(main())
