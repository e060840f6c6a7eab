"""The studies of `python -m harness <study>`: each a module with `add_arguments(parser)` and
`run(args) -> int` (harness/cli.py lists them)."""
