"""`python -m harness <study> ...`: one command line, one subcommand per study.

Each study is a plug-in module `harness/studies/<name>.py` with `add_arguments(parser)` and
`run(args) -> int` (the way meshio's `_cli` wires its subcommands). Only the chosen study's
module is imported: `--help` and a `solve` do not pay for the imports of `cost` or `bench`.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from typing import Sequence

from harness import freefem
from harness.arguments import Parser
from harness.contract import ExitCode
from harness.faults import guarded, report

# Subcommand -> its one-line help (the module's own docstring says the rest).
STUDIES: dict[str, str] = {
    "convergence": "run every level and measure E^h and its slope",
    "solve": "solve one level and summarise run.json",
    "scenes": "a convergence study of every scene in cases/ and one summary table",
    "stress": "the stress suite: every case of cases/hard/, classified, with physical checks",
    "branches": "the solution branches of the paper's scene from four starts",
    "verify": "manufactured-solution errors and the three-grid GCI",
    "adapt": "adaptive refinement from the error estimate (2D): error against unknowns, beside uniform",
    "cost": "what accuracy costs: the cost-accuracy frontier of a scene",
    "bench": "repeated timings (finest level, sweep, whole process), medians and spread",
    "solvers": "the solver table: every linear solver on the same levels, medians",
    "profile": "where a solve's time and memory go, piece by piece, medians and shares",
    "crosscheck": "FreeFEM against the GetFEM peer, level by level, field by field",
    "scale": "past one machine: a solve on 1 and 2 MPI ranks, a study on one worker and on Dask",
}


def parser(chosen: str | None) -> Parser:
    """The command line; only `chosen`'s plug-in adds its arguments (None: none, for --help)."""
    top = Parser(prog="python -m harness", description=__doc__.splitlines()[0])
    commands = top.add_subparsers(dest="command", required=True, parser_class=Parser, metavar="STUDY")
    for name, text in STUDIES.items():
        sub = commands.add_parser(name, help=text, description=text,
                                  formatter_class=argparse.RawDescriptionHelpFormatter)
        if name == chosen:
            module = plugin(name)
            sub.description = module.__doc__
            module.add_arguments(sub)
            sub.set_defaults(run=module.run)
    return top


def plugin(name: str):  # noqa: ANN201 (a module)
    return importlib.import_module(f"harness.studies.{name}")


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    chosen = next((a for a in argv if not a.startswith("-")), None)
    freefem.version_query(freefem.BINARY)  # asked while the plug-in is imported
    try:  # the plug-in's imports are the rest of the start-up
        args = parser(chosen if chosen in STUDIES else None).parse_args(argv)
    except KeyboardInterrupt as exc:
        return report(f"interrupted by {exc.args[0] if exc.args else 'SIGINT'} during start-up", ExitCode.INTERRUPTED)
    return guarded(lambda: args.run(args))
